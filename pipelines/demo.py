"""`spikesim demo`: the main job on a small embedded default, end to end.

Renders a bundled scene (Mitsuba 3, physical lights) under normal and low light, streams the
frames through the realistic sensor into `.dat` files with ground truth (the LLR layout, small
preset), reconstructs every window with TFP, TFI, TFP over the shipped network's span and the shipped
network (and a trained checkpoint if given), and
prints the table (aligned PSNR and SSIM first: the metrics no image without structure can win)
and the streams' statistics; previews go next to the data.

    spikesim demo                       # Fan, 64 x 100, normal and low light, 5 windows each
    spikesim demo --scenes ball car -o out/demo2 --no-model
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from pipelines.argtypes import (seed_int, add_device_argument, bundled_scene, existing_file, output_dir,
                                positive_int)


#: Below this many spikes per pixel over a reconstruction's span, the demo says that fine detail
#: cannot be shown: a pixel that fired once or twice carries almost no texture (Fan at 3.5 lx and
#: 100 x 64: 0.76 spikes per pixel over 205 steps).
FEW_SPIKES_PER_PIXEL = 3.0


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from model.methods import FLOORS, PRETRAINED_METHOD, ModelMethod, method_from_spec
    from model.streaming import StepWindows
    from model.evaluation import evaluate, evaluation_run, json_safe, markdown_table, scores_json, write_results
    from spikesim.generation import PRESETS, generate, job_status, plan_llr
    from spikesim.dataset import open_dataset
    from spikesim.imageio import write_png
    from spikesim._drjit import resolve_device
    from spikesim.dataset import check_outside_datasets
    from spikesim.outputs import check_results_owned, make_dirs, recorded_results, results_writing, writable
    from model.evaluation import RESULT_FILES
    from spikesim.stats import dark_pixel_fraction

    out = Path(args.out)
    for name in ("llr", "previews", "metrics.csv", "metrics.md"):  # a link where the demo writes: refused now
        writable(out, name)
    device = resolve_device(args.device)  # an unavailable GPU fails before any work
    # the methods first: a checkpoint that does not load fails now, not after the rendering
    models = [] if args.no_model else [method_from_spec(PRETRAINED_METHOD)]
    if args.checkpoint is not None:  # not through a spec: a path may contain "=" (runs/lr=1e-3/best.pt)
        models.append(ModelMethod(args.checkpoint.parent.name or args.checkpoint.stem, args.checkpoint))
    # TFP over the span each network saw in training: what plain counting makes of the same steps
    spans = sorted({m.span for m in models})
    methods = [method_from_spec(m) for m in ("tfp", "tfi", *(f"tfp:{n}" for n in spans), *FLOORS)] + models
    preset = dataclasses.replace(PRESETS["small"], llr_windows=args.windows)
    t0 = time.perf_counter()
    jobs = plan_llr(preset, seed=args.seed, scenes=args.scenes)
    # the tables and previews this run writes: a user's metrics.md in -o was replaced (round ten)
    results = [*RESULT_FILES, *(f"previews/{j.name}_{kind}_p99.png" for j in jobs
                                for kind in ("gt", *(m.name for m in methods if m.name not in FLOORS)))]
    ours = check_results_owned(out, results, "demo")
    # an earlier run's previews of scenes or methods this run does not draw (round eleven)
    earlier = [name for name in recorded_results(out, "demo") if name not in results]
    check_outside_datasets(out, [], "-o")
    todo = [j.name for j in jobs if job_status(j, out / "llr") != "done"]
    if todo:
        print(f"[demo] rendering {', '.join(todo)} at {preset.width}x{preset.height}, {jobs[0].num_steps} steps "
              f"each, and simulating the realistic sensor on {device} ...", file=sys.stderr)
    else:
        print(f"[demo] {', '.join(j.name for j in jobs)}: already rendered and simulated in {out / 'llr'}",
              file=sys.stderr)
    generate(jobs, out / "llr", workers=args.workers, info={"kind": "demo"}, show_progress=not args.quiet,
             device=device, overwrite_stale=args.overwrite)
    # the scenes of this run only: -o/llr keeps every scene an earlier demo made there, and those
    # were scored and drawn over the user's files too (round eleven)
    asked = {j.name for j in jobs}
    scenes = [sc for sc in open_dataset(out / "llr") if sc.name in asked]
    t_gen = time.perf_counter() - t0
    for sc in scenes:
        s = sc.stream()
        rate = s.counts().mean() / s.num_steps
        print(f"[demo] {sc.name:<12} mean rate {rate:.4f} spikes/step, "
              f"{dark_pixel_fraction(s, 41):.1%} of pixels without a spike per 41-step window", file=sys.stderr)
        span = max(spans, default=41)
        if rate * span < FEW_SPIKES_PER_PIXEL:
            print(f"[demo] {sc.name}: {rate * span:.1f} spikes per pixel over the {span} steps a reconstruction "
                  "draws on: too few to show fine detail such as a fan's blades, whatever the method (its preview "
                  "shows the large shapes those spikes allow)", file=sys.stderr)
    rows = evaluate(scenes, methods, 41, progress=False)
    names = [m.name for m in methods]
    # checked again (a file put there while it rendered); the earlier run's results removed first,
    # with its previews of scenes this run does not draw (round eleven), and each new one recorded
    # as it is written: a demo stopped while drawing left results every rerun refused (round twelve)
    with results_writing(out, results, "demo", stale=[*ours, *earlier]):
        write_results(rows, names, out)
        if args.json:
            print(json.dumps(json_safe(scores_json(rows, names, {"data": str(out / "llr")})), indent=2))
        else:
            print(markdown_table(rows, names))
        # previews of the middle window of each scene's run (a network sees the whole run, as in the
        # table): every image stretched to its own 99.5th percentile, so a person sees what each method
        # made, dark or bright (a shared scale shows low-light TFP black and TFI white)
        make_dirs(out, "previews")
        for sc in scenes:
            first, n = evaluation_run(sc, 41)
            mid = n // 2
            write_png(writable(out, "previews", f"{sc.name}_gt_p99.png"), sc.ground_truth(first + mid * 41),
                      percentile=99.5)
            src = StepWindows(sc.spikes, first - 20, 41, n)
            for m in (m for m in methods if m.name not in FLOORS):  # the floors show nothing
                frame = next(f for i, f in m.frames(src) if i == mid)
                write_png(writable(out, "previews", f"{sc.name}_{m.name}_p99.png"), np.asarray(frame),
                          percentile=99.5)
    print(f"[demo] done in {time.perf_counter() - t0:.0f} s (rendering and simulation {t_gen:.0f} s); "
          f"data in {out / 'llr'}, table in {out / 'metrics.md'}, previews in {out / 'previews'} (each image "
          "stretched to its own 99.5th percentile: _p99)", file=sys.stderr)
    return 0



def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="render a scene, simulate its spike stream and reconstruct it, end to end",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-o", "--out", type=output_dir, default=Path("out/demo"), help="output folder (dataset, tables, images)")
    p.add_argument("--scenes", nargs="+", type=bundled_scene, default=["fan"],
                   help="bundled scenes (ball, car, cook, fan, rotate)")
    p.add_argument("--windows", type=positive_int, default=5,
                   help="41-step windows per scene (default 5: the shipped network's span, so it and TFP over that "
                        "span see every window they were made for)")
    p.add_argument("--checkpoint", type=existing_file,
                   help="also reconstruct with a trained model (a train run's best.pt)")
    p.add_argument("--no-model", action="store_true",
                   help="leave the shipped network (lrrep) out: baselines only")
    p.add_argument("--workers", type=positive_int, default=None,
                   help="worker processes (default: one per core; one with a GPU)")
    add_device_argument(p)
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the sensor's noise and fixed patterns")
    p.add_argument("--overwrite", action="store_true",
                   help="rebuild scenes an earlier demo in -o made with another --seed or --windows (refused without it)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="print the scores as JSON (evaluate's layout) instead of the table")
    p.set_defaults(func=run)
