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
import itertools
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

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


def steps_per_run(checkpoints: dict[tuple[str, int], Path]) -> dict[tuple[str, int], int]:
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
