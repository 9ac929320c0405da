"""`spikesim render`: render a scene's frames or ground truth at given steps to EXR + PNG.

    spikesim render ball --light low --steps 0:861:41 --ground-truth --out out/ball_low
    spikesim render fan --variant spectral --spp 4 --steps 0:41 --height 125 --width 200

Writes <out>/<frames|gt>/step_NNNNNN.exr (linear y, float32) and a tone-mapped .png beside each,
plus <out>/render.json (SceneRenderer.describe(), timings and the files written). With --variant
rgb it writes PNG previews only (RGB renders carry no y). A folder holds one run: a rerun replaces
the files its render.json lists, and refuses files no record lists.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from pipelines.argtypes import (seed_int, add_device_argument, add_light_power_factor_argument, config_file, existing_file,
                                float_in, output_dir, positive_float, positive_int)
from spikesim.outputs import atomic_write_with, output_folder, writing


MAX_STEPS = 1_000_000  # steps one call may render (a typo such as 0:1e11 would exhaust memory instead)


def _bounded_range(r: range, already: int) -> range:
    # counted in Python integers: len() of 5:10**21:3 overflowed a C ssize_t, a traceback (round ten)
    count = max(0, -(-(r.stop - r.start) // r.step))
    if already + count > MAX_STEPS:
        raise argparse.ArgumentTypeError(f"{r.start}:{r.stop}:{r.step} selects {count:,} steps; "
                                         f"at most {MAX_STEPS:,} per call")
    return r


def parse_steps(spec: str) -> list[int]:
    """"0,20,40", "0:41" (range), "0:861:41" (range with stride), or a comma list of those."""
    steps: list[int] = []
    for part in spec.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if ":" in part:
                nums = [int(x) for x in part.split(":")]
                if len(nums) not in (2, 3):
                    raise ValueError
                steps.extend(_bounded_range(range(*nums), len(steps)))
            else:
                steps.append(int(part))
        except ValueError:
            raise argparse.ArgumentTypeError(f"bad step specification {part!r}; use N, A:B or A:B:S") from None
    if not steps or min(steps) < 0:
        raise argparse.ArgumentTypeError(f"{spec!r} selects no steps, or a negative one")
    seen: set[int] = set()
    if twice := sorted({s for s in steps if s in seen or seen.add(s)}):
        # 0,0,0 rendered one frame three times; simulate then asked for --keyframe-every 0 (round eight)
        raise argparse.ArgumentTypeError(f"{spec!r} selects step(s) {', '.join(map(str, twice[:5]))} more than once")
    return steps


def _resolution(args: argparse.Namespace) -> tuple[int, int] | None:
    """(height, width) from --height and --width, which go together."""
    if (args.height is None) != (args.width is None):
        raise ValueError("--height and --width go together (or leave both out for the scene's own film)")
    return None if args.height is None else (args.height, args.width)


def resolve_render_settings(args: argparse.Namespace, xml: Path) -> Any:
    """The film size, samples per pixel and light power factor of this run, each with its origin:
    the scene's own film and sampler unless a settings file or a flag says otherwise, decided as
    `generate scene` decides them (spikesim.generation.settings.resolve_command_settings)."""
    from spikesim.config_io import read_config_file
    from spikesim.generation.settings import resolve_command_settings
    from spikesim.render import RenderSettings

    _resolution(args)  # --height and --width go together
    defaults = RenderSettings()
    file_values = read_config_file(args.render_settings) if args.render_settings is not None else None
    flags = {"--spp": {"spp": args.spp}, "--gt-spp": {"gt_spp": args.gt_spp},
             "--height": {"height": args.height}, "--width": {"width": args.width},
             "--light-power-factor": {"light_power_factor": args.light_power_factor}}
    return resolve_command_settings(xml, {"spp": defaults.spp, "gt_spp": defaults.gt_spp, "light_power_factor": 1.0},
                                    settings=file_values, settings_origin=f"--render-settings {args.render_settings}",
                                    flags=flags)


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register the `render` subcommand on an argparse subparsers object."""
    p = subparsers.add_parser("render", help="render a scene's frames or ground truth to EXR + PNG",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="bundled scene name (ball, car, cook, fan, rotate) or a scene XML path")
    p.add_argument("--light", default="normal", help="lighting condition in the scene's lights.json (default normal)")
    p.add_argument("--variant", choices=("auto", "mono", "spectral", "rgb"), default=None,
                   help="mono (fast), spectral (accurate), rgb (previews only) or auto (default: mono when "
                        "the lighting has one spectrum, else spectral)")
    p.add_argument("--steps", type=parse_steps, default=[0], help="steps to render: N, A:B, A:B:S, comma lists")
    p.add_argument("--ground-truth", action="store_true", help="render ground truth (gt_spp) instead of frames")
    p.add_argument("--spp", type=positive_int, default=None,
                   help="samples per pixel per frame render (default: the scene's sampler, else 4)")
    p.add_argument("--gt-spp", type=positive_int, default=None,
                   help="samples per pixel of a ground-truth image, spread over its motion-blur sub-step renders (default 64)")
    p.add_argument("--seed", type=seed_int, default=None, help="render seed (default 0)")
    add_device_argument(p, sensor="none")
    p.add_argument("--height", type=positive_int, help="film rows, pixels (default: the scene's film; with --width)")
    p.add_argument("--width", type=positive_int, help="film columns, pixels (default: the scene's film; with --height)")
    add_light_power_factor_argument(p)
    p.add_argument("--motion", type=existing_file, default=None, help="motion file (default: motion.json beside the XML)")
    p.add_argument("--lights", type=existing_file, default=None, help="light file (default: lights.json beside the XML)")
    p.add_argument("--render-settings", type=config_file, default=None, metavar="FILE",
                   help="JSON/TOML file of render settings (spikesim.render_settings.RenderSettings)")
    p.add_argument("--exposure", type=config_file, default=None,
                   help="JSON/TOML file of Exposure (optics, pixel, T, threshold)")
    p.add_argument("--png-scale", type=positive_float, default=None, help="PNG preview: multiply y by this before display")
    p.add_argument("--png-percentile", type=float_in(0.0, 100.0, "a percentile"), default=None,
                   help="PNG preview: map this percentile (0-100) of y to white (default: 99.5 for a frame whose "
                        "99.5th percentile is below y = 0.25, else y = 1 is white)")
    p.add_argument("-o", "--out", type=output_dir, default=Path("out/render"), help="output folder")
    p.add_argument("--quiet", action="store_true",
                   help="no line per step: the settings and one line of what was written")
    p.add_argument("--json", action="store_true", help="print the render description (render.json) instead of file names")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from spikesim.generation.lock import output_lock
    from spikesim.signals import sigterm_raises
    # the folder is this run's until it ends: two renders into one -o left one's frames unlisted
    # beside the other's record, and every later render there was refused (round six). SIGTERM
    # stops it as Ctrl-C does, so its stage and lock are removed (round ten: both were left).
    with sigterm_raises(), output_folder(args.out), output_lock(args.out, f"render {args.scene}", what="render run"):
        remove_dead_stages(args.out)
        return _run(args)


def remove_dead_stages(out: Path) -> None:
    """Remove the stage folders (.render.XXXX.part) of runs killed before their clean-up (SIGKILL,
    a power cut): under the folder's lock none is another run's (round ten: a killed render's 60
    files stayed, and no later run removed them)."""
    from spikesim.outputs import remove
    for stale in Path(out).glob(".render.*.part"):
        if stale.is_dir() and not stale.is_symlink():
            remove(out, stale.name)


def _run(args: argparse.Namespace) -> int:
    from pipelines.render_folder import check_output_folder
    from spikesim.render import Exposure, RenderSettings, SceneRenderer
    from spikesim.render.scene_files import SceneFiles

    previous = check_output_folder(args.out)  # files no record lists: refused before any rendering
    # A bad scene, light or config file raises SceneError/ValueError: one line from pipelines.cli.
    settings = RenderSettings.from_file(args.render_settings) if args.render_settings is not None else None
    exposure = Exposure.from_file(args.exposure) if args.exposure is not None else None
    resolved = resolve_render_settings(args, SceneFiles.resolve(args.scene, args.motion, args.lights).xml)
    used = resolved.values
    film = (used["height"], used["width"]) if "height" in used and "width" in used else None
    renderer = SceneRenderer(args.scene, light=args.light, variant=args.variant, spp=used["spp"],
                             gt_spp=used["gt_spp"], resolution=film, seed=args.seed, motion=args.motion,
                             lights=args.lights, settings=settings, exposure=exposure, device=args.device,
                             light_power_factor=used["light_power_factor"])
    if not args.json:
        print(resolved.summary())
    kind = "gt" if args.ground_truth else ("preview" if renderer.variant == "rgb" else "frames")
    meta, written = _render_into(args, renderer, kind, previous, resolved.table())
    if args.json:
        print(json.dumps({**meta, "files": written}, indent=2, default=str))
    elif args.quiet:
        print(f"{args.out / kind}: {len(args.steps)} step(s), {sum(meta['seconds_per_step']):.2f} s")
    return 0


def _render_into(args: argparse.Namespace, renderer: Any, kind: str, previous: list[str],
                 settings_table: Any) -> tuple[dict, list[str]]:
    from pipelines.render_folder import remove_stage, replace_outputs
    from spikesim.imageio import auto_percentile, write_exr, write_png
    from spikesim.render import write_ground_truth

    # The run is written aside and moved in whole, so the folder always holds one run: a failed
    # rerun leaves the previous one as it was. An OS error (a full disk) names the file as it
    # would be in -o, not in the hidden stage.
    with writing(args.out):
        stage = Path(tempfile.mkdtemp(prefix=".render.", suffix=".part", dir=args.out))
    try:
        folder = stage / kind
        folder.mkdir()
        timings = []
        for step in args.steps:
            t0 = time.perf_counter()
            name = folder / f"step_{step:06d}"
            with writing(args.out / kind, stage=stage):
                if kind == "preview":
                    rgb = renderer.preview_rgb(step)
                    _write_rgb_png(name.with_suffix(".png"), rgb, args.png_scale, args.png_percentile)
                elif kind == "gt":
                    write_ground_truth(renderer, [step], folder, png_scale=args.png_scale,
                                       png_percentile=args.png_percentile)
                else:
                    y = renderer.render_step(step)
                    write_exr(name.with_suffix(".exr"), y)
                    write_png(name.with_suffix(".png"), y, scale=args.png_scale,
                              percentile=auto_percentile(y, args.png_scale, args.png_percentile))
            timings.append(time.perf_counter() - t0)
            if not args.json and not args.quiet:
                print(f"{args.out / kind / name.name}  ({timings[-1]:.2f} s)")
        meta = {**renderer.describe(), "kind": kind, "steps": args.steps, "seconds_per_step": timings,
                "stats": renderer.stats, "settings": settings_table}
        written = [p.relative_to(stage).as_posix() for p in sorted(stage.rglob("*")) if p.is_file()]
        replace_outputs(stage, args.out, written, previous, meta)
    finally:
        remove_stage(stage)
    return meta, written


def _write_rgb_png(path: Path, rgb, scale: float | None, percentile: float | None) -> None:
    import numpy as np
    from PIL import Image

    lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
    if percentile is not None:
        ref = float(np.percentile(lum, percentile))
        scale = 1.0 / ref if ref > 0 else 1.0
    img = np.clip(rgb * (1.0 if scale is None else scale), 0.0, 1.0) ** (1 / 2.2)
    atomic_write_with(path, lambda tmp: Image.fromarray(np.round(img * 255).astype(np.uint8)).save(tmp, format="PNG"))


__all__ = ["add_parser", "run", "parse_steps"]
