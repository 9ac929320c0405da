"""`spikesim golden`: check a camera model's spike statistics against a stored reference.

Without options it checks the built-in realistic camera against the project's reference. With
`--camera FILE` it checks your camera (or, unchanged, your changed simulator code) against the
project's reference or your own (`--reference`); `--write --camera FILE -o REF.json` stores a new
reference; `--power` measures which change of each noise term the check detects
(spikesim/golden.py says what the statistics are and why; docs/sensor.md has the table).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from pipelines.argtypes import camera_spec, existing_file, load_camera, positive_int
from spikesim import golden


def _camera(args: argparse.Namespace):
    return load_camera(args.camera)


def _backend(name: str) -> str:
    from spikesim.simulate import resolve_backend

    return resolve_backend(name)  # before measuring: a missing GPU is one line


def _table(rows: list[golden.Row], z_crit: float) -> str:
    lines = [f"{'band':8} {'statistic':17} {'value':>12} {'reference':>12} {'z':>8}  verdict (|z| <= {z_crit:.2f})"]
    for r in rows:
        lines.append(f"{r.band:8} {r.statistic:17} {r.value:12.6g} {r.reference:12.6g} {r.z:8.2f}  "
                     f"{'pass' if r.passed else 'FAIL'}")
    return "\n".join(lines)


def _check(args: argparse.Namespace) -> int:
    reference = golden.load_reference(args.reference)  # a missing or damaged file fails before measuring
    measured = golden.measure(_camera(args), _backend(args.backend), args.seed)
    rows = golden.compare(measured, reference)
    z_crit = golden.z_critical(len(rows))
    failed = [r for r in rows if not r.passed]
    if args.json:
        print(json.dumps({"reference": str(args.reference or golden.PACKAGED_REFERENCE), "backend": measured["backend"],
                          "seed": args.seed, "z_critical": z_crit, "family_false_alarm": golden.FAMILY_FALSE_ALARM,
                          "passed": not failed,
                          "statistics": [{"band": r.band, "statistic": r.statistic, "value": _num(r.value),
                                          "reference": r.reference, "z": _num(r.z), "passed": r.passed}
                                         for r in rows]}, indent=2))
    else:
        print(_table(rows, z_crit))
        print(f"golden statistics: {'OK' if not failed else f'{len(failed)} of {len(rows)} statistic(s) moved'} "
              f"(reference {args.reference or golden.PACKAGED_REFERENCE}, backend {measured['backend']}, seed {args.seed})")
    return 1 if failed else 0


def _num(x: float) -> Any:
    return x if math.isfinite(x) else str(x)


def _write(args: argparse.Namespace) -> int:
    measured = golden.measure(_camera(args), _backend(args.backend), golden.REFERENCE_SEED)
    path = golden.write_reference(measured, args.output)
    print(f"wrote {path} ({sum(len(e) for e in measured['stats'].values())} statistics, backend "
          f"{measured['backend']}, seed {golden.REFERENCE_SEED})", file=sys.stderr)
    return 0


def _power(args: argparse.Namespace) -> int:
    from spikesim.progress import progress_bar

    reference = golden.load_reference(args.reference)
    seeds = list(range(1, args.seeds + 1))
    total = len(seeds) * (1 + len(golden.POWER_TERMS) * len(golden.POWER_CHANGES))
    with progress_bar(total=total, desc="golden power", unit="run", quiet=args.json) as bar:
        result = golden.detection_power(reference, _camera(args), _backend(args.backend), seeds, progress=bar)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    changes = list(next(iter(result["terms"].values())))
    print("| term | " + " | ".join(changes) + " |")
    print("|---|" + "---|" * len(changes))
    for term, by in result["terms"].items():
        print(f"| {term} | " + " | ".join(f"{v['detected']:.0%}" for v in by.values()) + " |")
    print(f"\nunchanged camera: failed at {result['unchanged']['detected']:.0%} of {len(seeds)} seeds "
          f"(family false-alarm rate by design {golden.FAMILY_FALSE_ALARM:g})")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.write and args.output is None:
        raise ValueError("--write needs -o REF.json (the project's own reference is replaced only by naming it)")
    if args.output is not None and not args.write:
        raise ValueError("-o goes with --write")
    if args.write:
        return _write(args)
    return _power(args) if args.power else _check(args)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("golden", help="check a camera's spike statistics against a stored reference",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--camera", type=camera_spec, default="realistic",
                   help="realistic, noiseless or a JSON/TOML camera file (spikesim.camera.SpikeCamera fields)")
    p.add_argument("--reference", type=existing_file,
                   help=f"reference to compare with (default: the project's, {golden.PACKAGED_REFERENCE.name})")
    p.add_argument("--backend", default="numpy", choices=["numpy", "llvm", "cuda", "auto"],
                   help="simulator backend to measure with (default: numpy, the reference's)")
    p.add_argument("--seed", type=int, default=golden.MEASURE_SEED,
                   help=f"measurement seed (default: {golden.MEASURE_SEED}; references use {golden.REFERENCE_SEED})")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="measure and write a new reference to -o")
    mode.add_argument("--power", action="store_true",
                      help="measure the check's detection rate for changes of each noise term")
    p.add_argument("-o", "--output", type=Path, help="with --write: the reference file to write")
    p.add_argument("--seeds", type=positive_int, default=4, help="with --power: seeds per change (default: 4)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=run)


__all__ = ["add_parser", "run"]
