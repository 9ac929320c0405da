"""`spikesim bench`: throughput of the sensor backends on the same input, in one run.

Throughput is pixel-steps per second through `Simulator.run` (frames from memory, output
packed), reported as ratios: each backend against the NumPy reference measured in the same
process, and against the sensor's real-time rate (400 x 250 pixels x 40,000 steps/s = 4e9).
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from typing import Any

import numpy as np

from spikesim.camera import SpikeCamera
from spikesim.simulate import Simulator, available_backends

REAL_TIME_PIXEL_STEPS_PER_S = 400 * 250 * 40_000


def _time_run(cam: SpikeCamera, backend: str, frames: np.ndarray, keyframe_every: int, repeats: int) -> tuple[float, int]:
    """Best-of-`repeats` seconds for simulating `frames` (after one warm-up that compiles)."""
    sim = Simulator(cam, backend=backend, seed=0, chunk_steps=256)
    sim.run(frames[: min(len(frames), 2)], keyframe_every=keyframe_every)  # compile / warm up
    best = float("inf")
    steps = 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = sim.run(frames, keyframe_every=keyframe_every)
        best = min(best, time.perf_counter() - t0)
        steps = out.num_steps
    return best, steps


def measure(height: int = 250, width: int = 400, steps: int = 1024, numpy_steps: int = 64,
            backends: list[str] | None = None, repeats: int = 3, keyframe_every: tuple[int, ...] = (1, 8)) -> dict[str, Any]:
    rng = np.random.default_rng(0)
    frames = rng.uniform(0.0, 0.3, size=(steps, height, width)).astype(np.float32)
    backends = backends or [b for b in available_backends() if b != "numpy"]
    results: list[dict[str, Any]] = []
    for model, cam in (("noiseless", SpikeCamera.noiseless(height=height, width=width)),
                       ("realistic", SpikeCamera.realistic(height=height, width=width))):
        t, n = _time_run(cam, "numpy", frames[:numpy_steps], 1, repeats=1 if model == "realistic" else repeats)
        ref = n * height * width / t
        results.append({"model": model, "backend": "numpy", "keyframe_every": 1, "steps": n, "seconds": t,
                        "pixel_steps_per_s": ref, "vs_numpy": 1.0, "vs_real_time": ref / REAL_TIME_PIXEL_STEPS_PER_S})
        for b in backends:
            for k in keyframe_every:
                f = frames if k == 1 else frames[: (steps - 1) // k + 1]
                t, n = _time_run(cam, b, f, k, repeats)
                rate = n * height * width / t
                results.append({"model": model, "backend": b, "keyframe_every": k, "steps": n, "seconds": t,
                                "pixel_steps_per_s": rate, "vs_numpy": rate / ref,
                                "vs_real_time": rate / REAL_TIME_PIXEL_STEPS_PER_S})
    import os
    return {"height": height, "width": width, "machine": {"cpus": os.cpu_count(), "processor": platform.processor(),
                                                           "python": platform.python_version()},
            "real_time_pixel_steps_per_s": REAL_TIME_PIXEL_STEPS_PER_S, "results": results}


def format_table(res: dict[str, Any]) -> str:
    lines = [f"sensor throughput at {res['width']}x{res['height']} (pixel-steps/s; ratios measured in this run)",
             f"{'model':<10} {'backend':<7} {'keyframes':>9} {'steps':>6} {'pixel-steps/s':>14} {'x NumPy':>8} {'x real time':>11}"]
    for r in res["results"]:
        k = "every" if r["keyframe_every"] == 1 else f"1/{r['keyframe_every']}"
        lines.append(f"{r['model']:<10} {r['backend']:<7} {k:>9} {r['steps']:>6} {r['pixel_steps_per_s']:>14.3e} "
                     f"{r['vs_numpy']:>8.1f} {r['vs_real_time']:>11.3f}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    res = measure(args.height, args.width, steps=args.steps, numpy_steps=args.numpy_steps,
                  backends=args.backends, repeats=args.repeats)
    if args.json:
        print(json.dumps(res, indent=2))
    else:
        print(format_table(res))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="sensor throughput: NumPy reference vs Dr.Jit, and vs real time")
    p.add_argument("--height", type=int, default=250)
    p.add_argument("--width", type=int, default=400)
    p.add_argument("--steps", type=int, default=1024, help="steps per Dr.Jit run")
    p.add_argument("--numpy-steps", type=int, default=64, help="steps per NumPy run (it is slow)")
    p.add_argument("--backends", nargs="*", choices=["llvm", "cuda"], help="default: every available one")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run)
