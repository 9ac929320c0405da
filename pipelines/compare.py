"""`spikesim compare`: compare methods or ablations the way a difference can be trusted: each
config trained with several seeds (at least 3) for the same number of steps, every run evaluated
on the same test set, and each score reported as mean +- standard deviation over the seeds.

A difference between two configs is called only where it exceeds the spread: |mean_a - mean_b|
greater than std_a + std_b (the sample standard deviations over seeds). Below that, the table
says "within spread": a reordering by another seed would be no surprise.

    spikesim compare --data rllr --test-data llr --configs E=tiny A=tiny_ablation_a \\
        --seeds 0 1 2 --max-steps 150 --out runs/compare

Or compare training data: one config, several datasets, each labelled (equal steps of one network
are equal compute), optionally all fine-tuned from the same weights:

    spikesim compare --data OLD=rllr_procedural NEW=rllr_natural --test-data llr --configs lrrep_cpu \\
        --init lrrep --seeds 0 1 2 --max-steps 300 --out runs/data_study

Writes <out>/runs/<label>/seed<k>/ (training runs, resumable: a finished run is kept, an
unfinished one continued), <out>/metrics.csv (every run on every scene, evaluate's rows),
<out>/compare.csv, <out>/compare.json and <out>/compare.md.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import json
import math
import io
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from model.threads import set_cpu_threads
from pipelines.argtypes import add_threads_argument, nonnegative_int, output_dir, positive_float, positive_int
from spikesim.outputs import atomic_write_text, output_folder, writable

MIN_SEEDS = 3
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


def config_spec(text: str) -> tuple[str, Any]:
    """argparse type: LABEL=CONFIG or CONFIG (a named config or a JSON file); (label, config)."""
    from model.config import load_config
    label, _, name = text.rpartition("=") if "=" in text else ("", "", text)
    try:
        exp = load_config(name)
    except (OSError, ValueError, TypeError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    label = label or exp.name
    if not label or any(c in label for c in "/\\#") or label.startswith(".") or label.upper().startswith("ALL"):
        raise argparse.ArgumentTypeError(f"{text!r}: a label is a plain name (no /, \\ or #, not starting "
                                         "with a dot or ALL)")
    return label, exp


def data_spec(text: str) -> tuple[str, Path]:
    """argparse type: LABEL=ROOT or ROOT (a dataset root; label: its folder's name)."""
    label, _, root = text.rpartition("=") if "=" in text else ("", "", text)
    path = Path(root)
    if not label:
        return "", path  # unlabelled: one dataset for every config, or named by its folder (cmd_compare)
    if any(c in label for c in "/\\#") or label.startswith(".") or label.upper().startswith("ALL"):
        raise argparse.ArgumentTypeError(f"{text!r}: a label is a plain name (no /, \\ or #, not starting "
                                         "with a dot or ALL)")
    return label, path


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


def train_seeds(configs: Sequence[tuple[str, Any]], seeds: Sequence[int], steps: int | None,
                train_scenes: Sequence[Any] | dict[str, Sequence[Any]], out: Path, device: str = "auto",
                precision: str | None = None, progress: bool = False, budget_minutes: float | None = None,
                init: str | None = None) -> dict[tuple[str, int], Path]:
    """Train every (config, seed) for exactly `steps` steps, or for `budget_minutes` of wall time
    each (equal time: the steps are what each config's speed allows); returns each run's last
    checkpoint. A finished run is kept; an unfinished one is continued (--resume); one past
    `steps` is refused. `train_scenes` is one dataset for every label, or {label: scenes} (a
    comparison of data); `init` starts every new run from those weights (fine-tuning)."""
    from model.training import run_training

    if (steps is None) == (budget_minutes is None):
        raise ValueError("give either a number of steps or a budget in minutes")
    done: dict[tuple[str, int], Path] = {}
    for (label, exp), seed in itertools.product(configs, seeds):
        limits = {"max_steps": steps} if steps is not None else {"budget_minutes": budget_minutes, "max_steps": None}
        train = dataclasses.replace(exp.train, seed=int(seed), **limits,
                                    **({"precision": precision} if precision else {}))
        run = dataclasses.replace(exp, name=f"{label}_seed{seed}", train=train)
        folder = run_dir(out, label, seed)
        last = folder / "last.pt"
        have, planned = _steps_done(last)
        target = steps if steps is not None else planned
        if have is not None and target is not None and have > target:
            raise ValueError(f"{last} has {have} steps, more than --max-steps {steps}: choose another --out")
        if have is None or have != target:
            what = f"{steps} steps" if steps is not None else f"{budget_minutes:g} minutes"
            print(f"[compare] training {label} seed {seed} for {what}"
                  + (f" (continuing from step {have})" if have else ""), file=sys.stderr)
            scenes = train_scenes[label] if isinstance(train_scenes, dict) else train_scenes
            summary = run_training(run, scenes, [], folder, device, resume=have is not None, progress=progress,
                                   init=None if have is not None else init)
            if steps is not None and summary["steps"] != steps:
                raise ValueError(f"config {label}: its {exp.train.epochs} epochs end after {summary['steps']} steps, "
                                 f"before --steps {steps}; raise its epochs or lower --steps")
        done[(label, seed)] = last
    return done


def check_samples(configs: Sequence[tuple[str, Any]], train_scenes: Sequence[Any]) -> None:
    """Every config finds training samples in the data, checked before any run trains (so a
    config that cannot train does not fail after the others have)."""
    from model.data import SequenceDataset
    for label, exp in configs:
        try:
            SequenceDataset(train_scenes, exp.model.window, exp.train.num_windows, exp.train.crop)
        except ValueError as exc:
            raise ValueError(f"--configs {label}: {exc}") from None


def run_name(label: str, seed: int) -> str:
    return f"{label}#{seed}"


def evaluate_runs(checkpoints: dict[tuple[str, int], Path], test_scenes: Sequence[Any], window: int,
                  baselines: Sequence[str] = BASELINES, device: str = "cpu", chunk: int = 8,
                  progress: bool = False) -> list[Any]:
    """evaluate's rows for every run (method names label#seed) and the baselines."""
    from model.methods import ModelMethod, method_from_spec
    from model.evaluation import evaluate

    methods: list[Any] = [method_from_spec(b, window) for b in baselines]
    methods += [ModelMethod(run_name(label, seed), path, chunk, device) for (label, seed), path in checkpoints.items()]
    return evaluate(test_scenes, methods, window, progress=progress)


def baseline_label(spec: str, window: int = 41) -> str:
    """The column a baseline spec gets in the tables (TFP, TFI, TFP-205, black, ...)."""
    from model.methods import method_from_spec
    return method_from_spec(spec, window).name


def baseline_spec(text: str) -> str:
    """argparse type: a seedless method evaluate knows (tfp, tfi, black, mean, tfp:N)."""
    if not (text in ("tfp", "tfi", "black", "mean") or text.startswith("tfp:")):
        raise argparse.ArgumentTypeError(f"{text!r}: a baseline is tfp, tfi, black, mean or tfp:N")
    try:
        baseline_label(text)  # tfp:N's own checks (an odd number of windows)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


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
    return body if s.n == 1 else f"{body} ± {fmt.format(s.std)}"


def _steps_per_run(checkpoints: dict[tuple[str, int], Path]) -> dict[tuple[str, int], int]:
    return {key: int(_steps_done(path)[0] or 0) for key, path in checkpoints.items()}


def markdown(stats: Sequence[SeedStat], labels: Sequence[str], baselines: Sequence[str], seeds: Sequence[int],
             length: int | str, steps_per_run: dict[tuple[str, int], int] | None = None) -> str:
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


def cmd_compare(args: argparse.Namespace) -> int:
    from model.data import open_scenes
    from model.precision import resolve_precision
    from model.training import resolve_device

    dev = resolve_device(args.device)
    if args.precision:
        resolve_precision(args.precision, dev)
    set_cpu_threads(args.threads)  # before any torch work; the run log says how many and why
    seeds = list(dict.fromkeys(args.seeds))
    if len(seeds) < MIN_SEEDS:
        raise ValueError(f"--seeds: a comparison needs at least {MIN_SEEDS} distinct training seeds, got {seeds}")
    # labelled data (LABEL=ROOT), or several datasets: a comparison of data, runs labelled by the data
    by_data = len(args.data) > 1 or any(label for label, _ in args.data)
    data = {(label or root.resolve().name): root for label, root in args.data}
    if len(data) != len(args.data):
        raise ValueError(f"--data: labels must be unique, got {list(data)}; name them with LABEL=ROOT")
    if by_data and len(args.configs) > 1:
        raise ValueError("--data with labelled or several datasets compares data: give one config (its runs are "
                         "labelled by the datasets' labels)")
    if by_data:
        args.configs = [(label, args.configs[0][1]) for label in data]
    labels = [label for label, _ in args.configs]
    if len(set(labels)) != len(labels):
        raise ValueError(f"--configs: labels must be unique, got {labels}; name them with LABEL=CONFIG")
    taken = sorted(set(labels) & {baseline_label(b) for b in args.baselines})
    if taken:
        raise ValueError(f"--configs: label(s) {', '.join(taken)} name a baseline; choose others with LABEL=CONFIG")
    windows = {exp.model.window for _, exp in args.configs}
    if len(windows) != 1:
        raise ValueError(f"--configs: all configs must use one window length to be compared, got {sorted(windows)}")
    window = windows.pop()
    test_scenes = open_scenes(args.test_data)
    if by_data:
        train_scenes: Any = {label: open_scenes(root) for label, root in data.items()}
        for label, exp in args.configs:
            check_samples([(label, exp)], train_scenes[label])
    else:
        train_scenes = open_scenes(next(iter(data.values())))
        check_samples(args.configs, train_scenes)
    out = Path(args.out)
    checkpoints = train_seeds(args.configs, seeds, args.max_steps, train_scenes, out, str(dev), args.precision,
                              progress=not args.quiet, budget_minutes=args.budget_minutes, init=args.init)
    rows = evaluate_runs(checkpoints, test_scenes, window, args.baselines, str(dev), progress=not args.quiet)
    stats = aggregate(rows, labels, args.baselines)
    length = f"{args.max_steps} steps" if args.max_steps else f"{args.budget_minutes:g} minutes of wall time"
    text = markdown(stats, labels, args.baselines, seeds, length, _steps_per_run(checkpoints))
    meta = {"command": "spikesim " + shlex.join(sys.argv[1:]), "data": {k: str(v) for k, v in data.items()},
            "init": args.init,
            "test_data": str(args.test_data), "seeds": seeds, "steps": args.max_steps,
            "budget_minutes": args.budget_minutes, "steps_per_run": {f"{k[0]}#{k[1]}": v for k, v in
                                                                    _steps_per_run(checkpoints).items()},
            "configs": {label: exp.to_dict() for label, exp in args.configs}}
    write_comparison(stats, rows, text, meta, out)
    if args.json:
        from model.evaluation import json_safe
        print(json.dumps(json_safe({**meta, "statistics": [{**dataclasses.asdict(s), "values": list(s.values), "n": s.n}
                                                          for s in stats]}), indent=2))
    else:
        print(text)
    print(f"[compare] wrote {out / 'compare.md'}, {out / 'compare.csv'} and {out / 'metrics.csv'}", file=sys.stderr)
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `compare` on the CLI's subparsers."""
    p = subparsers.add_parser("compare", help="train configs with several seeds for equal steps; mean ± std",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, nargs="+", type=data_spec, metavar="[LABEL=]ROOT",
                   help="training dataset root (every scene trains); several, each LABEL=ROOT, with one config: "
                        "a comparison of training data")
    p.add_argument("--init", metavar="WEIGHTS",
                   help="start every run from these weights (a shipped network, lrrep, or a checkpoint): a "
                        "comparison of fine-tuning")
    p.add_argument("--test-data", required=True, help="test dataset root (evaluate's frames)")
    p.add_argument("--configs", nargs="+", required=True, type=config_spec, metavar="[LABEL=]CONFIG",
                   help="named configs or JSON files, each labelled (default label: the config's name)")
    p.add_argument("--seeds", nargs="+", type=nonnegative_int, default=[0, 1, 2],
                   help=f"training seeds, at least {MIN_SEEDS} (default: 0 1 2)")
    length = p.add_mutually_exclusive_group(required=True)
    length.add_argument("--max-steps", type=positive_int,
                        help="optimiser steps of every run (equal for all; as train --max-steps)")
    length.add_argument("--budget-minutes", type=positive_float,
                        help="wall minutes of every run (equal time, as train --budget-minutes: each config takes "
                             "the steps its speed allows)")
    p.add_argument("--baselines", nargs="*", type=baseline_spec, default=list(BASELINES),
                   help="seedless baselines in the tables: tfp, tfi, black, mean, tfp:N (TFP over N steps, an odd "
                        "number of windows: the span a network sees, e.g. tfp:205 for K = 5) (default: tfp tfi)")
    p.add_argument("-o", "--out", type=output_dir, required=True, help="folder for the runs and the tables")
    p.add_argument("--precision", choices=("bf16", "fp16", "fp32"),
                   help="training precision of every run (default: each config's, auto)")
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N or mps")
    add_threads_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="print the statistics over seeds as JSON instead of the tables")
    p.set_defaults(func=cmd_compare)
    return p
