"""`spikesim tradeoff`: the command line of the speed/accuracy study (pipelines.tradeoff_study).

    spikesim tradeoff --scenes ball fan --light low normal --height 50 --width 80 --windows 3 -o out/tradeoff
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from pipelines.argtypes import (add_device_argument, add_threads_argument, bundled_scene, output_dir, positive_int,
                               seed_int)
from pipelines import tradeoff_study as tradeoff
from spikesim._optional import require
from pipelines.tradeoff_study import (DEFAULT_SCENES, KNOBS, StudyConfig, collect_gt_rows, collect_rows, run_study,
                               write_report)

log = logging.getLogger("pipelines.tradeoff_study")


# ---- command line ---------------------------------------------------------------------------------
def _side(text: str) -> int:
    """--height, --width: at least SSIM's 11-pixel window."""
    v = positive_int(text)
    if v < 11:
        raise argparse.ArgumentTypeError(f"must be >= 11 (SSIM's window), got {text}")
    return v


def _windows(text: str) -> int:
    """--windows: 1 to the 21 windows of an LLR sequence."""
    v = positive_int(text)
    if v > 21:
        raise argparse.ArgumentTypeError(f"must be at most 21 (the windows of an LLR sequence), got {text}")
    return v


def cmd_tradeoff(args: argparse.Namespace) -> int:
    if args.xml is not None and args.scenes:
        raise ValueError("give --scenes (bundled scenes) or --xml (your own), not both")
    if args.xml is not None:
        from spikesim.render.scene_files import SceneFiles
        SceneFiles.resolve(str(args.xml))  # a missing file is named before anything renders
    scenes = (str(args.xml),) if args.xml is not None else tuple(args.scenes or DEFAULT_SCENES)
    for flag, given in (("--scenes", scenes), ("--light", tuple(args.light))):
        twice = [v for i, v in enumerate(given) if v in given[:i]]
        if twice:  # every row appeared once per repeat in the tables (issue 40, round 5)
            raise ValueError(f"{flag}: {', '.join(dict.fromkeys(twice))} given twice (each is studied once)")
    cfg = StudyConfig.of(scenes=scenes, lights=tuple(args.light),
                      resolution=(args.height, args.width), windows=args.windows, ref_spp=args.ref_spp, gt_spp=args.gt_spp,
                      seed=args.seed, backend=args.backend, device=args.device, knobs=tuple(args.knobs),
                      repeats=args.repeats, gt_error_spp=tuple(args.gt_error_spp), seed_spp_values=tuple(args.seed_spp),
                      threads=args.threads)
    skipped = sorted({s for s in cfg.gt_error_spp if s >= cfg.gt_spp})
    if skipped:
        log.info("--gt-error-spp %s: not below --gt-spp %d, skipped", " ".join(map(str, skipped)), cfg.gt_spp)
    out = Path(args.out)
    require("matplotlib", "plot", "the trade study's plot")  # before any run, not after hours of them
    from spikesim.generation.lock import output_lock
    from spikesim.outputs import output_folder
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(out)  # a study written into a dataset (round eleven)
    if args.images is not None:
        check_outside_datasets(args.images, [], "--images")
    with output_folder(out), output_lock(out, "tradeoff", what="tradeoff run"):
        from spikesim.outputs import check_results_owned
        from pipelines.tradeoff_study import PARETO_PLOT, REPORT_FILES
        check_results_owned(out, ["study.json", *REPORT_FILES], "tradeoff")  # a user's files: refused before any run
        if args.images is not None:
            check_results_owned(Path(args.images), [PARETO_PLOT], "tradeoff", "--images")
        return _study(args, cfg, out)


def _study(args: argparse.Namespace, cfg: StudyConfig, out: Path) -> int:
    """The study in its folder, which this run holds."""
    if args.report_only:
        rows = collect_rows(cfg, out)
        if not rows:
            raise FileNotFoundError(f"{out}: no cached runs of these scenes and lights; run the study "
                                    "without --report-only first")
    else:
        from spikesim._drjit import resolve_device
        from spikesim.simulate import resolve_backend
        resolve_backend(cfg.backend)  # an unavailable backend or GPU fails before any rendering or writing
        resolve_device(cfg.device)
        rows = run_study(cfg, out, progress=not args.quiet)
    gt_rows = collect_gt_rows(cfg, out)
    write_report(rows, out, Path(args.images) if args.images is not None else None, gt_rows)
    if args.json:
        import json
        print(json.dumps([*rows, *gt_rows], indent=2, default=str))
    else:
        print((out / "tradeoff.md").read_text())
    log.info("wrote %s, %s and %s", out / "tradeoff.csv", out / "tradeoff.md", out / "tradeoff.png")
    return 0


def add_parser(subparsers: Any) -> None:
    p = subparsers.add_parser("tradeoff", help="measure each render/sensor knob's cost and error (docs/tradeoff.md)",
                              description=tradeoff.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", nargs="+", type=bundled_scene,
                   help="LLR scenes (default: all five)")
    p.add_argument("--xml", type=Path,
                   help="your own scene XML instead (with its lights.json for --light and its motion.json)")
    p.add_argument("--light", nargs="+", default=["low", "normal"], choices=("low", "normal"),
                   help="lighting conditions to study")
    p.add_argument("--height", type=_side, default=50, help="rows of camera and renders, pixels")
    p.add_argument("--width", type=_side, default=80, help="columns of camera and renders, pixels")
    p.add_argument("--windows", type=_windows, default=3, help="41-step windows around the sequence centre (3)")
    p.add_argument("--ref-spp", type=positive_int, default=64, help="samples per pixel of the reference (64)")
    p.add_argument("--gt-spp", type=positive_int, default=256, help="samples per pixel of the ground truth (256)")
    p.add_argument("--gt-error-spp", nargs="*", type=positive_int, default=[16, 64], metavar="SPP",
                   help="the ground truth's own error: ground truths at these samples per pixel against the "
                        "--gt-spp one (16 64; values >= --gt-spp are skipped; none: no such renders)")
    p.add_argument("--knobs", nargs="+", default=list(KNOBS), choices=KNOBS, help="the knobs to vary, one at a time")
    p.add_argument("--seed-spp", nargs="+", type=positive_int, default=[1, 2], metavar="SPP",
                   help="the seeds knob: at these samples per pixel, a render seed per step against one for all (1 2)")
    add_threads_argument(p)  # scoring the network (the reconstruction axis) runs on the CPU
    p.add_argument("--repeats", type=positive_int, default=3, help="simulation timing repeats (minimum kept)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the renders and the sensor")
    p.add_argument("--backend", default="auto", choices=("auto", "numpy", "llvm", "cuda"), help="the sensor backend")
    add_device_argument(p, sensor="backend")
    p.add_argument("-o", "--out", type=output_dir, default=Path("out/tradeoff"),
                   help="output folder (cache, CSV, Markdown, PNG)")
    p.add_argument("--images", type=output_dir, default=None, help="also write the plot as <DIR>/tradeoff_pareto.png")
    p.add_argument("--report-only", action="store_true", help="rebuild the tables and plot from the cache")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the table's rows as JSON")
    p.set_defaults(func=cmd_tradeoff)
