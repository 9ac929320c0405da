"""What a dataset's pictures are like: brightness, motion, spectrum slope and edge density of its
ground truth, so training data can be compared with the data a model is judged on.

    python -m pipelines.content_stats data/rllr40 data/rllr_nat48 data/llr_paper \
        --dat 203_part1_key_id151.dat --gt 203_part1_key_id151.png --gt-scale 0.6 --center 151

Per scene (then the median and range over a dataset's scenes):
- brightness: mean and 99th percentile of the ground truth y (spikes per step, clipped at the
  sensor's saturation, as every score is);
- motion: the normal flow between ground-truth frames 41 steps apart, |dI/dt| / |grad I| over the
  tenth of pixels with the strongest gradient, its 90th percentile (the moving parts: the median is
  the still background's ~0.001), in pixels per step. A stream with one
  ground-truth frame (an external pair) is measured on TFP of consecutive 41-step windows instead,
  smoothed the same way (`motion_from`; on the LLR normal-light scenes the two agree within 35 %:
  fan 0.073 / 0.048, car 0.051 / 0.050, rotate 0.120 / 0.109, ball 0.017 / 0.025);
- spectrum slope: the log-log slope of the radially averaged power spectrum of the luminance
  (scenes.natural_textures.power_spectrum_slope; photographs about -2);
- edge density: the fraction of pixels on a Canny edge (skimage.feature.canny, sigma 1.5) of the
  image normalised by its 99th percentile, so it does not depend on the light level;
- lit and textured: the fraction of 16 x 16 blocks whose mean is at least LIT_FRACTION_OF_P99 of
  the image's 99th percentile and whose contrast (std / mean) is at least TEXTURED_CONTRAST: how
  much of the frame carries structure, where a video frame is textured over its whole area and a
  room with small objects is mostly dark or flat.

A recording without ground truth (`--real DAT --height H --width W`) is measured on TFP over all
its steps (brightness and lit-textured share include its dark current and noise: an upper bound).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.ndimage import gaussian_filter

from scenes.natural_textures import power_spectrum_slope
from spikesim.dataset import SATURATION_Y

WINDOW = 41
#: Fraction of pixels, those with the strongest gradient, the normal flow is taken over.
FLOW_PIXELS = 0.1
FLOW_SMOOTHING_PX = 1.5
#: The quantile of the normal flow reported over those pixels (module docstring).
FLOW_QUANTILE = 0.9
#: lit_textured_fraction's block side (pixels), its "lit" level (share of the image's 99th
#: percentile) and its "textured" contrast (std / mean inside the block).
TEXTURE_BLOCK_PX = 16
LIT_FRACTION_OF_P99 = 0.05
TEXTURED_CONTRAST = 0.1


def edge_density(y: np.ndarray, sigma: float = 1.5) -> float:
    """Fraction of pixels on a Canny edge of `y` normalised by its 99th percentile."""
    from skimage.feature import canny

    p = float(np.percentile(y, 99))
    if p <= 0:
        return 0.0
    return float(canny(np.clip(y / p, 0, 1.5), sigma=sigma).mean())


def normal_flow_px(a: np.ndarray, b: np.ndarray, steps: int) -> float:
    """The FLOW_QUANTILE of the normal flow |b - a| / |grad| over the FLOW_PIXELS strongest-gradient
    pixels, per step."""
    a = gaussian_filter(np.asarray(a, np.float64), FLOW_SMOOTHING_PX)
    b = gaussian_filter(np.asarray(b, np.float64), FLOW_SMOOTHING_PX)
    gy, gx = np.gradient((a + b) / 2)
    g = np.hypot(gx, gy)
    if not g.max() > 0:
        return 0.0
    sel = g >= np.quantile(g, 1 - FLOW_PIXELS)
    return float(np.quantile(np.abs(b - a)[sel] / g[sel], FLOW_QUANTILE) / steps)


def lit_textured_fraction(y: np.ndarray, block: int = TEXTURE_BLOCK_PX) -> float:
    """Share of whole block x block tiles that are lit and textured (module docstring)."""
    y = np.asarray(y, np.float64)
    h, w = (y.shape[0] // block) * block, (y.shape[1] // block) * block
    p = float(np.percentile(y, 99))
    if h == 0 or w == 0 or p <= 0:
        return 0.0
    tiles = y[:h, :w].reshape(h // block, block, w // block, block).swapaxes(1, 2).reshape(-1, block * block)
    mean, std = tiles.mean(axis=1), tiles.std(axis=1)
    good = (mean >= LIT_FRACTION_OF_P99 * p) & (std >= TEXTURED_CONTRAST * np.maximum(mean, 1e-12))
    return float(good.mean())


def image_statistics(y: np.ndarray) -> dict[str, float]:
    y = np.clip(np.asarray(y, np.float64), 0, SATURATION_Y)
    return {"mean_y": float(y.mean()), "p99_y": float(np.percentile(y, 99)),
            "spectrum_slope": power_spectrum_slope(y) if y.std() > 0 else float("nan"),
            "edge_density": edge_density(y), "lit_textured": lit_textured_fraction(y)}


def scene_statistics(scene: Any, frames: int = 3) -> dict[str, Any]:
    """A dataset scene's statistics: image ones averaged over up to `frames` ground-truth frames
    spread over the stream, motion over consecutive ground-truth pairs 41 steps apart."""
    steps = sorted(int(s) for s in scene.gt_steps)
    pick = [steps[i] for i in np.unique(np.linspace(0, len(steps) - 1, min(frames, len(steps))).round().astype(int))]
    stats = [image_statistics(scene.ground_truth(s)) for s in pick]
    out: dict[str, Any] = {k: float(np.nanmean([s[k] for s in stats])) for k in stats[0]}
    flows = [normal_flow_px(np.clip(scene.ground_truth(s), 0, SATURATION_Y),
                            np.clip(scene.ground_truth(s + WINDOW), 0, SATURATION_Y), WINDOW)
             for s in pick if s + WINDOW in set(steps)]
    out["motion_px_per_step"] = float(np.mean(flows)) if flows else float("nan")
    out["motion_from"] = "ground truth" if flows else "none"
    out["scene"] = scene.name
    out["size"] = f"{scene.height} x {scene.width}"
    return out


def pair_statistics(dat: Path, gt: np.ndarray, center: int, height: int | None = None,
                    width: int | None = None) -> dict[str, Any]:
    """An external stream with one ground-truth frame: image statistics of the frame, motion from
    TFP of the 41-step windows before and after the centre one."""
    from spikesim.stream import DatReader, stream_geometry

    height, width, flip = stream_geometry(dat, height, width, None)
    reader = DatReader(dat, height, width, flip=flip)
    half = WINDOW // 2
    tfp = [reader.read(c - half, c - half + WINDOW).unpack().mean(0).astype(np.float64)
           for c in (center - WINDOW, center + WINDOW) if c - half >= 0 and c + half < reader.num_steps]
    out: dict[str, Any] = {**image_statistics(gt), "scene": dat.stem, "size": f"{height} x {width}"}
    out["motion_px_per_step"] = normal_flow_px(tfp[0], tfp[1], 2 * WINDOW) if len(tfp) == 2 else float("nan")
    out["motion_from"] = "TFP-41 of the stream" if len(tfp) == 2 else "none"
    return out


def recording_statistics(dat: Path, height: int | None = None, width: int | None = None) -> dict[str, Any]:
    """A recording without ground truth: image statistics of TFP over all its steps, motion from
    TFP of its first and last 41-step windows."""
    from spikesim.stream import DatReader, stream_geometry

    height, width, flip = stream_geometry(dat, height, width, None)
    reader = DatReader(dat, height, width, flip=flip)
    n = reader.num_steps
    tfp_all = reader.read(0, n).unpack().mean(0).astype(np.float64)
    out: dict[str, Any] = {**image_statistics(tfp_all), "scene": dat.stem, "size": f"{height} x {width}"}
    if n >= 2 * WINDOW:
        a = reader.read(0, WINDOW).unpack().mean(0).astype(np.float64)
        b = reader.read(n - WINDOW, n).unpack().mean(0).astype(np.float64)
        out["motion_px_per_step"] = normal_flow_px(a, b, n - WINDOW)
        out["motion_from"] = "TFP-41 of the first and last windows"
    else:
        out["motion_px_per_step"], out["motion_from"] = float("nan"), "none"
    return out


def dataset_summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    keys = ("mean_y", "p99_y", "motion_px_per_step", "spectrum_slope", "edge_density", "lit_textured")
    out: dict[str, Any] = {"scenes": len(rows)}
    for k in keys:
        v = np.array([r[k] for r in rows], dtype=np.float64)
        v = v[np.isfinite(v)]
        out[k] = {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max())} if v.size else None
    return out


def markdown(summaries: dict[str, dict[str, Any]]) -> str:
    cols = (("mean_y", "mean y", "{:.3f}"), ("p99_y", "p99 y", "{:.3f}"), ("motion_px_per_step", "motion (px/step)", "{:.3f}"),
            ("spectrum_slope", "spectrum slope", "{:.2f}"), ("edge_density", "edge density", "{:.3f}"),
            ("lit_textured", "lit and textured", "{:.2f}"))
    lines = ["| data | scenes | " + " | ".join(c[1] for c in cols) + " |", "|---|---|" + "---|" * len(cols)]
    for name, s in summaries.items():
        cells = []
        for k, _, fmt in cols:
            v = s[k]
            cells.append("n/a" if v is None else
                         (fmt.format(v["median"]) if v["min"] == v["max"] else
                          f"{fmt.format(v['median'])} ({fmt.format(v['min'])} to {fmt.format(v['max'])})"))
        lines.append(f"| {name} | {s['scenes']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    from model.data import open_scenes

    p = argparse.ArgumentParser(prog="python -m pipelines.content_stats", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("datasets", nargs="*", type=Path, help="dataset roots")
    p.add_argument("--dat", type=Path, help="an external stream with one ground-truth frame")
    p.add_argument("--gt", type=Path, help="its ground truth (image; with --gt-scale to y)")
    p.add_argument("--gt-scale", type=float, default=1.0, help="y per unit of the ground-truth image")
    p.add_argument("--center", type=int, help="the step of the ground truth")
    p.add_argument("--real", type=Path, help="a recording without ground truth (measured on TFP over all its steps)")
    p.add_argument("--height", type=int, help="the --real recording's height (default: its sidecar or 250)")
    p.add_argument("--width", type=int, help="the --real recording's width (default: its sidecar or 400)")
    p.add_argument("--max-scenes", type=int, default=0, help="at most this many scenes per dataset (0: all)")
    p.add_argument("--json", action="store_true", help="every row and summary as JSON")
    args = p.parse_args(argv)
    summaries, rows_all = {}, {}
    for root in args.datasets:
        scenes = open_scenes(root)
        if args.max_scenes:
            scenes = scenes[:args.max_scenes]
        rows = [scene_statistics(sc) for sc in scenes]
        rows_all[str(root)] = rows
        summaries[root.name] = dataset_summary(rows)
        print(f"[content_stats] {root}: {len(rows)} scene(s)", file=sys.stderr)
    if args.dat is not None:
        from spikesim.imageio import read_image_y
        if args.gt is None or args.center is None:
            p.error("--dat needs --gt and --center")
        gt = read_image_y(args.gt, args.gt_scale)
        row = pair_statistics(args.dat, gt, args.center)
        rows_all[str(args.dat)] = [row]
        summaries[args.dat.stem] = dataset_summary([row])
    if args.real is not None:
        row = recording_statistics(args.real, args.height, args.width)
        rows_all[str(args.real)] = [row]
        summaries[args.real.stem + " (real, TFP)"] = dataset_summary([row])
    if args.json:
        print(json.dumps({"summaries": summaries, "rows": rows_all}, indent=1))
    else:
        print(markdown(summaries))
    return 0


if __name__ == "__main__":
    sys.exit(main())
