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

    spikesim compare --data OLD=rllr_procedural NEW=rllr_natural --test-data llr --configs lrrep_refine \\
        --init lrrep --seeds 0 1 2 --max-steps 300 --out runs/data_study

Writes <out>/runs/<label>/seed<k>/ (training runs, resumable: a finished run is kept, an
unfinished one continued), <out>/metrics.csv (every run on every scene, evaluate's rows),
<out>/compare.csv, <out>/compare.json and <out>/compare.md.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
from pathlib import Path
from typing import Any

# the library (model/comparison.py); re-exported here for callers of pipelines.compare
from model.comparison import (BASELINES, COMPARE_FILES, MIN_SEEDS, SeedStat, aggregate, baseline_label,  # noqa: F401
                              check_baselines, check_samples, difference_holds, evaluate_runs, markdown, run_costs,
                              run_dir, run_name, seed_stat, steps_per_run, train_seeds, write_comparison)
from model.threads import set_cpu_threads
from pipelines.argtypes import add_threads_argument, output_dir, positive_float, positive_int, seed_int

def config_spec(text: str) -> tuple[str, Any]:
    """argparse type: LABEL=CONFIG or CONFIG (a named config or a JSON file); (label, config)."""
    from model.config import load_config
    label, _, name = text.rpartition("=") if "=" in text else ("", "", text)
    try:
        exp = load_config(name)
    except (OSError, ValueError, TypeError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    label = label or exp.name
    _check_label(text, label)
    return label, exp


#: The longest label: it names a folder (with "#seed") and a table column.
MAX_LABEL = 64


def _check_label(text: str, label: str) -> None:
    """A label names a run's folder and a table's column: a plain name, printable, no |."""
    if (not label.strip() or any(c in label for c in "/\\#|=") or label.startswith(".")
            or label.upper().startswith("ALL") or any(not c.isprintable() for c in label) or len(label) > MAX_LABEL):
        raise argparse.ArgumentTypeError(f"{text[:80]!r}: a label is a plain, printable name of at most {MAX_LABEL} "
                                         "characters (not blank; no /, \\, #, | or =; not starting with a dot or ALL)")


def data_spec(text: str) -> tuple[str, Path]:
    """argparse type: LABEL=ROOT or ROOT (a dataset root; label: its folder's name). Split at the
    first "=", as evaluate's LABEL=SPEC (a root's path may hold "="; a label may not)."""
    if "=" not in text:
        return "", Path(text)  # unlabelled: one dataset for every config, or named by its folder (cmd_compare)
    label, _, root = text.partition("=")
    _check_label(text, label)
    if not root:
        raise argparse.ArgumentTypeError(f"{text!r}: LABEL=ROOT with no ROOT")
    return label, Path(root)


def baseline_spec(text: str) -> str:
    """argparse type: a seedless method evaluate knows (tfp, tfi, stp, snm, black, mean, tfp:N)."""
    if not (text in ("tfp", "tfi", "stp", "snm", "black", "mean") or text.startswith("tfp:")):
        raise argparse.ArgumentTypeError(f"{text!r}: a baseline is tfp, tfi, stp, snm, black, mean or tfp:N")
    try:
        baseline_label(text)  # tfp:N's digits; its span against the configs' window is checked once they are read
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _study_names() -> list[str]:
    from model.studies import STUDIES
    return list(STUDIES)


def _reference_label(args: argparse.Namespace, study: Any) -> str:
    """The config whose steps set the FLOP budget: the study's shipped network (lrrep_cpu), else the
    first config."""
    if study is not None:
        for label, name in study.configs:
            if name == "lrrep_cpu" and label in dict(args.configs):
                return label
    return args.configs[0][0]


def cmd_compare(args: argparse.Namespace) -> int:
    from model.data import open_scenes
    from model.precision import resolve_precision
    from model.training import resolve_device

    dev = resolve_device(args.device)
    study = None
    if args.study:
        from model.studies import get_study
        study = get_study(args.study)
        if not args.configs:
            args.configs = [config_spec(f"{label}={name}") for label, name in study.configs]
        if args.baselines is None:
            from model.studies import resolve_baselines
            first = args.configs[0][1]
            args.baselines = resolve_baselines(study.baselines, first.train.num_windows * first.model.window)
    if not args.configs:
        raise ValueError("--configs: name the configs to compare, or a --study")
    if args.baselines is None:
        args.baselines = list(BASELINES)
    if args.jobs > 1 and str(dev) != "cpu":
        raise ValueError(f"--jobs {args.jobs}: parallel runs are for CPU cores; on {dev} train one at a time")
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
    if len({label.casefold() for label in labels}) != len(labels):  # folders and columns differ in case only
        raise ValueError(f"--configs: labels must be unique (case aside), got {labels}; name them with LABEL=CONFIG")
    named = {baseline_label(b).casefold(): baseline_label(b) for b in args.baselines}
    taken = sorted(label for label in labels if label.casefold() in named)
    if taken:
        raise ValueError(f"--configs: label(s) {', '.join(taken)} name a baseline; choose others with LABEL=CONFIG")
    windows = {exp.model.window for _, exp in args.configs}
    if len(windows) != 1:
        raise ValueError(f"--configs: all configs must use one window length to be compared, got {sorted(windows)}")
    window = windows.pop()
    check_baselines(args.baselines, window)  # before any run trains
    test_scenes = open_scenes(args.test_data)
    if by_data:
        train_scenes: Any = {label: open_scenes(root) for label, root in data.items()}
        for label, exp in args.configs:
            check_samples([(label, exp)], train_scenes[label], flag="--data")
    else:
        train_scenes = open_scenes(next(iter(data.values())))
        check_samples(args.configs, train_scenes)
    from model.data import shared_scenes
    for label, scenes in (train_scenes.items() if by_data else [(str(next(iter(data.values()))), train_scenes)]):
        if both := shared_scenes(test_scenes, scenes):  # training scenes' scores reported as held out (round six)
            raise ValueError(f"--test-data: {len(both)} scene(s) are also in --data {label} ({', '.join(both[:3])}"
                             f"{' ...' if len(both) > 3 else ''}): a comparison scores held-out scenes; give other "
                             "test data")
    out = Path(args.out)
    from spikesim.dataset import check_outside_datasets
    from spikesim.generation.lock import output_lock
    from spikesim.outputs import check_results_owned, output_folder, results_writing
    from model.comparison import COMPARE_FILES
    from model.evaluation import RESULT_FILES
    # checkpoints written into the test data, which verify then reported damaged (round ten)
    check_outside_datasets(out, [*data.values(), args.test_data], "--out")
    # the tables this run writes: a user's compare.md or metrics.md there was replaced (round ten)
    tables = [*RESULT_FILES, *COMPARE_FILES, *((f"study_{study.name}.md", f"study_{study.name}.json") if study else ())]
    # one compare per folder: two at once would train the same runs and write each other's tables
    with output_folder(out), output_lock(out, "compare", what="compare run"):
        check_results_owned(out, tables, "compare", "--out")
        roots: Any = data if by_data else next(iter(data.values()))
        import torch
        worker_threads = max(1, torch.get_num_threads() // args.jobs)  # --threads (or the free cores) shared out
        steps: Any = args.max_steps
        if args.equal == "flop":
            if not args.max_steps:
                raise ValueError("--equal flop shares out --max-steps of the reference config by training FLOP; give --max-steps")
            from model.comparison import equal_flop_steps
            reference = _reference_label(args, study)
            steps = equal_flop_steps(args.configs, args.max_steps, reference)
            print(f"[compare] equal training FLOP: {args.max_steps} steps of {reference} -> "
                  + ", ".join(f"{k} {v}" for k, v in steps.items()), file=sys.stderr)
        checkpoints = train_seeds(args.configs, seeds, steps, train_scenes, out, str(dev), args.precision,
                                  progress=not args.quiet, budget_minutes=args.budget_minutes, init=args.init,
                                  jobs=args.jobs, data_roots=roots, threads=worker_threads)
        rows = evaluate_runs(checkpoints, test_scenes, window, args.baselines, str(dev), progress=not args.quiet,
                             jobs=args.jobs, test_root=Path(args.test_data), out=out,
                             threads=worker_threads)
        stats = aggregate(rows, labels, args.baselines)
        length = (f"{args.max_steps} steps" if args.max_steps and args.equal == "steps" else
                  f"the training FLOP of {args.max_steps} steps of {_reference_label(args, study)}" if args.max_steps else
                  f"{args.budget_minutes:g} minutes of wall time")
        costs = run_costs(args.configs, checkpoints, test_scenes[0].height, test_scenes[0].width)
        text = markdown(stats, labels, args.baselines, seeds, length, steps_per_run(checkpoints), costs)
        if study is not None:
            from model.studies import study_markdown
            labels_of = {baseline_label(b): baseline_label(b) for b in args.baselines}
            text = study_markdown(study, stats, costs, labels_of) + "\n" + text
        meta = {"command": "spikesim " + shlex.join(sys.argv[1:]), "data": {k: str(v) for k, v in data.items()},
                "init": args.init,
                "test_data": str(args.test_data), "seeds": seeds, "steps": args.max_steps,
                "budget_minutes": args.budget_minutes, "equal": args.equal, "steps_per_run": {f"{k[0]}#{k[1]}": v for k, v in
                                                                        steps_per_run(checkpoints).items()},
                "configs": {label: exp.to_dict() for label, exp in args.configs}, "study": args.study,
                "costs": costs, "jobs": args.jobs}
        # checked again (a file put there while it trained); each table recorded as it is written,
        # so an interrupted or failed write leaves none the rerun refuses (round twelve)
        with results_writing(out, tables, "compare", "--out"):
            write_comparison(stats, rows, text, meta, out)
            if study is not None:  # one folder can hold every study (runs shared): each keeps its own table
                from model.evaluation import json_safe
                from spikesim.outputs import atomic_write_text, writable
                atomic_write_text(writable(out, f"study_{study.name}.md"), text)
                atomic_write_text(writable(out, f"study_{study.name}.json"), json.dumps(json_safe(
                    {**meta, "statistics": [{**dataclasses.asdict(s), "values": list(s.values)} for s in stats]}),
                    indent=1))
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
    p.add_argument("--configs", nargs="+", type=config_spec, metavar="[LABEL=]CONFIG",
                   help="named configs or JSON files, each labelled (default label: the config's name); "
                        "default with --study: the study's")
    p.add_argument("--study", choices=sorted(_study_names()),
                   help="one of the paper's comparisons (docs/comparisons.md): its configs, its seedless methods "
                        "and a table with the paper's figures beside ours")
    p.add_argument("--equal", choices=("steps", "flop"), default="steps",
                   help="what --max-steps makes equal: steps of every run (default), or training FLOP: --max-steps "
                        "steps of the reference (the study's shipped network, else the first config) and for each "
                        "other config the steps with the same FLOP (model/flops.py)")
    p.add_argument("--jobs", type=positive_int, default=1,
                   help="runs trained (and scored) at once, each in its own process with --threads / jobs torch "
                        "threads (default 1; 2 on a 2-core machine: one thread each scales better than two threads "
                        "on one run)")
    p.add_argument("--seeds", nargs="+", type=seed_int, default=[0, 1, 2],
                   help=f"training seeds, at least {MIN_SEEDS} (default: 0 1 2)")
    length = p.add_mutually_exclusive_group(required=True)
    length.add_argument("--max-steps", type=positive_int,
                        help="optimiser steps of every run (equal for all; as train --max-steps)")
    length.add_argument("--budget-minutes", type=positive_float,
                        help="wall minutes of every run (equal time, as train --budget-minutes: each config takes "
                             "the steps its speed allows)")
    p.add_argument("--baselines", nargs="*", type=baseline_spec, default=None,
                   help="seedless baselines in the tables: tfp, tfi, stp, snm (the traditional STP and SNM), black, "
                        "mean, tfp:N (TFP over N steps, an odd "
                        "number of windows: the span a network sees, e.g. tfp:205 for K = 5) (default: tfp tfi)")
    p.add_argument("-o", "--out", type=output_dir, required=True, help="folder for the runs and the tables (compare.md/.csv/.json, metrics.md/.csv, study_NAME.md/.json "
                        "with --study); a file of those names that no earlier compare wrote there is refused")
    p.add_argument("--precision", choices=("bf16", "fp16", "fp32"),
                   help="training precision of every run (default: each config's, auto)")
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N or mps")
    add_threads_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="print the statistics over seeds as JSON instead of the tables")
    p.set_defaults(func=cmd_compare)
    return p


__all__ = ["cmd_compare", "add_parser", "config_spec", "data_spec", "baseline_spec",
           # the library's names, for callers of pipelines.compare
           "BASELINES", "COMPARE_FILES", "MIN_SEEDS", "SeedStat", "aggregate", "baseline_label", "check_samples",
           "difference_holds", "evaluate_runs", "markdown", "run_dir", "run_name", "seed_stat", "steps_per_run",
           "train_seeds", "write_comparison"]
