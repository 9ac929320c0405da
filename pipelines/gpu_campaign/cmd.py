"""`spikesim gpu-campaign`: every GPU measurement and a training run in one device call (or two)
(the run is pipelines/gpu_campaign/runner.py, the stages pipelines/gpu_campaign/stages.py;
docs/gpu_campaign.md says how to run it). This module only parses and prints.
`scripts/gpu_campaign.sh` runs it as `python -m pipelines.gpu_campaign.cmd`, which needs nothing
beyond the standard library to start: the packages a lent machine lacks are installed by the
campaign's first stage.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from pipelines.argtypes import seed_int, output_dir, positive_float, positive_int

DESCRIPTION = __doc__ + """
On a lent GPU, from the repository root, with .whl (scripts/gpu_wheels.sh) carried:
  scripts/gpu_campaign.sh               # part one, 9 minutes: install, bench, LLR, 1-2 RLLR scenes,
                                        # a short `full` bf16 training, its weights; gpu tests,
                                        # evaluate and table1 only where time is left
The Table-1 networks at their published sizes, at equal training FLOP, in a call of their own:
  scripts/gpu_campaign.sh --stages install llr rllr table1
For a longer lease, two calls:
  scripts/gpu_campaign.sh --part 1      # install, gpu tests, bench, LLR, an RLLR slice
  scripts/gpu_campaign.sh --part 2      # train `full` in bf16 on it, evaluate on LLR, weights
Rehearsal on the CPU (tiny sizes, the same stages and files):
  scripts/gpu_campaign.sh --dry-run -o out/campaign
"""


def _injection(text: str) -> tuple[str, str]:
    """argparse type: STAGE=fail or STAGE=timeout."""
    from pipelines.gpu_campaign.options import INJECTIONS, STAGE_NAMES

    stage, sep, what = text.partition("=")
    if not sep or stage not in STAGE_NAMES or what not in INJECTIONS:
        raise argparse.ArgumentTypeError(f"{text!r}: expected STAGE=fail or STAGE=timeout, STAGE one of "
                                         f"{', '.join(STAGE_NAMES)}")
    return stage, what


def options_from_args(args: argparse.Namespace):
    from pipelines.gpu_campaign.options import PROFILES, ROOT, Options

    out = args.out if args.out is not None else (Path(os.environ["OUT"]) if os.environ.get("OUT") else None)
    if out is None:
        raise ValueError("gpu-campaign needs -o/--out (or $OUT, as on a lent machine)")
    profile = PROFILES["dry-run" if args.dry_run else "gpu"]
    work = args.work if args.work is not None else ROOT / "runs" / ("gpu_campaign_dry" if args.dry_run else "gpu_campaign")
    # every path absolute before it is handed on: the stages run from the repository, not the user's folder
    out, work = Path(out).resolve(), Path(work).resolve()
    wheels = Path(args.wheels).resolve() if args.wheels else ROOT / ".whl"
    deadline_s = None if args.deadline_minutes is None else 60.0 * args.deadline_minutes  # None: the part's
    return Options(out=out, work=work, profile=profile, part=args.part, stages=tuple(args.stages or ()),
                   deadline_s=deadline_s, wheels=wheels, seed=args.seed,
                   rllr_count=args.rllr_count, inject=dict(args.inject or ()), fresh=args.fresh)


def cmd_gpu_campaign(args: argparse.Namespace) -> int:
    from pipelines.gpu_campaign.runner import run_campaign

    options = options_from_args(args)
    summary = run_campaign(options, progress=None if args.quiet else lambda text: print(text, file=sys.stderr,
                                                                                         flush=True))
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        for s in summary["stages"]:
            note = f"  ({s['note']})" if s.get("note") else ""
            print(f"{s['name']:<13} {s['status']:<8} {s['seconds']:8.1f} s{note}")
        c = summary["counts"]
        print(f"{options.out}: summary.json, logs.txt, report.md{' and weights' if any(f['name'].startswith('weights') for f in summary['files']) else ''}; "
              f"{c['ok']} ok, {c['failed']} failed, {c['timeout']} timed out, {c['skipped']} skipped, "
              f"{summary['seconds']:.0f} s")
    # the campaign ran to its end whatever its stages did: their statuses are in the summary
    return 0


def minutes_in_a_day(text: str) -> float:
    """A deadline in minutes, at most a day (1e307 minutes became "inf" seconds)."""
    v = positive_float(text)
    if v > 24 * 60:
        raise argparse.ArgumentTypeError(f"at most a day ({24 * 60} minutes), got {text}")
    return v


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from pipelines.gpu_campaign.options import DEFAULT_PART, PART_DEADLINE_S, PARTS, STAGE_NAMES

    p = sub.add_parser("gpu-campaign", help="every GPU measurement and a training run, each stage time-boxed, "
                                            "into at most 8 files (--dry-run: rehearse on the CPU)",
                       description=DESCRIPTION)
    p.add_argument("-o", "--out", type=output_dir,
                   help="folder for summary.json, logs.txt, report.md and the weights (default: $OUT)")
    p.add_argument("--work", type=output_dir,
                   help="scratch folder: datasets, the training run, the logs, the records a second call continues "
                        "(default: runs/gpu_campaign, runs/gpu_campaign_dry with --dry-run)")
    p.add_argument("--dry-run", action="store_true",
                   help="every stage on the CPU (Dr.Jit LLVM, torch CPU) at a tiny size, into the same files")
    p.add_argument("--part", choices=list(PARTS), default=DEFAULT_PART,
                   help="one (default): every stage in one call, in order of value (install, bench, LLR, 1-2 RLLR "
                        "scenes, train, export; gpu tests, evaluate and table1 only where time is left); for a longer "
                        "lease, 1: install, gpu tests, bench, LLR, RLLR slice; 2: install, train, evaluate, export "
                        "(remaking a dataset the machine lost), then table1 where time is left; all: every stage in "
                        "stage order")
    p.add_argument("--stages", nargs="+", choices=STAGE_NAMES, metavar="STAGE",
                   help=f"only these of the part's stages ({', '.join(STAGE_NAMES)})")
    deadlines = ", ".join(f"{k}: {v / 60:g}" for k, v in PART_DEADLINE_S.items())
    p.add_argument("--deadline-minutes", type=minutes_in_a_day, default=None,
                   help="wall-clock minutes this call may take in all; each stage's box is cut to leave the later "
                        f"stages their least (default by part, {deadlines}: a device call is killed at 10, and "
                        "this leaves a stage's 20 s of grace and the last writes)")
    p.add_argument("--wheels", type=Path, help="the folder scripts/gpu_wheels.sh filled (default: .whl)")
    p.add_argument("--rllr-count", type=positive_int,
                   help="RLLR scenes to make (default: 2 in part one, 10 in the others on a GPU, 2 with --dry-run; "
                        "fewer if the box ends first)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the datasets and of training")
    p.add_argument("--fresh", action="store_true",
                   help="forget the stage records an earlier call left in the work folder")
    p.add_argument("--inject", type=_injection, action="append", metavar="STAGE=fail|timeout",
                   help="replace a stage's work by a failure or a hang (to test that later stages still run); "
                        "repeatable")
    p.add_argument("--json", action="store_true", help="print summary.json on stdout")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_gpu_campaign)
    return p


if __name__ == "__main__":
    from pipelines.cli import main

    sys.exit(main(["gpu-campaign", *sys.argv[1:]]))
