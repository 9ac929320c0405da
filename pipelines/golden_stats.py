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

from pipelines.argtypes import seed_int, camera_spec, existing_file, load_camera, output_file_in, positive_int
from spikesim import golden


def _camera(args: argparse.Namespace):
    """The --camera to measure; a size other than a saved camera's (250 x 400) or the test
    scene's is refused: golden measures every camera on its own test scene, so a camera file's
    height and width are not used, and silently ignoring 10^6 rows would hide the mistake."""
    from spikesim.camera import SpikeCamera

    camera = load_camera(args.camera)
    default = SpikeCamera()
    if (camera.height, camera.width) not in ((default.height, default.width), (golden.HEIGHT, golden.WIDTH)):
        raise ValueError(f"--camera {args.camera}: height {camera.height}, width {camera.width} would not be used: "
                         f"golden measures every camera on its own {golden.HEIGHT} x {golden.WIDTH} test scene; "
                         "remove height and width from the file")
    return camera


def _backend(name: str) -> str:
    from spikesim.simulate import resolve_backend

    return resolve_backend(name)  # before measuring: a missing GPU is one line


#: Why a statistic has no value: what the golden statistics need and a camera may not give.
UNDEFINED = "cannot be computed: too few spikes or intervals in this band"


def _table(rows: list[golden.Row], z_crit: float) -> str:
    lines = [f"{'band':8} {'statistic':17} {'value':>12} {'reference':>12} {'z':>8}  verdict (|z| <= {z_crit:.2f})"]
    for r in rows:
        if not math.isfinite(r.value):  # said in words, not "nan" and "z inf"
            lines.append(f"{r.band:8} {r.statistic:17} {'undefined':>12} {r.reference:12.6g} {'n/a':>8}  "
                         f"FAIL ({UNDEFINED})")
            continue
        lines.append(f"{r.band:8} {r.statistic:17} {r.value:12.6g} {r.reference:12.6g} {r.z:8.2f}  "
                     f"{'pass' if r.passed else 'FAIL'}")
    return "\n".join(lines)


def _check(args: argparse.Namespace) -> int:
    reference = golden.load_reference(args.reference)  # a missing or damaged file fails before measuring
    golden.check_design(reference)
    if args.seed in golden.reference_seeds(reference):
        raise ValueError(f"--seed {args.seed} is one of the reference's seeds {golden.reference_seeds(reference)}: "
                         "the check would replay the reference, not test it")
    measured = golden.measure(_camera(args), _backend(args.backend), args.seed)
    rows = golden.compare(measured, reference)
    z_crit = golden.reference_z_critical(reference)
    failed = [r for r in rows if not r.passed]
    if args.json:
        print(json.dumps({"reference": str(args.reference or golden.PACKAGED_REFERENCE), "backend": measured["backend"],
                          "seed": args.seed, "z_critical": z_crit, "family_false_alarm": golden.FAMILY_FALSE_ALARM,
                          "passed": not failed,
                          "statistics": [{"band": r.band, "statistic": r.statistic, "value": _num(r.value),
                                          "reference": r.reference, "z": _num(r.z), "passed": r.passed,
                                          **({} if math.isfinite(r.value) else {"note": UNDEFINED})}
                                         for r in rows]}, indent=2))
    else:
        print(_table(rows, z_crit))
        print(f"golden statistics: {'OK' if not failed else f'{len(failed)} of {len(rows)} statistic(s) moved'} "
              f"(reference {args.reference or golden.PACKAGED_REFERENCE}, backend {measured['backend']}, seed {args.seed})")
    return 1 if failed else 0


def _num(x: float) -> Any:
    return x if math.isfinite(x) else str(x)


def _write(args: argparse.Namespace) -> int:
    from spikesim.progress import progress_bar

    from spikesim.outputs import check_not_link, check_results_owned, results_writing

    check_not_link(args.output)  # a link at -o is refused before the measurement, not after
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(args.output)  # a reference written into a dataset (round eleven)
    out = Path(args.output)
    check_results_owned(out.parent, [out.name], "golden")  # a user's JSON there is refused, not replaced (round eight)
    camera, backend = _camera(args), _backend(args.backend)
    count = args.seeds if args.seeds is not None else len(golden.REFERENCE_SEEDS)
    if count > golden.MEASURE_SEED:  # checked before the list: 10^9 seeds were listed and measured (round eight)
        raise ValueError(f"--seeds {count}: at most {golden.MEASURE_SEED} (seed {golden.MEASURE_SEED} is the check's)")
    seeds = list(range(count))
    with progress_bar(total=len(seeds), desc="golden reference", unit="seed", quiet=args.json) as bar:
        reference = golden.measure_reference(camera, backend, seeds, progress=bar)
    # checked again (a file put there while it measured: round ten), recorded as it is written (round twelve)
    with results_writing(out.parent, [out.name], "golden"):
        path = golden.write_reference(reference, args.output)
    if args.json:
        print(json.dumps({"wrote": str(path), "backend": reference["backend"], "seeds": seeds,
                          "statistics": sum(len(e) for e in reference["stats"].values())}, indent=2))
        return 0
    print(f"wrote {path} ({sum(len(e) for e in reference['stats'].values())} statistics, backend "
          f"{reference['backend']}, seeds {seeds[0]}..{seeds[-1]})", file=sys.stderr)
    return 0


def _power(args: argparse.Namespace) -> int:
    from spikesim.progress import progress_bar

    reference = golden.load_reference(args.reference)
    golden.check_design(reference)
    seeds = golden.power_seeds(args.seeds if args.seeds is not None else 4)
    cam = _camera(args)
    cells = sum(golden.changed(cam, t, c) is not None for t in golden.POWER_TERMS for c in golden.POWER_CHANGES)
    total = len(seeds) * (1 + cells)
    with progress_bar(total=total, desc="golden power", unit="run", quiet=args.json) as bar:
        result = golden.detection_power(reference, cam, _backend(args.backend), seeds, progress=bar)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(_power_table(result))
    print(f"\nunchanged camera: failed at {result['unchanged']['detected']:.0%} of {len(seeds)} seeds "
          f"(median largest |z| {result['unchanged']['median_max_abs_z']:.1f}; family false-alarm rate by "
          f"design {golden.FAMILY_FALSE_ALARM:g})")
    return 0


def _power_table(result: dict[str, Any]) -> str:
    """Markdown: per term and change, the share of seeds that failed and (in brackets) the median
    largest |z| against the threshold."""
    changes = list(next(iter(result["terms"].values())))
    lines = [f"detection rate over {len(result['seeds'])} seeds (median largest |z|; threshold "
             f"{result['z_critical']:.2f}), backend {result['backend']}", "",
             "| term | " + " | ".join(changes) + " | largest z in |", "|---|" + "---|" * (len(changes) + 1)]
    for term, by in result["terms"].items():
        cells = ["n/a" if v is None else f"{v['detected']:.0%} ({v['median_max_abs_z']:.1f})" for v in by.values()]
        first = next((v["failing"] for v in (by.get("+20%"), by.get("+100%")) if v and v["failing"]), "-")
        lines.append(f"| {term} | " + " | ".join(cells) + f" | {first} |")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.write and args.output is None:
        raise ValueError("--write needs -o REF.json (the project's own reference is replaced only by naming it)")
    if args.output is not None and not args.write:
        raise ValueError("-o goes with --write")
    if args.seeds is not None and not (args.write or args.power):  # it was ignored (round fourteen)
        raise ValueError(f"--seeds {args.seeds} goes with --write (the reference's seeds) or --power (seeds per "
                         "change); a check measures one seed, --seed")
    if args.write:
        return _write(args)
    return _power(args) if args.power else _check(args)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("golden", help="check a camera's spike statistics against a stored reference",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--camera", type=camera_spec, default="realistic",
                   help="realistic, measured, noiseless, scsim or a JSON/TOML camera file (spikesim.camera.SpikeCamera fields)")
    p.add_argument("--reference", type=existing_file,
                   help=f"reference to compare with (default: the project's, {golden.PACKAGED_REFERENCE.name})")
    p.add_argument("--backend", default="numpy", choices=["numpy", "llvm", "cuda", "auto"],
                   help="simulator backend to measure with (default: numpy, the reference's)")
    p.add_argument("--seed", type=seed_int, default=golden.MEASURE_SEED,
                   help="seed of the check's measurement; refused if the reference used it (references use "
                        "0 .. N-1 for --seeds N)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true",
                      help="measure and write a new reference to -o (the mean over --seeds replicate seeds)")
    mode.add_argument("--power", action="store_true",
                      help="measure the check's detection rate for changes of each noise term")
    p.add_argument("-o", "--output", type=output_file_in("golden_stats.json"),
                   help="with --write: the reference file to write (written whole: temporary file, then rename; "
                        "a folder: golden_stats.json in it)")
    p.add_argument("--seeds", type=positive_int,
                   help=f"with --write: replicate seeds of the reference (default {len(golden.REFERENCE_SEEDS)}); "
                        "with --power: seeds per change (default 4)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=run)


__all__ = ["add_parser", "run"]
