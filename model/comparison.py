"""Comparisons as a library: configs (or training sets) trained with several seeds for equal
steps, every run scored on one test set, each score's mean and spread over the seeds, and a
difference called only where it exceeds the spreads (`spikesim compare` parses and prints).

A difference between two configs is called only where it exceeds the spread: |mean_a - mean_b|
greater than std_a + std_b (the sample standard deviations over seeds). Below that, the tables
say "within spread": a reordering by another seed would be no surprise.
"""
from __future__ import annotations

import csv
import dataclasses
import io
import hashlib
import itertools
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from spikesim.config_io import read_small_file
from spikesim.outputs import atomic_write_text, output_folder, writable

MIN_SEEDS = 3
#: Windows a run is scored on in one pass: the paper's LLR sequences have 21, and a chunk that holds
#: the whole sequence is the one-shot computation (chunked streaming costs about 1.6x, model/streaming.py).
EVAL_CHUNK_WINDOWS = 32
BASELINES = ("tfp", "tfi")


@dataclass(frozen=True)
class SeedStat:
    """One score of one config over its seeds."""

    label: str
    group: str
    metric: str
    mean: float
    std: float
    values: tuple[float, ...]

    @property
    def n(self) -> int:
        return len(self.values)


def seed_stat(label: str, group: str, metric: str, values: Sequence[float]) -> SeedStat:
    """Mean and sample standard deviation (ddof 1; 0 for a single value, as for TFP/TFI, which
    have no seed)."""
    v = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore"):  # an infinite PSNR (a perfect frame) has no spread: nan
        std = float(v.std(ddof=1)) if v.size > 1 else 0.0
    return SeedStat(label, group, metric, float(v.mean()), std, tuple(float(x) for x in v))


def difference_holds(a: SeedStat, b: SeedStat) -> bool:
    """Whether a and b differ by more than their spreads together: |mean_a - mean_b| > std_a + std_b."""
    if not (math.isfinite(a.mean) and math.isfinite(b.mean)):
        return False
    return abs(a.mean - b.mean) > a.std + b.std


def run_dir(out: Path, label: str, seed: int) -> Path:
    """A run's folder: inside `out`, with no link on the way (refused, naming it)."""
    writable(out, "runs", label, f"seed{seed}")
    return out / "runs" / label / f"seed{seed}"


def _steps_done(last: Path) -> tuple[int | None, int | None]:
    """(steps of a run's last checkpoint, the steps its budget planned), None where there is none."""
    if not last.exists():
        return None, None
    from model.checkpoint import load_checkpoint
    state = load_checkpoint(last)
    planned = state.get("extra", {}).get("budget_planned_steps")
    return int(state["step"]), None if planned is None else int(planned)


#: Each run's record of what it cost: process CPU seconds and wall seconds, summed over the sessions
#: that trained it (a resumed run adds to it), and the steps it reached.
COMPUTE_FILE = "compute.json"
#: The metric fields of a kept score row (model.evaluation.Score).
SCORE_METRICS = ("psnr", "ssim", "psnr_8bit", "ssim_8bit", "psnr_norm", "ssim_norm", "psnr_aligned", "ssim_aligned")


def _process_cpu_seconds() -> float:
    """CPU time of this process, every thread (user + system): what a run consumed, however many
    other jobs shared the machine (its wall time is not)."""
    import resource
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _damaged(path: Path, what: str) -> None:
    """One warning naming a kept record that is malformed: it is set aside (re-made), never trusted."""
    import warnings
    warnings.warn(f"{path}: {what}; it is treated as damaged and made again", stacklevel=3)


def _finite_nonnegative(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0


def read_compute(folder: Path) -> dict[str, Any]:
    """A run's compute record ({} when it has none: trained before the record existed; {} with one
    warning when it is malformed: "cpu_seconds": "abc" ended a comparison with a TypeError after all
    its scoring)."""
    path = folder / COMPUTE_FILE
    if not path.exists():
        return {}
    try:
        data = json.loads(read_small_file(path, "a run's compute record"))
    except (OSError, ValueError):  # damaged, or not a regular file (a FIFO is not read)
        _damaged(path, "not a readable JSON compute record")
        return {}
    ok = (isinstance(data, dict) and all(_finite_nonnegative(data.get(k, 0.0)) for k in ("cpu_seconds", "wall_seconds"))
          and all(isinstance(data.get(k, 0), int) and not isinstance(data.get(k, 0), bool) and data.get(k, 0) >= 0
                  for k in ("sessions", "steps"))
          and isinstance(data.get("threads", []), list)
          and all(isinstance(t, int) and not isinstance(t, bool) and t > 0 for t in data.get("threads", [])))
    if not ok:
        _damaged(path, "its fields are not the numbers a compute record holds")
        return {}
    return data


def _record_compute(folder: Path, cpu_s: float, wall_s: float, steps: int, threads: int) -> None:
    before = read_compute(folder)
    record = {"cpu_seconds": float(before.get("cpu_seconds", 0.0)) + cpu_s,
              "wall_seconds": float(before.get("wall_seconds", 0.0)) + wall_s,
              "sessions": int(before.get("sessions", 0)) + 1, "steps": steps,
              "threads": sorted(set(before.get("threads", [])) | {threads})}
    atomic_write_text(writable(folder, COMPUTE_FILE), json.dumps(record, indent=1))


def _comparable(experiment: dict[str, Any]) -> dict[str, Any]:
    """A stored or asked-for experiment without its names: what makes two runs the same training."""
    return json.loads(json.dumps({k: v for k, v in experiment.items() if k not in ("name", "description")}))


def run_mismatch(last: Path, run: Any, identity: str, init: str | None, content: str | None = None) -> str | None:
    """How a kept run differs from the run asked for (its network and recipe, its training data, the
    weights it started from), or None: compare keeps a run only for the very run it would train
    (the checks `train --resume` makes). `identity` and `content` are the training data's
    (model.training.data_identity, data_content): names and sizes, and what the files hold."""
    from model.checkpoint import load_checkpoint
    from model.config import ExperimentConfig
    state = load_checkpoint(last)
    stored = state.get("experiment")
    if isinstance(stored, dict):
        # read as `train --resume` reads it: a field added since the run was written takes its default,
        # which is what that run trained with (a new field's default keeps the old behaviour)
        try:
            stored = ExperimentConfig.from_dict(stored, where=str(last)).to_dict()
        except ValueError:
            pass  # compared as stored: the fields that differ are named below
    if not isinstance(stored, dict) or _comparable(stored) != _comparable(run.to_dict()):
        have = _comparable(stored) if isinstance(stored, dict) else {}
        want = _comparable(run.to_dict())
        fields = [f"{sec}.{k}" for sec in ("model", "train") for k in sorted(set(want.get(sec, {})) | set(have.get(sec, {})))
                  if want.get(sec, {}).get(k) != have.get(sec, {}).get(k)]
        return "another network or recipe (" + (", ".join(fields[:4]) or "its config") + ")"
    extra = state.get("extra") if isinstance(state.get("extra"), dict) else {}
    if extra.get("data_identity") not in (None, identity):
        return "other training data"
    if content is not None and extra.get("data_content") not in (None, content):
        # the same names and sizes with other files: a dataset rewritten in place (round twenty: the runs
        # trained on the old content were kept, rc 0)
        return "other training data (the same scenes with other content: rewritten in place?)"
    started = (extra.get("init_weights") or {}).get("spec") if isinstance(extra.get("init_weights"), dict) else None
    if started != init:
        return f"other starting weights ({started or 'a random draw'}, not {init or 'a random draw'})"
    return None


def _same_run(out: Path, run: Any, seed: int, steps: int | None, identity: str, content: str) -> Path | None:
    """A finished run in `out` of the very same network, recipe, seed and training data under another
    label (the ablation's E is the representations' LR-Rep), or None. Only step-budgeted runs trained
    from a random draw are shared."""
    if steps is None:
        return None
    want = _comparable(run.to_dict())
    for cfg in sorted((out / "runs").glob(f"*/seed{seed}/config.json")):
        try:
            have = json.loads(read_small_file(cfg, "a run's config"))
        except (OSError, ValueError):
            continue
        if isinstance(have, dict) and _comparable(have) == want:
            last = cfg.parent / "last.pt"
            if _steps_done(last)[0] == steps and run_mismatch(last, run, identity, None, content) is None:
                return last
    return None


@dataclass(frozen=True)
class RunTask:
    """One (config, seed) run to train, everything a worker process needs (picklable)."""

    label: str
    seed: int
    experiment: Any
    folder: Path
    data: Any  # the training scenes, or the root to open them from (a worker process)
    device: str
    resume: bool
    init: str | None
    steps: int | None
    threads: int
    progress: bool
    overwrite: bool = False


def _train_task(task: RunTask) -> tuple[str, int, int]:
    """Train one run and add its cost to its compute record; (label, seed, steps reached)."""
    import time

    import torch

    from model.training import run_training
    scenes = task.data
    if isinstance(scenes, (str, Path)):  # a worker process opens the data itself
        from model.data import open_scenes
        from model.threads import set_cpu_threads
        set_cpu_threads(task.threads)
        scenes = open_scenes(scenes)
    cpu0, wall0 = _process_cpu_seconds(), time.monotonic()
    summary = run_training(task.experiment, scenes, [], task.folder, task.device, resume=task.resume,
                           progress=task.progress, init=None if task.resume else task.init, overwrite=task.overwrite)
    _record_compute(task.folder, _process_cpu_seconds() - cpu0, time.monotonic() - wall0, int(summary["steps"]),
                    torch.get_num_threads())
    if summary.get("stopped_by"):  # the run took Ctrl-C or SIGTERM, wrote last.pt and returned: the comparison
        raise _interruption(summary["stopped_by"])  # stops too (it went on to its next run, or called the stop an error)
    if task.steps is not None and summary["steps"] != task.steps:
        raise ValueError(f"config {task.label}: its {task.experiment.train.epochs} epochs end after "
                         f"{summary['steps']} steps, before --steps {task.steps}; raise its epochs or lower --steps")
    return task.label, task.seed, int(summary["steps"])


def _interruption(signal_name: str) -> KeyboardInterrupt:
    """What a task stopped by a signal raises: Terminated for SIGTERM (the CLI's exit status 143),
    KeyboardInterrupt for Ctrl-C."""
    from spikesim.signals import Terminated
    return Terminated(f"stopped by {signal_name}") if signal_name == "SIGTERM" else KeyboardInterrupt(signal_name)


#: In a worker process: the signal that stopped a task there. The pool hands a worker its next task
#: from a queue that cancelling cannot empty, so a worker refuses every task after a stop.
_STOPPED_IN_THIS_WORKER: list[str] = []


def _in_worker(fn: Any, task: Any) -> Any:
    """fn(task) in a pool worker, not started once a task there was stopped by a signal (round
    twenty-four: a training worker catches SIGTERM, writes last.pt and returns, and the pool gave it
    the next run, so `compare` asked to stop went on training every run left)."""
    if _STOPPED_IN_THIS_WORKER:
        raise _interruption(_STOPPED_IN_THIS_WORKER[0])
    try:
        return fn(task)
    except KeyboardInterrupt as exc:
        from spikesim.signals import Terminated
        _STOPPED_IN_THIS_WORKER.append("SIGTERM" if isinstance(exc, Terminated) else "SIGINT")
        raise


def _run_parallel(fn: Any, tasks: Sequence[Any], jobs: int, on_done: Any) -> list[Any]:
    """fn over tasks, in `jobs` worker processes (spawned: no torch state is forked) or in this one.
    Ctrl-C or SIGTERM stops the tasks running (fn's own rule: a training run finishes its step and
    writes last.pt) and starts no other."""
    if jobs <= 1 or len(tasks) <= 1:
        results = []
        for t in tasks:
            results.append(fn(t))
            on_done(results[-1])
        return results
    import concurrent.futures
    import multiprocessing
    from concurrent.futures.process import BrokenProcessPool

    from spikesim.signals import stop_pool_workers
    results = []
    with concurrent.futures.ProcessPoolExecutor(min(jobs, len(tasks)),
                                                mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(_in_worker, fn, t): t for t in tasks}
        try:
            for fut in concurrent.futures.as_completed(futures):
                results.append(fut.result())
                on_done(results[-1])
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM (here or in a worker): the tasks not started are not started,
            for fut in futures:   # and the workers stop rather than finish their runs (each finishes its step and
                fut.cancel()      # writes last.pt, so a rerun goes on: round fourteen)
            stop_pool_workers(pool)
            raise
        except BrokenProcessPool:  # a worker killed from outside: most often the kernel, for memory
            running = [getattr(t, "name", None) or f"{getattr(t, 'label', '?')} seed {getattr(t, 'seed', '?')}"
                       for f, t in futures.items() if not f.done() or f.exception() is not None]
            raise MemoryError(f"a worker process was killed while on {', '.join(running[:4])} (out of memory?); "
                              f"what finished is kept: run the same command again to go on, with --jobs 1 if it "
                              "happens again") from None
    return results


def train_seeds(configs: Sequence[tuple[str, Any]], seeds: Sequence[int], steps: int | dict[str, int] | None,
                train_scenes: Sequence[Any] | dict[str, Sequence[Any]], out: Path, device: str = "auto",
                precision: str | None = None, progress: bool = False, budget_minutes: float | None = None,
                init: str | None = None, jobs: int = 1,
                data_roots: Path | dict[str, Path] | None = None, threads: int = 1) -> dict[tuple[str, int], Path]:
    """Train every (config, seed) for exactly `steps` steps, or for `budget_minutes` of wall time
    each (equal time: the steps are what each config's speed allows); returns each run's last
    checkpoint. A finished run is kept; an unfinished one is continued (--resume); one past
    `steps` is refused. `train_scenes` is one dataset for every label, or {label: scenes} (a
    comparison of data); `init` starts every new run from those weights (fine-tuning).

    `steps` may differ per label ({label: steps}: equal training FLOP, `equal_flop_steps`).

    jobs > 1 trains that many runs at once, each in its own process with `threads` torch threads
    (data_roots: where each process opens the data). Each run records the CPU seconds it took
    (COMPUTE_FILE), measured in the process that trained it."""
    if (steps is None) == (budget_minutes is None):
        raise ValueError("give either a number of steps or a budget in minutes")
    if jobs > 1 and data_roots is None:
        raise ValueError("train_seeds: jobs > 1 needs data_roots (each worker process opens the data)")
    done: dict[tuple[str, int], Path] = {}
    tasks: list[RunTask] = []
    from model.training import data_content, data_identity
    identities: dict[int, tuple[str, str]] = {}
    per_label = steps if isinstance(steps, dict) else {label: steps for label, _ in configs}
    for (label, exp), seed in itertools.product(configs, seeds):
        steps = per_label[label]
        limits = {"max_steps": steps} if steps is not None else {"budget_minutes": budget_minutes, "max_steps": None}
        train = dataclasses.replace(exp.train, seed=int(seed), **limits,
                                    **({"precision": precision} if precision else {}))
        run = dataclasses.replace(exp, name=f"{label}_seed{seed}", train=train)
        folder = run_dir(out, label, seed)
        last = folder / "last.pt"
        scenes = train_scenes[label] if isinstance(train_scenes, dict) else train_scenes
        if id(scenes) not in identities:
            identities[id(scenes)] = (data_identity(scenes, []), data_content(scenes, []))
        identity, content = identities[id(scenes)]
        if last.exists():
            differs = run_mismatch(last, run, identity, init, content)
            if differs == "another network or recipe (train.max_steps)":  # the schedule was planned for its steps
                raise ValueError(f"{folder} holds a run trained for {_steps_done(last)[0]} steps; --max-steps {steps} "
                                 "plans another learning-rate schedule, so it is a new run: choose another --out")
            if differs is not None:
                raise ValueError(f"{folder} holds a run trained with {differs} than asked for now; compare keeps a run "
                                 "only for the very config, data, seed and --init it would train: remove that folder "
                                 "or choose another --out")
        if not last.exists() and init is None:
            same = _same_run(out, run, seed, steps, identity, content)
            if same is not None:  # this config and seed trained under another label: one run serves both
                print(f"[compare] {label} seed {seed}: the same config and seed already trained as {same.parent}",
                      file=sys.stderr)
                done[(label, seed)] = same
                continue
        have, planned = _steps_done(last)
        target = steps if steps is not None else planned
        if have is not None and target is not None and have > target:
            raise ValueError(f"{last} has {have} steps, more than --max-steps {steps}: choose another --out")
        done[(label, seed)] = last
        if have is None or have != target:
            if jobs > 1:
                data: Any = data_roots[label] if isinstance(data_roots, dict) else data_roots
            else:
                data = train_scenes[label] if isinstance(train_scenes, dict) else train_scenes
            # a folder without last.pt is a run cut before its first checkpoint: nothing to keep, start it again
            fresh_again = have is None and folder.exists()
            tasks.append(RunTask(label, int(seed), run, folder, data, device, have is not None, init, steps,
                                 threads, progress and jobs <= 1, fresh_again))
    counts = sorted({n for n in per_label.values() if n is not None})
    what = (f"{'/'.join(map(str, counts))} steps" if counts else f"{budget_minutes:g} minutes")
    if tasks:
        print(f"[compare] {len(tasks)} of {len(done)} runs to train ({what} each), {jobs} at a time", file=sys.stderr)
    import time

    from spikesim.progress import progress_bar
    start, count = time.monotonic(), [0]
    with progress_bar(total=len(tasks), desc="runs", unit="run", quiet=not progress or not tasks) as bar:
        def finished(result: tuple[str, int, int]) -> None:
            bar.update(1)
            count[0] += 1
            left = (time.monotonic() - start) / count[0] * (len(tasks) - count[0])
            print(f"[compare] run {count[0]}/{len(tasks)} trained: {result[0]} seed {result[1]}, {result[2]} steps; "
                  f"about {left / 60:.0f} min of training left", file=sys.stderr)
        _run_parallel(_train_task, tasks, jobs, finished)
    return done


def equal_flop_steps(configs: Sequence[tuple[str, Any]], steps: int, reference: str) -> dict[str, int]:
    """Steps per label with the training FLOP of `steps` steps of the `reference` label: a network
    whose step costs twice as much trains half as many steps (model/flops.py; the frame size does not
    enter: a training step's FLOP is at the config's crop)."""
    from model.flops import network_cost
    cost = {label: network_cost(exp, exp.train.crop, exp.train.crop).train_flop_per_step for label, exp in configs}
    if reference not in cost:
        raise ValueError(f"equal FLOP: the reference {reference!r} is not among the configs {list(cost)}")
    return {label: max(1, round(steps * cost[reference] / c)) for label, c in cost.items()}


def check_samples(configs: Sequence[tuple[str, Any]], train_scenes: Sequence[Any], flag: str = "--configs") -> None:
    """Every config finds training samples in the data, checked before any run trains (so a
    config that cannot train does not fail after the others have); the error names `flag` and the
    run's label (--data LABEL where the runs are labelled by their data)."""
    from model.data import SequenceDataset
    for label, exp in configs:
        try:
            SequenceDataset(train_scenes, exp.model.window, exp.train.num_windows, exp.train.crop,
                            set_shares=exp.train.set_shares)  # a share naming no set: refused before any run
        except ValueError as exc:
            raise ValueError(f"{flag} {label}: {exc}") from None


def run_name(label: str, seed: int) -> str:
    return f"{label}#{seed}"


def _scores_file(test_id: str) -> str:
    return f"scores-{test_id}.json"


def _checkpoint_stamp(path: Path) -> list[Any]:
    """What a kept score was made from: the file's size, time and content. The content too: a
    checkpoint copied over another with its time kept (`cp -p`, an archive unpacked) has the same
    size and time, and kept the old weights' scores."""
    from spikesim.dataset import sha256_file
    st = path.stat()
    return [st.st_size, st.st_mtime_ns, sha256_file(path)]


def _read_scores(path: Path, stamp: list[Any], scenes: Sequence[str] | None = None) -> list[Any] | None:
    """Cached rows of one method on one test set, None unless written for this very checkpoint."""
    from model.evaluation import Score
    try:  # a damaged cache, or one that is not a regular file (a FIFO is not read), is scored again
        if not path.exists():
            return None
        data = json.loads(read_small_file(path, "a score cache", limit=64 << 20))
        if data.get("checkpoint") != stamp:
            return None
        missing = sorted({m for row in data["rows"] for m in SCORE_METRICS if m not in row})
        if missing:  # a cache from before a metric existed (ssim_aligned): scored again, not shown as nan
            raise ValueError(f"it has no {', '.join(missing)} (written before that metric existed)")
        rows = [Score(**{k: (math.nan if v is None else v) for k, v in row.items()}) for row in data["rows"]]
        for r in rows:  # every value of its type and range: an edited cache ("frames": -5, a string) is not used
            if not (isinstance(r.scene, str) and isinstance(r.method, str) and isinstance(r.frames, int)
                    and not isinstance(r.frames, bool) and r.frames >= 1
                    and all(isinstance(getattr(r, m), (int, float)) and not isinstance(getattr(r, m), bool)
                            for m in SCORE_METRICS)):
                raise ValueError(f"row {dataclasses.asdict(r)} is not a score")
        if not rows:
            raise ValueError("no rows")
        if scenes is not None and {r.scene for r in rows if not r.scene.startswith("ALL")} != set(scenes):
            raise ValueError("its scenes are not the test set's")
        return rows
    except (OSError, ValueError, TypeError, KeyError, AttributeError) as exc:
        _damaged(path, f"a malformed score cache ({str(exc)[:120]})")
        return None


def _write_scores(path: Path, stamp: list[Any], rows: Sequence[Any]) -> None:
    from model.evaluation import json_safe
    atomic_write_text(path, json.dumps(json_safe({"checkpoint": stamp, "rows": [dataclasses.asdict(r) for r in rows]})))


@dataclass(frozen=True)
class EvalTask:
    """One method (a run's checkpoint, or a seedless baseline) to score on the test set."""

    name: str
    spec: str | Path  # a baseline spec, or a checkpoint path
    is_run: bool
    cache: Path | None  # where its rows are kept (None: not kept)
    test_data: Any  # scenes, or the root a worker opens
    window: int
    device: str
    chunk: int
    threads: int


def _eval_task(task: EvalTask) -> list[Any]:
    from model.evaluation import evaluate
    from model.methods import ModelMethod, method_from_spec
    scenes = task.test_data
    if isinstance(scenes, (str, Path)):
        from model.data import open_scenes
        from model.threads import set_cpu_threads
        set_cpu_threads(task.threads)
        scenes = open_scenes(scenes)
    method = (ModelMethod(task.name, Path(task.spec), task.chunk, task.device) if task.is_run
              else method_from_spec(str(task.spec), task.window))
    rows = evaluate(scenes, [method], task.window, progress=False)
    stamp = _checkpoint_stamp(Path(task.spec)) if task.is_run else _baseline_stamp(str(task.spec), task.window)
    if task.cache is not None:
        _write_scores(task.cache, stamp, rows)
    return rows


def check_baselines(baselines: Sequence[str], window: int) -> list[str]:
    """Each baseline's column label at this window; a ValueError for a spec the window cannot take
    (baseline_label) or two specs of one column: `--baselines tfp tfp` scored TFP twice and pooled it
    as a two-seed mean with a spread of 0.000 (round twenty-two), where `evaluate` refuses repeats."""
    labels = [baseline_label(b, window) for b in baselines]
    repeated = sorted({label for label in labels if labels.count(label) > 1})
    if repeated:
        raise ValueError(f"--baselines: {', '.join(repeated)} given more than once ({' '.join(baselines)}); a seedless "
                         "method is scored once")
    return labels


def _baseline_stamp(spec: str, window: int) -> list[Any]:
    """What a baseline's kept scores answer for: its spec and the window it was scored at ("TFP" is
    TFP at every window: scores of window 41 were reported beside window-21 networks, round twenty-one)."""
    return ["baseline", spec, int(window)]


def evaluate_runs(checkpoints: dict[tuple[str, int], Path], test_scenes: Sequence[Any], window: int,
                  baselines: Sequence[str] = BASELINES, device: str = "cpu", chunk: int | None = None,
                  progress: bool = False, jobs: int = 1, test_root: Path | None = None, out: Path | None = None,
                  threads: int = 1) -> list[Any]:
    """evaluate's rows for every run (method names label#seed) and the baselines.

    Each method is scored on its own (evaluate scores methods independently, so the rows are the
    same), and with `out` its rows are kept beside it (a run's folder, or `out` for a baseline),
    keyed by the test set's identity and the checkpoint's size and time: a comparison rerun with
    more configs scores only what is new. jobs > 1 scores that many methods at once, each process
    opening `test_root`."""
    from model.training import data_content, data_identity
    if chunk is None:  # a test sequence in one pass: streaming in chunks would redo the backward half (1.6x)
        chunk = EVAL_CHUNK_WINDOWS
    if jobs > 1 and test_root is None:
        raise ValueError("evaluate_runs: jobs > 1 needs test_root (each worker process opens the test data)")
    # the test set's names and sizes and what its files hold: scores kept for a test set rewritten in
    # place were reported for the new content (round twenty)
    test_id = hashlib.sha256(f"{data_identity(test_scenes, [])}-{data_content(test_scenes, [])}".encode()).hexdigest()[:16]
    scene_names = [s.name for s in test_scenes]
    data: Any = test_root if jobs > 1 else test_scenes
    cached: dict[str, list[Any]] = {}
    tasks: list[EvalTask] = []
    names: list[str] = []
    for b, name in zip(baselines, check_baselines(baselines, window)):
        names.append(name)
        cache = writable(out, _scores_file(f"{test_id}-w{window}-{name}")) if out is not None else None
        rows = _read_scores(cache, _baseline_stamp(b, window), scene_names) if cache is not None else None
        if rows is not None:
            cached[name] = rows
        else:
            tasks.append(EvalTask(name, b, False, cache, data, window, device, chunk, threads))
    for (label, seed), path in checkpoints.items():
        name = run_name(label, seed)
        names.append(name)
        cache = writable(path.parent, _scores_file(test_id)) if out is not None else None
        rows = _read_scores(cache, _checkpoint_stamp(path), scene_names) if cache is not None else None
        if rows is not None:
            cached[name] = [dataclasses.replace(r, method=name) for r in rows]
        else:
            tasks.append(EvalTask(name, path, True, cache, data, window, device, chunk, threads))
    if tasks:
        print(f"[compare] scoring {len(tasks)} methods on the test set ({len(cached)} kept from before), "
              f"{jobs} at a time", file=sys.stderr)
    import time
    start, count = time.monotonic(), [0]

    def finished(rows: list[Any]) -> None:
        count[0] += 1
        left = (time.monotonic() - start) / count[0] * (len(tasks) - count[0])
        print(f"[compare] scored {count[0]}/{len(tasks)}: {rows[-1].method} aligned PSNR {rows[-1].psnr_aligned:.2f} dB; "
              f"about {left / 60:.0f} min of scoring left", file=sys.stderr)
    for rows in _run_parallel(_eval_task, tasks, jobs, finished):
        cached[rows[0].method] = rows
    from model.evaluation import ALL

    def is_group(r: Any) -> bool:
        return r.scene == ALL or r.scene.startswith(ALL + "_")
    per_scene = [r for n in names for r in cached[n] if not is_group(r)]
    pooled = [r for n in names for r in cached[n] if is_group(r)]
    return per_scene + pooled


def baseline_label(spec: str, window: int | None = None) -> str:
    """The column a baseline spec gets in the tables (TFP, TFI, TFP-205, black, ...); with a window,
    the spec is also checked against it (tfp:N spans an odd number of windows)."""
    from model.methods import method_from_spec, span_method_spec
    if window is None:
        span = span_method_spec(spec, 1)
        return f"TFP-{span}" if span is not None else method_from_spec(spec).name
    return method_from_spec(spec, window).name


def aggregate(rows: Sequence[Any], labels: Sequence[str], baselines: Sequence[str] = BASELINES) -> list[SeedStat]:
    """Per label, group (ALL_low, ALL_normal, ALL) and metric: the statistics over seeds."""
    from model.metrics import METRICS
    from model.evaluation import ALL

    groups = [g for g in dict.fromkeys(r.scene for r in rows) if g.startswith(ALL)]
    stats = []
    for group in groups:
        for label in [baseline_label(b) for b in baselines] + list(labels):
            mine = [r for r in rows if r.scene == group and (r.method == label or r.method.startswith(label + "#"))]
            for metric in METRICS:
                stats.append(seed_stat(label, group, metric, [r.value(metric) for r in mine]))
    return stats


def _fmt(s: SeedStat, fmt: str) -> str:
    body = fmt.format(s.mean)
    # an infinite mean (a frame whose 8-bit image equals the ground truth's: a dark scene, both all
    # zeros) has no spread to give: "inf ± nan" read as a failure
    return body if s.n == 1 or not math.isfinite(s.mean) else f"{body} ± {fmt.format(s.std)}"


#: What a difference of two scores says where one is infinite: inf - inf has no value, and a
#: finite score against an infinite one is no measured gap.
NO_DIFFERENCE = "n/a (a frame scores inf: exact in 8 bits)"


def run_costs(configs: Sequence[tuple[str, Any]], checkpoints: dict[tuple[str, int], Path], height: int,
              width: int) -> dict[str, dict[str, Any]]:
    """Per config label: parameters, GFLOP per frame at height x width and per training step
    (model/flops.py), the steps its runs reached, their mean CPU minutes (COMPUTE_FILE; None where a
    run has no record) and how many seeds."""
    from model.flops import network_cost
    steps = steps_per_run(checkpoints)
    out: dict[str, dict[str, Any]] = {}
    for label, exp in configs:
        keys = [k for k in checkpoints if k[0] == label]
        cost = network_cost(exp, height, width).to_dict()
        cpu = [read_compute(checkpoints[k].parent).get("cpu_seconds") for k in keys]
        reached = sorted({steps[k] for k in keys})
        out[label] = {"parameters": cost["parameters"], "gflop_per_frame": cost["gflop_per_frame"],
                      "sampling_gflop_per_frame": cost["sampling_flop_per_frame"] / 1e9,
                      "train_gflop_per_step": cost["train_gflop_per_step"], "frame": [height, width],
                      "steps": reached[0] if len(reached) == 1 else "/".join(map(str, reached)),
                      "cpu_minutes": (sum(cpu) / len(cpu) / 60 if cpu and all(c is not None for c in cpu) else None),
                      "seeds": len(keys)}
    return out


def steps_per_run(checkpoints: dict[tuple[str, int], Path]) -> dict[tuple[str, int], int]:
    return {key: int(_steps_done(path)[0] or 0) for key, path in checkpoints.items()}


def markdown(stats: Sequence[SeedStat], labels: Sequence[str], baselines: Sequence[str], seeds: Sequence[int],
             length: int | str, steps_per_run: dict[tuple[str, int], int] | None = None,
             costs: dict[str, dict[str, Any]] | None = None) -> str:
    """Per group, a table of mean +- std over seeds; then every pair of configs, with the
    difference called only where it exceeds the spread."""
    from model.metrics import METRICS
    from model.evaluation import ALL, TABLE_ROWS, method_label

    cols = [baseline_label(b) for b in baselines] + list(labels)
    by = {(s.label, s.group, s.metric): s for s in stats}
    groups = list(dict.fromkeys(s.group for s in stats))
    groups = [g for g in groups if g != ALL] + [ALL]
    length = f"{length} steps" if isinstance(length, int) else length
    lines = [f"{len(seeds)} training seeds ({', '.join(map(str, seeds))}) x {length} per config; mean ± "
             f"standard deviation over seeds (baselines have no seed). A difference is called only where "
             f"|mean_a - mean_b| > std_a + std_b.", ""]
    if steps_per_run:
        per_label: dict[str, list[int]] = {}
        for (label, _), n in steps_per_run.items():
            per_label.setdefault(label, []).append(n)
        lines += ["Steps per run: " + "; ".join(f"{label} {', '.join(map(str, n))}" for label, n in per_label.items()), ""]
    if costs:
        h, w = next(iter(costs.values()))["frame"]
        lines += [f"| Config | parameters | GFLOP per {w} x {h} frame | GFLOP per training step | steps | "
                  "CPU-minutes per run (mean) | seeds |", "|---|---|---|---|---|---|---|"]
        for label, c in costs.items():
            cpu = "—" if c["cpu_minutes"] is None else f"{c['cpu_minutes']:.1f}"
            lines.append(f"| {label} | {c['parameters']:,} | {c['gflop_per_frame']:.1f} | "
                         f"{c['train_gflop_per_step']:.1f} | {c['steps']} | {cpu} | {c['seeds']} |")
        lines += ["", "FLOP: torch's counter on convolutions and matrix products, deformable sampling added at 8 "
                  "FLOP per sample and channel (model/flops.py); CPU-minutes: the training process's own CPU time, "
                  "every thread.", ""]
    for g in groups:
        title = "All scenes" if g == ALL else f"{g.split('_', 1)[1].capitalize()} light"
        lines += [f"**{title}**", "", "| Metric | " + " | ".join(method_label(c) for c in cols) + " |",
                  "|---|" + "---|" * len(cols)]
        for key in TABLE_ROWS:  # aligned PSNR first: the floors cannot win it
            _, label, fmt = METRICS[key]
            lines.append(f"| {label} | " + " | ".join(_fmt(by[(c, g, key)], fmt) for c in cols) + " |")
        lines.append("")
    pairs = list(itertools.combinations(labels, 2))
    if pairs:
        lines += ["| Groups | Metric | " + " | ".join(f"{a} - {b}" for a, b in pairs) + " |",
                  "|---|---|" + "---|" * len(pairs)]
        for g in groups:
            for key in TABLE_ROWS:
                _, label, fmt = METRICS[key]
                cells = []
                for a, b in pairs:
                    sa, sb = by[(a, g, key)], by[(b, g, key)]
                    if not (math.isfinite(sa.mean) and math.isfinite(sb.mean)):
                        cells.append(NO_DIFFERENCE)
                        continue
                    d = fmt.format(sa.mean - sb.mean)
                    cells.append(f"**{d}**" if difference_holds(sa, sb) else f"{d} (within spread)")
                lines.append(f"| {g} | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


COMPARE_FILES = ("compare.csv", "compare.json", "compare.md")


def write_comparison(stats: Sequence[SeedStat], rows: Sequence[Any], text: str, meta: dict[str, Any], out: Path) -> None:
    """compare.csv, compare.json, compare.md and every run's per-scene metrics.csv, each written
    whole, inside `out` and never through a link there (spikesim.outputs)."""
    from model.evaluation import check_results, write_results
    for name in COMPARE_FILES:
        writable(out, name)
    check_results(out)
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(["label", "group", "metric", "mean", "std", "seeds", "values"])
    for s in stats:
        w.writerow([s.label, s.group, s.metric, f"{s.mean:.6f}", f"{s.std:.6f}", s.n,
                    " ".join(f"{v:.6f}" for v in s.values)])
    with output_folder(out):
        write_results(rows, list(dict.fromkeys(r.method for r in rows)), out)
        atomic_write_text(writable(out, "compare.csv"), buf.getvalue())
        atomic_write_text(writable(out, "compare.json"),
                          json.dumps({**meta, "stats": [dataclasses.asdict(s) for s in stats]}, indent=1))
        atomic_write_text(writable(out, "compare.md"), text)
