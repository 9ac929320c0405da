"""`spikesim bench`: throughput of each stage, as ratios measured in one run.

Three stages, each on every available Dr.Jit device:
- sensor: pixel-steps per second through the simulator (frames from memory, output packed),
  against the NumPy reference measured in the same process; also S streams in one launch.
- render: Mitsuba renders of a bundled scene at the camera size; a render covers
  `keyframe_every` steps (the sensor interpolates in between).
- pipeline (render + sensor): frames kept on the device and fed to the sensor there, against the
  host round trip with the same sensor and against the NumPy reference (host frames, NumPy
  sensor), with the share of time spent rendering.

Every throughput is also given against the sensor's real-time rate (400 x 250 pixels x 40,000
steps/s = 4e9 pixel-steps/s). Machines differ: the CPU model and GPU are printed with the
figures, and only ratios taken in one run compare.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from typing import Any, Callable

import numpy as np

from pipelines.argtypes import bounded_count, bundled_scene, positive_int
from spikesim.camera import SpikeCamera
from spikesim.keyframes import keyframe_count, steps_covered
from spikesim.simulate import BatchSimulator, Simulator, aligned_empty, available_backends

REAL_TIME_PIXEL_STEPS_PER_S = 400 * 250 * 40_000
STAGES = ("sensor", "render", "pipeline")


# ---- the machine ------------------------------------------------------------------------------------
def machine_info() -> dict[str, Any]:
    """What the figures were measured on: CPU model and cores, GPU (if any), library versions."""
    from spikesim.machine import cpu_model
    info: dict[str, Any] = {"cpu": cpu_model(), "cores": os.cpu_count(), "python": platform.python_version()}
    import drjit
    info["drjit"] = drjit.__version__
    if "cuda" in available_backends():
        try:
            import torch
            info["gpu"] = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "CUDA (name unknown)"
        except ImportError:
            info["gpu"] = "CUDA (name unknown)"
    return info


def _best(fn: Callable[[], Any], repeats: int) -> float:
    """Best-of-`repeats` seconds (a shared machine only ever adds time)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _row(stage: str, what: str, device: str, rate: float, ref: float | None, **extra: Any) -> dict[str, Any]:
    return {"stage": stage, "what": what, "device": device, "pixel_steps_per_s": rate,
            "vs_reference": None if ref is None else rate / ref, "vs_real_time": rate / REAL_TIME_PIXEL_STEPS_PER_S,
            **extra}


# ---- sensor -----------------------------------------------------------------------------------------
def measure_sensor(height: int, width: int, steps: int, numpy_steps: int, backends: list[str], repeats: int,
                   streams: int, keyframe_every: tuple[int, ...] = (1, 8)) -> list[dict[str, Any]]:
    rng = np.random.default_rng(0)
    # Frames as the simulator's own buffers hold them: rows on 64-byte boundaries. A copy 16 bytes
    # off (where NumPy's allocator may put an array) shows what unaligned rows cost on the CPU.
    frames = aligned_empty((steps, height, width))
    frames[:] = rng.uniform(0.0, 0.3, size=(steps, height, width))
    unaligned = aligned_empty((steps * height * width + 4,))[4:].reshape(steps, height, width)
    unaligned[:] = frames
    rows = []
    for model, cam in (("noiseless", SpikeCamera.noiseless(height=height, width=width)),
                       ("realistic", SpikeCamera.realistic(height=height, width=width)),
                       ("realistic-renewal", SpikeCamera.realistic(height=height, width=width,
                                                                               shot_noise="renewal"))):
        def run(sim: Any, f: np.ndarray, k: int) -> Callable[[], Any]:
            return lambda: [p.to_numpy() for p in sim.stream_packed(f, keyframe_every=k)]

        ref_sim = Simulator(cam, backend="numpy", seed=0)
        t = _best(run(ref_sim, frames[:numpy_steps], 1), repeats if model == "noiseless" else 1)
        ref = numpy_steps * height * width / t
        rows.append(_row("sensor", f"{model}, frames every step", "numpy", ref, ref))
        for b in backends:
            for k in keyframe_every:
                f = frames[: keyframe_count(steps, k)]
                n = steps_covered(len(f), k)  # the steps these keyframes give
                sim = Simulator(cam, backend=b, seed=0)
                run(sim, f[:2], k)()  # compile
                t = _best(run(sim, f, k), repeats)
                what = f"{model}, frames every step" if k == 1 else f"{model}, keyframes every {k}"
                rows.append(_row("sensor", what, b, n * height * width / t, ref))
                if k == 1 and b == "llvm" and model == "noiseless":
                    sim = Simulator(cam, backend=b, seed=0)
                    run(sim, unaligned[:2], k)()
                    t = _best(run(sim, unaligned, k), repeats)
                    rows.append(_row("sensor", f"{model}, frames every step, rows 16 bytes off 64", b,
                                     steps * height * width / t, ref))
            if streams > 1:
                batch = BatchSimulator(cam, list(range(streams)), backend=b)
                fb = np.broadcast_to(frames[:, None], (steps, streams, height, width)).copy()
                run(batch, fb[:2], 1)()
                t = _best(run(batch, fb, 1), repeats)
                rows.append(_row("sensor", f"{model}, {streams} streams per launch", b,
                                 streams * steps * height * width / t, ref))
    return rows


# ---- render and render + sensor ------------------------------------------------------------------------
def _renderer(scene: str, light: str, spp: int, cam: SpikeCamera, device: str) -> Any:
    from spikesim.render import SceneRenderer
    r = SceneRenderer(scene, light=light, variant="mono", spp=spp, camera=cam, device=device)
    r.render_step(0)  # compile
    return r


def measure_render(scene: str, light: str, spp: int, cam: SpikeCamera, devices: list[str], frames: int,
                   repeats: int, keyframe_every: int) -> list[dict[str, Any]]:
    """Renders per second, as pixel-steps per second when one render serves `keyframe_every` steps."""
    from spikesim._drjit import dr
    rows = []
    for d in devices:
        r = _renderer(scene, light, spp, cam, d)

        def renders() -> None:
            dr.eval([r.render_step_device(430 + i) for i in range(frames)])
            dr.sync_thread()
        per_frame = _best(renders, repeats) / frames
        rows.append(_row("render", f"{scene} mono {spp} spp, 1 render per {keyframe_every} steps", d,
                         keyframe_every * cam.num_pixels / per_frame, None, seconds_per_render=per_frame))
    return rows


def measure_pipeline(scene: str, light: str, spp: int, cam: SpikeCamera, devices: list[str], steps: int,
                     numpy_steps: int, repeats: int, keyframe_every: int) -> list[dict[str, Any]]:
    """Render + sensor for `steps` steps: device-resident, host round trip, NumPy reference. The
    render share is the renders' own time (measured alone, synchronised) over the total."""
    from spikesim._drjit import dr
    k = keyframe_every

    def run(r: Any, backend: str, n: int, device_frames: bool) -> Callable[[], None]:
        def go() -> None:
            sim = Simulator(cam, backend=backend, seed=0)
            for p in sim.stream_packed(r.frames(400, n, keyframe_every=k, device=device_frames), keyframe_every=k):
                p.to_numpy()  # what a writer takes: only packed words leave the device
        return go

    def render_seconds(r: Any, n: int) -> float:
        def renders() -> None:
            dr.eval([r.render_step_device(400 + j * k) for j in range(n)])
            dr.sync_thread()
        return _best(renders, repeats)

    rows = []
    ref_r = _renderer(scene, light, spp, cam, devices[0])
    t = _best(run(ref_r, "numpy", numpy_steps, False), 1)
    ref = numpy_steps * cam.num_pixels / t
    rows.append(_row("pipeline", f"{scene}: host frames -> NumPy sensor (reference)", f"{devices[0]}+numpy", ref, ref))
    renders = keyframe_count(steps, k)
    for d in devices:
        r = _renderer(scene, light, spp, cam, d)
        render_s = render_seconds(r, renders)
        for label, on_device in (("frames stay on the device", True), ("host round trip", False)):
            run(r, d, 2 * k + 1, on_device)()  # compile the sensor
            t = _best(run(r, d, steps, on_device), repeats)
            rows.append(_row("pipeline", f"{scene}: {label}", d, steps * cam.num_pixels / t, ref,
                             render_share=min(1.0, render_s / t)))
    return rows


# ---- the command ------------------------------------------------------------------------------------
def measure(stages: tuple[str, ...] = STAGES, height: int = 250, width: int = 400, steps: int = 1024,
            numpy_steps: int = 64, backends: list[str] | None = None, repeats: int = 3, streams: int = 1,
            scene: str = "fan", light: str = "normal", spp: int = 4, keyframe_every: int = 8,
            render_frames: int = 4, pipeline_steps: int = 129) -> dict[str, Any]:
    devices = backends or [b for b in available_backends() if b != "numpy"]
    rows: list[dict[str, Any]] = []
    cam = SpikeCamera.realistic(height=height, width=width)
    if "sensor" in stages:
        rows += measure_sensor(height, width, steps, numpy_steps, devices, repeats, streams)
    if "render" in stages and devices:
        rows += measure_render(scene, light, spp, cam, devices, render_frames, repeats, keyframe_every)
    if "pipeline" in stages and devices:
        rows += measure_pipeline(scene, light, spp, cam, devices, pipeline_steps, min(numpy_steps, pipeline_steps),
                                 repeats, keyframe_every)
    return {"height": height, "width": width, "machine": machine_info(),
            "real_time_pixel_steps_per_s": REAL_TIME_PIXEL_STEPS_PER_S, "results": rows}


def format_table(res: dict[str, Any]) -> str:
    m = res["machine"]
    lines = [f"machine: {m['cpu']}, {m['cores']} cores" + (f", GPU {m['gpu']}" if "gpu" in m else ", no GPU")
             + f"; Dr.Jit {m['drjit']}",
             f"throughput at {res['width']}x{res['height']} in pixel-steps/s; ratios measured in this run "
             f"(real time = {REAL_TIME_PIXEL_STEPS_PER_S:.0e})",
             f"{'stage':<9} {'what':<52} {'device':<11} {'pixel-steps/s':>13} {'x reference':>11} {'x real time':>11}"]
    for r in res["results"]:
        ref = "" if r["vs_reference"] is None else f"{r['vs_reference']:.1f}"
        note = f"  (render {r['render_share']:.0%})" if "render_share" in r else ""
        note += f"  ({r['seconds_per_render'] * 1e3:.0f} ms/render)" if "seconds_per_render" in r else ""
        lines.append(f"{r['stage']:<9} {r['what']:<52} {r['device']:<11} {r['pixel_steps_per_s']:>13.3e} "
                     f"{ref:>11} {r['vs_real_time']:>11.3f}{note}")
    lines.append("reference: the NumPy sensor (sensor stage); host frames into the NumPy sensor (pipeline stage)")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    res = measure(tuple(args.stages), args.height, args.width, steps=args.steps, numpy_steps=args.numpy_steps,
                  backends=args.backends, repeats=args.repeats, streams=args.streams, scene=args.scene,
                  light=args.light, spp=args.spp, keyframe_every=args.keyframe_every,
                  pipeline_steps=args.pipeline_steps)
    print(json.dumps(res, indent=2) if args.json else format_table(res))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="throughput of the sensor, the renderer and both together, as ratios "
                                     "against the NumPy reference and real time")
    p.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES),
                   help="what to measure: the sensor kernel, the renderer, or both together")
    p.add_argument("--height", type=positive_int, default=250, help="frame rows, pixels")
    p.add_argument("--width", type=positive_int, default=400, help="frame columns, pixels")
    p.add_argument("--steps", type=positive_int, default=1024, help="steps per Dr.Jit sensor run")
    p.add_argument("--numpy-steps", type=positive_int, default=64, help="steps per NumPy run (it is slow)")
    # bounded: --streams 10^8 and --repeats 10^9 ran on without a word (round nine)
    p.add_argument("--streams", type=bounded_count(1024, "streams"), default=1,
                   help="also time this many streams in one launch (at most 1024)")
    p.add_argument("--backends", nargs="*", choices=["llvm", "cuda"], help="default: every available one")
    p.add_argument("--repeats", type=bounded_count(100, "repeats"), default=3,
                   help="timed runs per case, at most 100 (the best is reported)")
    p.add_argument("--scene", type=bundled_scene, default="fan", help="render and pipeline stages")
    p.add_argument("--light", choices=["normal", "low"], default="normal", help="lighting of the render stage's scene")
    p.add_argument("--spp", type=positive_int, default=4, help="render samples per pixel")
    p.add_argument("--keyframe-every", type=positive_int, default=8, help="steps one render serves")
    p.add_argument("--pipeline-steps", type=positive_int, default=129, help="readout steps of the render+sensor stage")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=run)
