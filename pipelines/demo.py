"""`spikesim demo`: the main job on a small embedded default, end to end.

Renders a bundled scene (Mitsuba 3, physical lights) under normal and low light, streams the
frames through the realistic sensor into `.dat` files with ground truth (the LLR layout, small
preset), reconstructs every window with TFP and TFI (and a trained checkpoint if given), and
prints the PSNR/SSIM table and the streams' statistics; previews go next to the data.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from pipelines.argtypes import (add_device_argument, bundled_scene, existing_file, nonnegative_int, output_dir,
                                positive_int)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from model.methods import FLOORS, ModelMethod, method_from_spec
    from model.streaming import StepWindows
    from pipelines.evaluate import evaluate, json_safe, markdown_table, scores_json, write_results
    from spikesim.generation import PRESETS, generate, plan_llr
    from spikesim.dataset import open_dataset
    from spikesim.imageio import write_png
    from spikesim._drjit import resolve_device
    from spikesim.stats import dark_pixel_fraction

    out = Path(args.out)
    device = resolve_device(args.device)  # an unavailable GPU fails before any work
    # the methods first: a checkpoint that does not load fails now, not after the rendering
    methods = [method_from_spec(m) for m in ("tfp", "tfi", *FLOORS)]
    if args.checkpoint is not None:  # not through a spec: a path may contain "=" (runs/lr=1e-3/best.pt)
        methods.append(ModelMethod(args.checkpoint.parent.name or args.checkpoint.stem, args.checkpoint))
    preset = dataclasses.replace(PRESETS["small"], llr_windows=args.windows)
    t0 = time.perf_counter()
    jobs = plan_llr(preset, seed=args.seed, scenes=args.scenes)
    print(f"[demo] rendering {', '.join(j.name for j in jobs)} at {preset.width}x{preset.height}, "
          f"{jobs[0].num_steps} steps each, and simulating the realistic sensor on {device} ...", file=sys.stderr)
    generate(jobs, out / "llr", workers=args.workers, info={"kind": "demo"}, show_progress=not args.quiet,
             device=device)
    scenes = open_dataset(out / "llr")
    t_gen = time.perf_counter() - t0
    for sc in scenes:
        s = sc.stream()
        rate = s.counts().mean() / s.num_steps
        print(f"[demo] {sc.name:<12} mean rate {rate:.4f} spikes/step, "
              f"{dark_pixel_fraction(s, 41):.1%} of pixels without a spike per 41-step window", file=sys.stderr)
    rows = evaluate(scenes, methods, 41, progress=False)
    names = [m.name for m in methods]
    write_results(rows, names, out)
    if args.json:
        print(json.dumps(json_safe(scores_json(rows, names, {"data": str(out / "llr")})), indent=2))
    else:
        print(markdown_table(rows, names))
    # previews of the middle window: ground truth and each method, scaled to the scene's
    # brightest ground-truth value (so low light looks dark, as it is)
    for sc in scenes:
        c = sc.gt_steps[len(sc.gt_steps) // 2]
        gt = sc.ground_truth(c)
        scale = 1.0 / max(float(np.percentile(gt, 99.5)), 1e-6)
        write_png(out / "previews" / f"{sc.name}_gt.png", gt, scale=scale)
        src = StepWindows(sc.spikes, c - 20, 41, 1)
        for m in (m for m in methods if getattr(m, "kind", None) not in FLOORS):  # the floors show nothing
            (_, frame), = list(m.frames(src))
            write_png(out / "previews" / f"{sc.name}_{m.name}.png", np.asarray(frame), scale=scale)
    print(f"[demo] done in {time.perf_counter() - t0:.0f} s (rendering and simulation {t_gen:.0f} s); "
          f"data in {out / 'llr'}, table in {out / 'metrics.md'}, previews in {out / 'previews'}", file=sys.stderr)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="render a scene, simulate its spike stream and reconstruct it, end to end")
    p.add_argument("-o", "--out", type=output_dir, default=Path("out/demo"), help="output folder (dataset, tables, images)")
    p.add_argument("--scenes", nargs="+", type=bundled_scene, default=["fan"],
                   help="bundled scenes (ball, car, cook, fan, rotate)")
    p.add_argument("--windows", type=positive_int, default=3, help="41-step windows per scene")
    p.add_argument("--checkpoint", type=existing_file,
                   help="also reconstruct with a trained model (a train run's best.pt)")
    p.add_argument("--workers", type=positive_int, default=None,
                   help="worker processes (default: one per core; one with a GPU)")
    add_device_argument(p)
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of the sensor's noise and fixed patterns")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="print the scores as JSON (evaluate's layout) instead of the table")
    p.set_defaults(func=run)
