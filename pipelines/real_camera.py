"""What a real spike camera does that the simulator may not: no-reference statistics of a
recording, and the same statistics of its simulated twin (docs/sensor.md, "A camera like the real
one").

    python -m pipelines.real_camera uhsr_helicopter.dat --height 250 --width 250
    python -m pipelines.real_camera uhsr_helicopter.dat --height 250 --width 250 --camera measured --seeds 0 1

The twin is a camera under the recording's own rate map (the per-pixel spike count over the
recording, median-filtered over RATE_MAP_PX pixels, as y) for as many steps: the same scene, the
simulator's sensor. A statistic where the recording and its twin differ beyond the twin's
seed-to-seed spread is something the simulated camera lacks.
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.ndimage import median_filter

#: Side of the median filter that makes the rate map and the local reference of each pixel.
RATE_MAP_PX = 9
#: Share of pixels, those with the smallest local gradient of the rate map, called flat.
FLAT_SHARE = 0.3
#: A pixel whose rate is this far (relative) from its neighbourhood's counts as an outlier.
OUTLIER_OFFSET = 0.3
HOT_Z = 6.0


def spike_time_rate(spikes: np.ndarray) -> np.ndarray:
    """Per-pixel rate from the first and last spike times, (n - 1) / (t_last - t_first): far less
    quantised than count / steps when a pixel fires a few times; NaN below 3 spikes."""
    spikes = np.asarray(spikes, dtype=bool)
    steps = spikes.shape[0]
    fired = spikes.any(0)
    first = np.argmax(spikes, 0)
    last = steps - 1 - np.argmax(spikes[::-1], 0)
    n = spikes.sum(0)
    rate = np.full(spikes.shape[1:], np.nan)
    ok = fired & (n >= 3) & (last > first)
    rate[ok] = (n[ok] - 1) / (last[ok] - first[ok])
    return rate


def measure(spikes: np.ndarray) -> dict[str, float]:
    """The statistics of docs/sensor.md's table for a (steps, H, W) 0/1 recording."""
    spikes = np.asarray(spikes, dtype=bool)
    steps = spikes.shape[0]
    rate = spike_time_rate(spikes)
    ref = median_filter(np.nan_to_num(rate, nan=float(np.nanmedian(rate))), RATE_MAP_PX)
    rel = rate / np.maximum(ref, 1e-9) - 1
    gy, gx = np.gradient(ref)
    grad = np.hypot(gx, gy) / np.maximum(ref, 1e-9)
    flat = (grad <= np.percentile(grad, 100 * FLAT_SHARE)) & np.isfinite(rel)
    r = rel[flat]
    with warnings.catch_warnings():  # a row or column with no flat pixel has no median: skipped
        warnings.simplefilter("ignore", RuntimeWarning)
        rows = np.nanmedian(np.where(flat, rel, np.nan), axis=1)
        cols = np.nanmedian(np.where(flat, rel, np.nan), axis=0)
    count_rate = spikes.mean(0)
    smooth = median_filter(count_rate, RATE_MAP_PX)
    z = (count_rate - smooth) / np.sqrt(np.maximum(smooth, 1e-3) / steps)
    isi_cv = []
    for y in range(0, spikes.shape[1], 5):
        for x in range(0, spikes.shape[2], 5):
            t = np.flatnonzero(spikes[:, y, x])
            if t.size >= 5:
                d = np.diff(t)
                isi_cv.append(d.std() / d.mean())
    return {
        "mean_rate": float(count_rate.mean()),
        "rate_spread_robust": float(1.4826 * np.median(np.abs(r - np.median(r)))),
        "rate_spread_std": float(np.std(r)),
        "outlier_share": float(np.mean(np.abs(r) > OUTLIER_OFFSET)),
        "row_median_spread": float(np.nanstd(rows)),
        "column_median_spread": float(np.nanstd(cols)),
        "hot_pixels": int(np.sum(z > HOT_Z)),
        "dead_pixels": int(np.sum((count_rate == 0) & (smooth > 0.05))),
        "isi_cv_median": float(np.median(isi_cv)) if isi_cv else float("nan"),
    }


def rate_map(spikes: np.ndarray) -> np.ndarray:
    """The recording's scene as the twin sees it: spike count / steps, median-filtered."""
    return median_filter(np.asarray(spikes, dtype=bool).mean(0).astype(np.float64), RATE_MAP_PX).astype(np.float32)


def twin(spikes: np.ndarray, camera: Any, seed: int = 0, backend: str = "auto") -> np.ndarray:
    """The recording's simulated twin: `camera` (resized to the recording) under its rate map."""
    from spikesim.simulate import Simulator

    steps, h, w = np.asarray(spikes).shape
    cam = camera.replace(height=h, width=w)
    # The recording's rate holds its dark counts, and the twin's camera adds its own dark current:
    # the light is the rate less the camera's mean dark rate (the twin's rate was 0.0338 against the
    # recording's 0.0314 before, the difference being 94 Hz x 25 us = 0.0024 per step).
    y = np.clip(rate_map(spikes) - np.float32(cam.dark_per_step), 0.0, None).astype(np.float32)
    return Simulator(cam, backend=backend, seed=seed).run(y for _ in range(steps)).unpack()


def read_recording(path: Path, height: int | None, width: int | None) -> np.ndarray:
    """A recording as (steps, H, W) bool, row 0 at the top: a `.dat` (geometry as given or recorded
    beside it) or an `.npz` with key `spk` (Spike-Zoo's layout)."""
    if path.suffix == ".npz":
        with np.load(path) as z:
            if "spk" not in z:
                raise ValueError(f"{path}: no 'spk' array (expected Spike-Zoo's layout: spk of (steps, rows, columns))")
            return z["spk"].astype(bool)
    from spikesim.stream import DatReader, stream_geometry
    h, w, flip = stream_geometry(path, height, width, None)
    return DatReader(path, h, w, flip=flip).read().unpack()


def main(argv: Sequence[str] | None = None) -> int:
    from pipelines.argtypes import camera_spec, load_camera

    p = argparse.ArgumentParser(prog="python -m pipelines.real_camera", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recording", type=Path, help="a .dat (with --height/--width) or Spike-Zoo .npz recording")
    p.add_argument("--height", type=int)
    p.add_argument("--width", type=int)
    p.add_argument("--camera", type=camera_spec, default="realistic", help="the twin's camera (realistic, measured, a file)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="sensor seeds of the twin")
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    spikes = read_recording(args.recording, args.height, args.width)
    real = measure(spikes)
    twins = [measure(twin(spikes, load_camera(args.camera), seed)) for seed in args.seeds]
    if args.json:
        print(json.dumps({"recording": real, "twins": twins, "camera": str(args.camera)}, indent=1))
        return 0
    print(f"| statistic | recording | twin ({args.camera}, seeds {' '.join(map(str, args.seeds))}) |")
    print("|---|---|---|")
    for k, v in real.items():
        tv = [t[k] for t in twins]
        fmt = "{:d}" if isinstance(v, int) else "{:.4f}"
        print(f"| {k} | {fmt.format(v)} | " + ", ".join(fmt.format(x) for x in tv) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
