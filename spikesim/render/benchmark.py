"""Measure the rendering knobs: cost per frame, and error against a high-quality reference.

    python -m spikesim.render.benchmark --out bench.json            # everything (minutes)
    python -m spikesim.render.benchmark --only timing --scenes fan
    python -m spikesim.render.benchmark --only images --images docs/images   # docs/scenes.md figures

Each knob's cost and its error are measured (docs/design.md section 4): samples per pixel, mono
against spectral, keyframes every k steps, and the share of time spent rendering against
simulating spikes.
Errors are relative RMS: sqrt(mean((y - ref)^2)) / mean(ref), over the whole frame.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..outputs import atomic_write_text, atomic_write_with, check_not_link, output_file, output_folder
from .renderer import SceneRenderer

MID_STEP = 430  # the centre of the 861-step LLR sequence (21 windows x 41 steps)


def rel_rmse(y: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((y.astype(np.float64) - ref) ** 2)) / max(float(ref.mean()), 1e-30))


def _timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def timing(scene: str, variant: str, spps: tuple[int, ...] = (1, 4, 16), frames: int = 3,
           light: str = "normal") -> dict[str, Any]:
    """Seconds to load, to render the first frame (kernel compilation included), and per frame."""
    r, load_s = _timed(lambda: SceneRenderer(scene, light=light, variant=variant, spp=1))
    _, first_s = _timed(lambda: r.render_step(0, spp=1))
    per = {}
    for spp in spps:
        r.render_step(1, spp=spp)  # warm this spp
        _, t = _timed(lambda: [r.render_step(MID_STEP + i, spp=spp) for i in range(frames)])
        per[spp] = t / frames
    return {"scene": scene, "variant": variant, "load_s": load_s, "first_frame_s": first_s, "per_frame_s": per}


def spp_error(scene: str, variant: str, spps: tuple[int, ...] = (1, 4, 16), ref_spp: int = 256,
              resolution: tuple[int, int] | None = None) -> dict[int, float]:
    """Relative RMS error of a frame rendered with `spp` against a `ref_spp` reference."""
    r = SceneRenderer(scene, variant=variant, resolution=resolution)
    ref = r.ground_truth(MID_STEP, spp=ref_spp)
    return {spp: rel_rmse(r.render_step(MID_STEP, spp=spp), ref) for spp in spps}


def mono_vs_spectral(scene: str, light: str, spp: int = 64, resolution: tuple[int, int] | None = None) -> dict[str, float]:
    """How far the fast mono path is from the spectral one (grey-surface approximation)."""
    mono = SceneRenderer(scene, light=light, variant="mono", resolution=resolution).ground_truth(MID_STEP, spp=spp)
    spec = SceneRenderer(scene, light=light, variant="spectral", resolution=resolution).ground_truth(MID_STEP, spp=spp)
    noise = rel_rmse(SceneRenderer(scene, light=light, variant="spectral", resolution=resolution, seed=1)
                     .ground_truth(MID_STEP, spp=spp), spec)
    return {"mean_ratio_mono_over_spectral": float(mono.mean() / spec.mean()), "rel_rmse": rel_rmse(mono, spec),
            "spectral_noise_rel_rmse": noise}


def _render_common_seed(r: SceneRenderer, step: int, spp: int, seed: int = 0) -> np.ndarray:
    """y at a step rendered with one fixed seed: Monte Carlo noise is then nearly the same at every
    step (common random numbers), so differences between steps show motion, not noise."""
    from .backend import mi, use_variant

    use_variant(r._variant)
    r.animator.apply(r.time_of(step))
    return np.array(mi.render(r.scene, spp=spp, seed=seed), dtype=np.float32)[..., 0] * r._gain


def keyframe_error(scene: str, ks: tuple[int, ...] = (2, 4, 8, 16, 41), spp: int = 64,
                   resolution: tuple[int, int] | None = None) -> dict[str, Any]:
    """Error of the step halfway between keyframes k apart when the sensor interpolates linearly,
    against rendering that step (both with common random numbers, so the error is the motion's)."""
    r = SceneRenderer(scene, resolution=resolution)
    cache: dict[int, np.ndarray] = {}

    def at(step: int) -> np.ndarray:
        if step not in cache:
            cache[step] = _render_common_seed(r, MID_STEP + step, spp)
        return cache[step]

    out: dict[str, Any] = {"spp": spp}
    for k in ks:
        j = k // 2
        interp = (1 - j / k) * at(0) + (j / k) * at(k)
        out[k] = rel_rmse(interp, at(j))
    return out


def render_vs_simulate(scene: str, light: str = "normal", steps: int = 41, spp: int = 4) -> dict[str, float]:
    """Time to render `steps` frames and to turn them into spikes with the realistic sensor."""
    from spikesim.camera import SpikeCamera
    from spikesim.simulate import Simulator

    r = SceneRenderer(scene, light=light, spp=spp)
    r.render_step(0)
    frames, render_s = _timed(lambda: list(r.frames(MID_STEP, steps)))
    sim = Simulator(SpikeCamera.realistic(), backend="auto", seed=0)
    sim.run(frames[:2])  # compile
    sim = Simulator(SpikeCamera.realistic(), backend="auto", seed=0)
    _, sim_s = _timed(lambda: sim.run(frames))
    return {"steps": steps, "spp": spp, "render_s": render_s, "simulate_s": sim_s,
            "render_share": render_s / (render_s + sim_s)}


def doc_images(out: Path, scene: str = "fan", low_gain: float = 30.0) -> dict[str, float]:
    """docs/scenes.md's figures: ground truth and a 41-step TFP of `scene` at the centre step under
    both lights (low light shown `low_gain` times brighter), and a strip of all five scenes."""
    from PIL import Image

    from scenes import SCENES
    from spikesim.camera import SpikeCamera
    from spikesim.imageio import to_display, write_png
    from spikesim.simulate import Simulator

    half, stats = 20, {}
    for light, gain in (("normal", 1.0), ("low", low_gain)):
        r = SceneRenderer(scene, light=light, spp=4, gt_spp=64, seed=0)
        gt = r.ground_truth(MID_STEP)
        write_png(out / f"{scene}_{light}_gt.png", gt, scale=gain)
        stream = Simulator(SpikeCamera.realistic(), seed=0).run(r.frames(MID_STEP - half, 2 * half + 1))
        tfp = stream.counts().astype(np.float32) / stream.num_steps
        write_png(out / f"{scene}_{light}_tfp.png", tfp, scale=gain)
        stats[f"{light}_gt_mean"], stats[f"{light}_tfp_mean"] = float(gt.mean()), float(tfp.mean())
    strip = Image.new("L", (200 * len(SCENES), 125))
    for i, name in enumerate(SCENES):
        gt = SceneRenderer(name, light="normal", gt_spp=32).ground_truth(MID_STEP)
        strip.paste(Image.fromarray(to_display(gt)).resize((200, 125), Image.BOX), (200 * i, 0))
    atomic_write_with(out / "llr_scenes_normal_gt.png", lambda tmp: strip.save(tmp, format="PNG", optimize=True))
    return stats


def main(argv: list[str] | None = None) -> int:
    from scenes import SCENES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--only", choices=("timing", "spp", "spectral", "keyframes", "share", "images"), nargs="*",
                    default=["timing", "spp", "spectral", "keyframes", "share"])
    ap.add_argument("--images", type=Path, default=Path("docs/images"), help="folder for --only images")
    ap.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    args = ap.parse_args(argv)
    if args.out:
        check_not_link(args.out)  # refused before minutes of measuring, not after
    results: dict[str, Any] = {}

    def report(key: str, value: Any) -> None:
        results.setdefault(key, []).append(value)
        print(key, json.dumps(value), flush=True)

    for scene in args.scenes:
        if "timing" in args.only:
            for variant in ("mono", "spectral"):
                report("timing", timing(scene, variant))
        if "spp" in args.only:
            report("spp_error", {"scene": scene, "variant": "mono", **spp_error(scene, "mono")})
        if "spectral" in args.only:
            for light in ("normal", "low"):
                report("mono_vs_spectral", {"scene": scene, "light": light,
                                            **mono_vs_spectral(scene, light, resolution=(125, 200))})
        if "keyframes" in args.only:
            report("keyframe_error", {"scene": scene, **keyframe_error(scene)})
        if "share" in args.only:
            report("render_vs_simulate", {"scene": scene, **render_vs_simulate(scene)})
    if "images" in args.only:
        with output_folder(args.images):  # the project's output guard: no write through a link
            report("images", doc_images(args.images))
    if args.out:
        with output_file(args.out):
            atomic_write_text(args.out, json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
