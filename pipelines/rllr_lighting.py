"""The RLLR lighting study: how much light the random scenes get, and how much of their ground truth
lies above the sensor's saturation (y > 1 spike per step), measured on the scenes
`spikesim generate rllr` plans.

For each planned scene (same seeds, same random scene, same darkening factor as `generate`) it
renders the ground truth at a few steps, at a reduced resolution and sample count, through the
generator's own frame source, and reports the illuminance at the subject after darkening (the
lamps' level times the factor) and the fraction of ground-truth pixels above saturation. The
saturated fraction does not depend on the resolution beyond pixel sampling; the reduced size keeps
the paper-size set (100 scenes) within about 10 minutes of one CPU. docs/scenes.md reports it:

    python -m pipelines.rllr_lighting --preset paper --out results/rllr_lighting.json
    python -m pipelines.rllr_lighting --preset paper --lamps-lux 100 1000   # the range before
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from pipelines.argtypes import seed_int, nonnegative_int, output_file, positive_float, positive_int
from spikesim import outputs

#: Illuminance at the subject of the LLR scenes' lighting conditions (docs/scenes.md, section 2).
LLR_LOW_LUX = (3.5, 10.0)
LLR_NORMAL_LUX = (100.0, 400.0)
SATURATION_WARN = 0.01


def scene_record(name: str, y: np.ndarray, lamps_lux: float, factor: float, saturation_y: float = 1.0) -> dict[str, Any]:
    """One scene's line of the study: its light and how much of its ground truth `y` (frames,
    already darkened) lies above `saturation_y`."""
    y = np.asarray(y, dtype=np.float64)
    return {"name": name, "lamps_lux": float(lamps_lux), "factor": float(factor),
            "subject_lux": float(lamps_lux * factor), "pixels": int(y.size),
            "saturated_fraction": float(np.mean(y > saturation_y)),
            "y_median": float(np.median(y)), "y_p99": float(np.percentile(y, 99)), "y_max": float(y.max())}


def summarise(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The distribution over scenes: illuminance at the subject and saturated fraction (pooled over
    every pixel of every scene, and per scene)."""
    lux = np.array([r["subject_lux"] for r in records])
    sat = np.array([r["saturated_fraction"] for r in records])
    pixels = np.array([r["pixels"] for r in records], dtype=np.float64)
    q = [0, 5, 25, 50, 75, 95, 100]
    return {
        "scenes": len(records),
        "subject_lux_percentiles": dict(zip((f"p{p}" for p in q), np.percentile(lux, q).round(3).tolist())),
        "share_at_or_below_llr_low": float(np.mean(lux <= LLR_LOW_LUX[1])),
        "share_in_llr_low": float(np.mean((lux >= LLR_LOW_LUX[0]) & (lux <= LLR_LOW_LUX[1]))),
        "share_in_llr_normal": float(np.mean((lux >= LLR_NORMAL_LUX[0]) & (lux <= LLR_NORMAL_LUX[1]))),
        "saturated_fraction_pooled": float(np.sum(sat * pixels) / np.sum(pixels)),
        "saturated_fraction_percentiles": dict(zip((f"p{p}" for p in q), np.percentile(sat, q).round(5).tolist())),
        "scenes_above_1_percent": int(np.sum(sat > SATURATION_WARN)),
        "scenes_with_any_saturation": int(np.sum(sat > 0)),
    }


def markdown(summary: dict[str, Any]) -> str:
    """The summary as the two small tables docs/scenes.md shows."""
    lux, sat = summary["subject_lux_percentiles"], summary["saturated_fraction_percentiles"]
    keys = list(lux)
    lines = ["| | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys),
             "| illuminance at the subject (lx) | " + " | ".join(f"{lux[k]:.3g}" for k in keys) + " |",
             "| saturated GT pixels | " + " | ".join(f"{100 * sat[k]:.2f} %" for k in keys) + " |", "",
             f"- scenes: {summary['scenes']}; saturated pixels pooled over all scenes: "
             f"{100 * summary['saturated_fraction_pooled']:.3f} %",
             f"- scenes above 1 % saturated: {summary['scenes_above_1_percent']}; with any saturated pixel: "
             f"{summary['scenes_with_any_saturation']}",
             f"- share of scenes at or below LLR's low light (<= {LLR_LOW_LUX[1]:g} lx): "
             f"{100 * summary['share_at_or_below_llr_low']:.0f} %, within {LLR_LOW_LUX[0]:g}-{LLR_LOW_LUX[1]:g} lx: "
             f"{100 * summary['share_in_llr_low']:.0f} %, within LLR's normal {LLR_NORMAL_LUX[0]:g}-"
             f"{LLR_NORMAL_LUX[1]:g} lx: {100 * summary['share_in_llr_normal']:.0f} %"]
    return "\n".join(lines) + "\n"


def study_job(job: Any, steps: Sequence[int], height: int, width: int, gt_spp: int, device: str) -> tuple[dict[str, Any], np.ndarray]:
    """Render one planned RLLR scene's ground truth at `steps` (reduced size) through the
    generator's frame source; returns its record and the frames (darkened, as stored)."""
    from spikesim.generation.job import _FrameSource
    from spikesim.dataset import SATURATION_Y

    small = dataclasses.replace(job, camera={**job.camera, "height": height, "width": width},
                                render={**job.render, "gt_spp": gt_spp, "resolution": [height, width]})
    with tempfile.TemporaryDirectory(prefix=".rllr_lighting.") as work:
        source = _FrameSource(small, Path(work), device)
        y = np.stack([source.ground_truth(int(s)) for s in steps])
        lamps = float(source.renderer.lighting.subject_illuminance_lux())
        rec = scene_record(job.name, y, lamps, job.light_power_factor, SATURATION_Y)
        rec["variant"] = source.renderer.variant
        rec["spectra"] = sorted({e.spectrum for e in source.renderer.lighting.emitters})
    return rec, y


def run(args: argparse.Namespace) -> int:
    from spikesim.generation import PRESETS, plan_rllr

    for target in (args.out, args.save_frames):  # refused before the study, not after it
        if target is not None:
            outputs.check_not_link(target)
    jobs = plan_rllr(PRESETS[args.preset], seed=args.seed, count=args.count)
    if args.lamps_lux is not None:  # another range for the same scenes: only their light level changes
        lo, hi = args.lamps_lux
        if lo > hi:
            raise ValueError(f"--lamps-lux {lo:g} {hi:g}: the low end is above the high end")
        jobs = [dataclasses.replace(j, source={**j.source, "lamps_lux": [lo, hi]}) for j in jobs]
    steps = args.steps or [0, PRESETS[args.preset].rllr_steps // 2, PRESETS[args.preset].rllr_steps - 1]
    records, t0 = [], time.perf_counter()
    frames = {}
    for i, job in enumerate(jobs):
        rec, y = study_job(job, steps, args.height, args.width, args.gt_spp, args.device)
        records.append(rec)
        if args.save_frames:
            frames[job.name] = y.astype(np.float32)
        if not args.quiet:
            print(f"[rllr-lighting] {i + 1}/{len(jobs)} {rec['name']}: {rec['subject_lux']:.1f} lx at the subject "
                  f"(lamps {rec['lamps_lux']:.0f} lx x {rec['factor']:.3f}), {100 * rec['saturated_fraction']:.2f} % "
                  f"saturated, y max {rec['y_max']:.2f} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    summary = summarise(records)
    result = {"command": "python -m pipelines.rllr_lighting " + " ".join(sys.argv[1:]),
              "preset": args.preset, "seed": args.seed, "steps": list(steps), "height": args.height,
              "width": args.width, "gt_spp": args.gt_spp, "seconds": time.perf_counter() - t0,
              "summary": summary, "scenes": records}
    if args.out is not None:
        with outputs.output_file(args.out):  # through the project's output guard, as every command
            outputs.atomic_write_text(args.out, json.dumps(result, indent=1) + "\n")
    if args.save_frames:
        with outputs.output_file(args.save_frames):  # a file object: np.savez would add .npz to a name
            outputs.atomic_write_file(args.save_frames, lambda f: np.savez_compressed(f, **frames))
    print(markdown(summary))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from spikesim._drjit import DEVICE_CHOICES

    p = argparse.ArgumentParser(prog="python -m pipelines.rllr_lighting", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", choices=["paper", "small"], default="paper", help="the preset whose scenes are planned")
    p.add_argument("--seed", type=seed_int, default=0, help="dataset seed, as generate's --seed")
    p.add_argument("--count", type=positive_int, help="scenes (default: the preset's; paper 100)")
    p.add_argument("--steps", type=nonnegative_int, nargs="+", help="ground-truth steps per scene (default: first, middle, last)")
    p.add_argument("--lamps-lux", type=positive_float, nargs=2, metavar=("LOW", "HIGH"),
                   help="measure another range of the lamps' illuminance at the subject (default: the one "
                        "generate uses, scenes.random_scene.LAMPS_LUX; 100 1000 was the range before)")
    p.add_argument("--height", type=positive_int, default=64)
    p.add_argument("--width", type=positive_int, default=100)
    p.add_argument("--gt-spp", type=positive_int, default=16, help="samples per pixel of the ground truth (default 16)")
    p.add_argument("--device", choices=DEVICE_CHOICES, default="llvm")
    p.add_argument("--out", type=output_file, help="JSON with every scene's record and the summary")
    p.add_argument("--save-frames", type=output_file, help="also keep the rendered ground truth (.npz)")
    p.add_argument("--quiet", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the study; bad input ends in one line naming the flag or file, status 2."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (ValueError, OSError) as exc:
        print(f"rllr_lighting: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
