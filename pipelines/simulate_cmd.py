"""`spikesim simulate`: irradiance frames (a built-in pattern, a .npy array or EXR files) into a
spike stream on disk, with its JSON sidecar, streamed chunk by chunk."""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Iterator

import numpy as np

from spikesim.camera import SpikeCamera
from spikesim.patterns import MovingPattern

log = logging.getLogger("spikesim.simulate")


def camera_from_args(args: argparse.Namespace) -> SpikeCamera:
    if getattr(args, "camera", None):
        cam = SpikeCamera.from_file(args.camera)
    else:
        cam = SpikeCamera.noiseless() if args.preset == "noiseless" else SpikeCamera.realistic()
    changes = {k: v for k, v in (("height", args.height), ("width", args.width)) if v is not None}
    return cam.replace(**changes) if changes else cam


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("camera")
    g.add_argument("--camera", type=Path, help="camera config (JSON/TOML); overrides --preset")
    g.add_argument("--preset", choices=["realistic", "noiseless"], default="realistic")
    g.add_argument("--height", type=int, help="sensor rows (default: the camera's, 250)")
    g.add_argument("--width", type=int, help="sensor columns (default: the camera's, 400)")


def frames_from_source(args: argparse.Namespace, cam: SpikeCamera) -> tuple[Iterator[np.ndarray], dict]:
    """The irradiance source named on the command line, as a frame iterator plus a description."""
    if args.frames is not None and args.scene is not None:
        raise ValueError("give --frames or --scene, not both")
    if args.scene is not None:
        from spikesim.render import SceneRenderer
        r = SceneRenderer(args.scene, light=args.light, camera=cam, motion=args.motion, lights=args.lights,
                          spp=args.spp, seed=args.seed)
        steps = args.steps or 2000
        return r.frames(0, steps, keyframe_every=args.keyframe_every), {"source": "scene", **r.describe()}
    if args.frames is not None:
        src = Path(args.frames)
        if src.suffix == ".npy":
            arr = np.load(src, mmap_mode="r")
            if arr.ndim != 3:
                raise ValueError(f"{src}: expected an (N, H, W) array of y, got shape {arr.shape}")
            n = arr.shape[0] if args.steps is None else min(args.steps, arr.shape[0])
            return (np.asarray(arr[i]) for i in range(n)), {"source": str(src)}
        if src.is_dir():
            from spikesim.imageio import read_exr
            files = sorted(src.glob("*.exr"))
            if not files:
                raise FileNotFoundError(f"{src}: no .exr frames in this folder")
            files = files[: args.steps] if args.steps else files
            return (read_exr(f) for f in files), {"source": str(src), "frames": len(files)}
        raise ValueError(f"--frames {src}: expected a .npy array or a folder of .exr files")
    pattern = MovingPattern(height=cam.height, width=cam.width, peak_y=args.peak_y,
                            readout_period_s=cam.readout_period_s, seed=args.seed)
    steps = args.steps or 2000
    k = args.keyframe_every
    nkey = (steps - 1) // k + 1 if k > 1 else steps
    return pattern.frames(nkey, every=k), {"source": "moving_pattern", "peak_y": args.peak_y}


def run(args: argparse.Namespace) -> int:
    from spikesim.simulate import Simulator
    from spikesim.stats import summary

    cam = camera_from_args(args)
    frames, source = frames_from_source(args, cam)
    sim = Simulator(cam, backend=args.backend, seed=args.seed)
    log.info("simulating on backend %s, %dx%d, from %s", sim.backend_name, cam.width, cam.height,
             source.get("scene") or source.get("source"))
    t0 = time.perf_counter()
    out = sim.run_to_dat(_progress(frames, args), args.out, keyframe_every=args.keyframe_every,
                         flip=not args.no_flip, extra={"irradiance": source}, max_steps=args.steps)
    dt = time.perf_counter() - t0
    from spikesim.stream import DatReader
    stream = DatReader(out, cam.height, cam.width, flip=not args.no_flip).read()
    log.info("wrote %s: %d steps in %.2f s (%.3g pixel-steps/s)", out, stream.num_steps, dt,
             stream.num_steps * cam.num_pixels / max(dt, 1e-9))
    s = summary(stream, cam.readout_period_s)
    print(f"{out}: {s['num_steps']} steps of {s['width']}x{s['height']} ({s['duration_s'] * 1e3:.2f} ms), "
          f"mean rate {s['mean_rate_per_step']:.4f} spikes/step ({s['mean_rate_hz']:.0f} Hz), "
          f"dark pixels {s['dark_pixel_fraction']:.1%}")
    return 0


def _progress(frames: Iterator[np.ndarray], args: argparse.Namespace) -> Iterator[np.ndarray]:
    from tqdm import tqdm
    yield from tqdm(frames, desc="frames", unit="frame", disable=args.quiet, mininterval=0.5)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="irradiance frames -> spike stream (.dat + JSON sidecar)")
    src = p.add_argument_group("irradiance source (default: the built-in moving pattern)")
    src.add_argument("--frames", help="an (N, H, W) .npy array of y, or a folder of EXR frames")
    src.add_argument("--scene", help="a bundled scene (ball, car, cook, fan, rotate) or a scene XML to render")
    src.add_argument("--light", default="normal", help="lighting condition of the scene (normal, low)")
    src.add_argument("--motion", help="motion file (default: motion.json beside the XML)")
    src.add_argument("--lights", help="lights file (default: lights.json beside the XML)")
    src.add_argument("--spp", type=int, help="render samples per pixel (default: the renderer's)")
    src.add_argument("--peak-y", type=float, default=0.25, help="pattern brightness: y of white (spikes/step)")
    src.add_argument("--steps", type=int, help="number of steps (pattern default 2000)")
    src.add_argument("--keyframe-every", type=int, default=1,
                     help="frames are keyframes this many steps apart; the sensor interpolates")
    add_camera_arguments(p)
    p.add_argument("--backend", default="auto", choices=["auto", "numpy", "llvm", "cuda"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-flip", action="store_true", help="write rows top-down (SPCS/SCSim convention)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("-o", "--out", type=Path, default=Path("out/stream.dat"))
    p.set_defaults(func=run)
