"""`spikesim simulate`: irradiance frames (a built-in pattern, a .npy array or EXR files) into a
spike stream on disk, with its JSON sidecar, streamed chunk by chunk."""
from __future__ import annotations

import argparse
import contextlib
import logging
import os
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from pipelines.argtypes import (seed_int, add_device_argument, add_light_power_factor_argument, camera_spec, existing_file, load_camera,
                                nonnegative_float,
                                output_file, positive_int, sensor_steps)
from spikesim import outputs
from spikesim.camera import SpikeCamera
from spikesim.config_io import standard_json
from spikesim.keyframes import keyframe_count, steps_covered
from spikesim.stream import sidecar_path
from spikesim.patterns import MovingPattern

log = logging.getLogger("spikesim.simulate")

NPY_MAGIC = b"\x93NUMPY"  # the first bytes of every .npy file (numpy.lib.format)
DEFAULT_STEPS = 2000  # steps of the pattern and of a rendered scene when --steps is not given
DEFAULT_PEAK_Y = 0.25  # the built-in pattern's y of white when --peak-y is not given


def camera_from_args(args: argparse.Namespace) -> SpikeCamera:
    cam = load_camera(args.camera)
    changes = {k: v for k, v in (("height", args.height), ("width", args.width)) if v is not None}
    return cam.replace(**changes) if changes else cam


def add_camera_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("camera")
    g.add_argument("--camera", type=camera_spec, default="realistic",
                   help="a built-in camera (realistic: every noise term; noiseless: none) or a JSON/TOML camera file")
    g.add_argument("--height", type=positive_int,
                   help="sensor rows (default: a camera file's, else a --scene's film or the --frames', else 250)")
    g.add_argument("--width", type=positive_int,
                   help="sensor columns (default: a camera file's, else a --scene's film or the --frames', else 400)")


def scene_settings(args: argparse.Namespace) -> Any:
    """The film size, samples per pixel and light power factor of a rendered scene, each with its
    origin: the scene's own film and sampler unless a camera file or a flag says otherwise,
    decided as `generate scene` and `render` decide them
    (spikesim.generation.settings.resolve_command_settings)."""
    from spikesim.generation.settings import resolve_command_settings
    from spikesim.render import RenderSettings
    from spikesim.render.scene_files import SceneFiles

    base = load_camera(args.camera)
    flags = {"--spp": {"spp": args.spp}, "--height": {"height": args.height}, "--width": {"width": args.width},
             "--light-power-factor": {"light_power_factor": args.light_power_factor}}
    defaults = {"height": base.height, "width": base.width, "spp": RenderSettings().spp, "light_power_factor": 1.0}
    xml = SceneFiles.resolve(args.scene, args.motion, args.lights).xml
    return resolve_command_settings(xml, defaults, camera=None if args.camera == "realistic" else args.camera,
                                    flags=flags)


def frames_from_source(args: argparse.Namespace, cam: SpikeCamera, sensor_device: str | None = None,
                       settings: Any = None) -> tuple[Iterator[Any], dict, int]:
    """The irradiance source named on the command line, as a frame iterator, a description and
    the number of steps to simulate (--steps, else what the frames cover; the keyframes may reach
    past it, spikesim.keyframes). A rendered scene's frames stay on the render device when the
    sensor runs there too."""
    if args.frames is not None and args.scene is not None:
        raise ValueError("give --frames or --scene, not both")
    for flag, value in (("--motion", args.motion), ("--lights", args.lights), ("--spp", args.spp),
                        ("--light-power-factor", args.light_power_factor)):
        if value is not None and args.scene is None:
            raise ValueError(f"{flag} applies to a rendered scene; give --scene too")
    k = args.keyframe_every
    if args.scene is not None:
        from spikesim.render import SceneRenderer
        settings = settings or scene_settings(args)
        r = SceneRenderer(args.scene, light=args.light or "normal", camera=cam, motion=args.motion, lights=args.lights,
                          spp=settings.values["spp"], seed=args.seed, device=args.device,
                          light_power_factor=settings.values["light_power_factor"])
        steps = DEFAULT_STEPS if args.steps is None else args.steps
        frames = r.frames(0, steps, keyframe_every=k, device=sensor_device == r.device)
        return frames, {"source": "scene", **r.describe(), "settings": settings.table()}, steps
    if args.frames is not None:
        src = Path(args.frames)
        if src.is_dir():
            from pipelines.render_folder import listed_frames
            listed = listed_frames(src, k)  # a render folder: only the frames its record lists
            files = exr_files(src) if listed is None else listed
            steps = frames_steps(args.steps, len(files), k, src)
            files = files[: keyframe_count(steps, k)]
            return _checked_exr_frames(files, cam), {"source": str(src), "frames": len(files)}, steps
        arr = load_npy_frames(src, cam)
        steps = frames_steps(args.steps, arr.shape[0], k, src)
        n = keyframe_count(steps, k)
        return (np.asarray(arr[i]) for i in range(n)), {"source": str(src), "frames": n}, steps
    peak = DEFAULT_PEAK_Y if args.peak_y is None else args.peak_y
    pattern = MovingPattern(height=cam.height, width=cam.width, peak_y=peak,
                            readout_period_s=cam.readout_period_s, seed=args.seed)
    steps = DEFAULT_STEPS if args.steps is None else args.steps
    return pattern.frames(keyframe_count(steps, k), every=k), {"source": "moving_pattern", "peak_y": peak}, steps


def check_source_flags(args: argparse.Namespace) -> None:
    """--light lights a rendered --scene and --peak-y the built-in pattern: given with another
    source they were ignored without a word (round ten: `--frames RENDERFOLDER --light low --peak-y
    0.9` simulated the render's own light, rc 0, where --spp was refused)."""
    if args.light is not None and args.scene is None:
        if args.frames is not None and Path(args.frames).is_dir():
            from pipelines.render_folder import RECORD, read_record
            base = Path(args.frames)
            base = base if (base / RECORD).is_file() else base.parent if (base.parent / RECORD).is_file() else None
            record = (read_record(base) or {}) if base is not None else {}
            light = record.get("light", {}).get("name") if isinstance(record.get("light"), dict) else None
            # the render's own light given again: it said "render again with --light normal" (round eleven)
            if base is not None and light == args.light:
                raise ValueError(f"--light {args.light}: --light is not taken with --frames (the render's own "
                                 f"light {light!r} is used, {base / RECORD}); drop --light")
            if base is not None:
                said = f" (light {light!r}, {base / RECORD})" if isinstance(light, str) else f" ({base / RECORD})"
                raise ValueError(f"--light {args.light}: the render fixed the light of the --frames {args.frames}"
                                 f"{said}; drop --light, or render again with --light {args.light}")
        if args.frames is not None:
            raise ValueError(f"--light {args.light} applies to a rendered --scene only; the --frames {args.frames} "
                             "are lit as they were made; drop --light")
        # round eleven: with no frames given, it said "frames are lit as they were made"
        raise ValueError(f"--light {args.light} applies to a rendered --scene only; the built-in pattern's "
                         "brightness is --peak-y")
    if args.peak_y is not None and (args.frames is not None or args.scene is not None):
        source, light = ((f"--frames {args.frames}", "frames are lit as they were made") if args.frames is not None
                         else (f"--scene {args.scene}", "a scene's light is --light and --light-power-factor"))
        raise ValueError(f"--peak-y {args.peak_y:g} sets the built-in pattern's brightness, not that of {source}; "
                         f"drop --peak-y ({light})")


def _camera_file_sizes(camera: Any) -> bool:
    """Whether --camera is a file that sets the frame size (a preset does not)."""
    if not isinstance(camera, Path):
        return False
    from spikesim.config_io import read_config_file
    data = read_config_file(camera)
    return "height" in data or "width" in data


def frames_size(path: Path, keyframe_every: int = 1) -> tuple[int, int] | None:
    """(H, W) of --frames (a .npy's array, a folder's first EXR); None where it cannot be read, so
    that the reader's own error names what is wrong. `keyframe_every` is the run's: a render folder
    of keyframes checked as frames one step apart was not read, and its size became 250 x 400 (round
    eight)."""
    try:
        if path.is_dir():
            from pipelines.render_folder import listed_frames
            from spikesim.imageio import read_exr
            # a render folder's frames sit under its kind folder, listed by its record (round six: a 16 x 24
            # render folder was read as 250 x 400); a folder of one's own EXRs holds them directly
            files = listed_frames(path, keyframe_every) or exr_files(path)
            shape = read_exr(files[0]).shape
        else:
            shape = np.load(path, mmap_mode="r").shape[1:]
    except (OSError, ValueError, EOFError, IndexError):
        return None
    return (int(shape[0]), int(shape[1])) if len(shape) == 2 and min(shape) > 0 else None


def render_camera_fields(cam: SpikeCamera, folder: Path, camera_spec: Any) -> SpikeCamera:
    """`cam` with the readout period and threshold the render folder's frames were made for: a
    preset camera takes them; a camera file that gives others is refused (round eight: frames
    rendered for 1e-4 s were simulated at 25e-6 s; round nine: frames for a 1000-electron threshold
    simulated by a 500-electron camera, half as bright as its own render; both rc 0)."""
    import math

    from pipelines.render_folder import recorded_camera_fields
    differ = {k: v for k, v in recorded_camera_fields(folder).items()
              if not math.isclose(v, getattr(cam, k), rel_tol=1e-9)}
    if not differ:
        return cam
    if isinstance(camera_spec, Path):
        said = ", ".join(f"{k} {v:g} (the camera's {getattr(cam, k):g})" for k, v in differ.items())
        raise ValueError(f"--frames {folder}: rendered for {said} (its render.json's exposure), but --camera "
                         f"{camera_spec} gives others; render again with that camera (render --exposure), or give "
                         "a camera file with the render's values")
    log.info("%s, the render's (%s/render.json)", ", ".join(f"{k} {v:g}" for k, v in differ.items()), folder)
    return cam.replace(**differ)


def load_npy_frames(path: Path, cam: SpikeCamera) -> np.ndarray:
    """The (N, H, W) array of y in a .npy file, memory-mapped, checked against the camera; every
    error names the file (numpy's own say neither the file nor what was expected)."""
    with open(path, "rb") as f:
        magic = f.read(len(NPY_MAGIC))
    if magic != NPY_MAGIC:  # numpy would try to unpickle it, and blame pickling
        hint = " (an .npz archive? save one array with numpy.save)" if magic.startswith(b"PK") else ""
        raise ValueError(f"{path}: not a .npy file, it does not start with the NumPy header{hint}")
    try:
        arr = np.load(path, mmap_mode="r")
    except (ValueError, EOFError) as exc:  # truncated, a broken header, Python objects
        raise ValueError(f"{path}: not a readable .npy array ({exc})") from exc
    if arr.ndim != 3:
        raise ValueError(f"{path}: expected an (N, H, W) array of y, got shape {arr.shape}")
    # an integer array (an 8-bit image, 0..255) was taken as y = 200 spikes/step: a saturated stream,
    # rc 0 (round eleven); bool and other non-float dtypes are refused alike
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{path}: dtype {arr.dtype}, but frames are linear y (spikes/step) as floats; an 8-bit or "
                         "other integer image must be scaled to y (and linearised, undoing its gamma) first, e.g. "
                         "saved as float32")
    if arr.shape[0] == 0:
        raise ValueError(f"{path}: holds no frames (shape {arr.shape})")
    if arr.shape[1:] != (cam.height, cam.width):
        h, w = arr.shape[1:]
        raise ValueError(f"{path}: frames are {h}x{w} (HxW) but the camera is {cam.height}x{cam.width}; "
                         f"give --height {h} --width {w}")
    return arr


def exr_files(folder: Path) -> list[Path]:
    """The folder's EXR frames in natural name order: numbers in the names compared as numbers
    (round eleven: frame_0 ... frame_11.exr, not zero-padded, were read as 0, 1, 10, 11, 2, ...)."""
    from pipelines.render_folder import natural_key
    files = sorted(folder.glob("*.exr"), key=lambda p: natural_key(p.name))
    if not files:
        raise FileNotFoundError(f"{folder}: no .exr frames in this folder")
    return files


def _checked_exr_frames(files: list[Path], cam: SpikeCamera) -> Iterator[np.ndarray]:
    """Each EXR's y, checked as the simulator would, so that a bad frame names its file."""
    from spikesim.imageio import read_exr
    from spikesim.simulate import check_frame

    for i, f in enumerate(files):
        y = read_exr(f)  # its errors name the file
        try:
            y = check_frame(y, i, cam.height, cam.width)
        except ValueError as exc:
            raise ValueError(f"{f}: {exc}") from None
        yield y


def frames_steps(steps: int | None, num_frames: int, keyframe_every: int, source: Path) -> int:
    """The steps to simulate from `num_frames` stored frames: --steps (refused beyond what the
    frames cover, rather than simulating fewer steps without a word), else all they cover."""
    from pipelines.argtypes import MAX_SENSOR_STEPS
    covered = steps_covered(num_frames, keyframe_every)
    # --steps has this bound; the count the frames give had none and ran 2**31 steps (round eleven)
    if steps is None and covered > MAX_SENSOR_STEPS:
        raise ValueError(f"--frames {source}: {num_frames} keyframes with --keyframe-every {keyframe_every} cover "
                         f"{covered:,} steps, more than the sensor's {MAX_SENSOR_STEPS:,} (2**31 - 1); give a "
                         "smaller --keyframe-every, or --steps of at most that")
    if steps is not None and steps > covered:
        what = (f"{num_frames} frames" if keyframe_every == 1
                else f"{num_frames} keyframes {keyframe_every} steps apart")
        raise ValueError(f"--steps {steps}: the {what} in {source} cover only {covered} steps")
    return covered if steps is None else steps


def check_outputs(args: argparse.Namespace) -> None:
    """-o (and with --twin its twin) and their JSON sidecars can be written and overwrite no file
    this run reads, nor one that is not a stream this command wrote (unless --overwrite); none is a
    symlink (refused, not followed nor replaced: spikesim.outputs). Checked before the simulation,
    which may take long."""
    for out in (Path(args.out),) + ((twin_path(Path(args.out)),) if getattr(args, "twin", False) else ()):
        _check_output(args, out)


@contextlib.contextmanager
def _user_records_aside(args: argparse.Namespace) -> Iterator[None]:
    """With --overwrite, a regular file at a stream's record name that is not a stream's record (the
    user's X.dat.json) is replaced, as --overwrite says; the library's writer refuses it
    (spikesim.stream.check_sidecar_slot). It is moved aside for the run and removed when the run
    succeeds; a run that fails (a bad frame, Ctrl-C) puts it back: it was deleted before simulating
    (round twenty-two)."""
    from spikesim.outputs import new_temp_beside
    from spikesim.stream import is_stream_sidecar, sidecar_path

    aside: list[tuple[Path, Path]] = []
    outs = (Path(args.out),) + ((twin_path(Path(args.out)),) if getattr(args, "twin", False) else ())
    try:
        for out in outs if getattr(args, "overwrite", False) else ():
            side = sidecar_path(out)
            if side.is_file() and not side.is_symlink() and not is_stream_sidecar(side, beside_stream=out.is_file()):
                keep = new_temp_beside(side, ".aside")
                os.replace(side, keep)
                aside.append((side, keep))
        yield
    except BaseException:
        for side, keep in aside:
            if not (side.exists() or side.is_symlink()):
                os.replace(keep, side)
        raise
    finally:
        for _, keep in aside:
            keep.unlink(missing_ok=True)


def _check_output(args: argparse.Namespace, out: Path) -> None:
    from spikesim.outputs import check_replaceable
    from spikesim.stream import sidecar_path

    side = sidecar_path(out)
    check_replaceable(out)  # a device or FIFO: refused even with --overwrite, which it once suggested
    check_replaceable(side)
    if side.is_dir():
        raise ValueError(f"--out {out}: its sidecar {side} is a directory")
    camera_file = args.camera if isinstance(args.camera, Path) else None
    inputs = {"--frames": args.frames, "--camera": camera_file, "--motion": args.motion, "--lights": args.lights}
    for written in (out, side):
        for flag, path in inputs.items():
            if path is not None and written.exists() and Path(path).exists() and written.samefile(path):
                raise ValueError(f"--out {out} would overwrite the {flag} input {path}")
    if out.exists() and not getattr(args, "overwrite", False) and not simulated_stream(out):
        raise ValueError(f"--out {out} exists and is not a spike stream simulate wrote (no sidecar beside it "
                         "that matches its size); pass --overwrite to replace it, or choose another -o")
    if not out.exists() and side.exists() and not getattr(args, "overwrite", False):
        # a user's X.dat.json beside no X.dat was replaced by the new stream's record (round nine)
        raise ValueError(f"--out {out}: {side.name} exists beside no stream, so no simulate run wrote it; pass "
                         "--overwrite to replace it, or choose another -o")


def simulated_stream(path: Path) -> bool:
    """Whether `path` is a stream this command wrote: its sidecar records the spikesim version,
    the geometry and a number of steps that give exactly its size. Such a file a rerun replaces
    without asking (as it always did); any other needs --overwrite."""
    from spikesim.stream import frame_bytes, read_sidecar

    try:
        info = read_sidecar(path)
    except (ValueError, OSError):
        return False
    if not info or "spikesim_version" not in info:
        return False
    h, w, n = info.get("height"), info.get("width"), info.get("num_steps")
    if not all(isinstance(v, int) and v > 0 for v in (h, w, n)):
        return False
    return path.is_file() and path.stat().st_size == n * frame_bytes(h, w)


def run(args: argparse.Namespace) -> int:
    from spikesim.signals import sigterm_raises
    # SIGTERM stops the run as Ctrl-C does, so the partial stream (.NAME.XXXX.part) is removed and it says
    # "interrupted" (round eleven: SIGTERM left the hidden .part behind)
    with sigterm_raises():
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from pipelines.inspect_cmd import summarize
    from spikesim._drjit import resolve_device
    from spikesim.simulate import Simulator

    check_outputs(args)
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(args.out)  # a stream written into a dataset, which verify then reported (round eleven)
    check_source_flags(args)
    cam = camera_from_args(args)
    if args.frames is not None and args.height is None and args.width is None and not _camera_file_sizes(args.camera):
        size = frames_size(Path(args.frames), args.keyframe_every)  # the frames' own size, not the default camera's 250 x 400
        if size is not None:
            cam = cam.replace(height=size[0], width=size[1])
    elif args.frames is not None and Path(args.frames).is_dir():
        check_folder_size(args, cam)
    if args.frames is not None and Path(args.frames).is_dir():
        cam = render_camera_fields(cam, Path(args.frames), args.camera)
    backend = args.backend
    settings = None
    if args.scene is not None and args.frames is None:
        settings = scene_settings(args)  # the scene's film and spp unless a camera file or a flag says otherwise
        cam = cam.replace(height=settings.values["height"], width=settings.values["width"])
        if not args.json:
            print(settings.summary())
        device = resolve_device(args.device)  # an unavailable GPU fails first
        backend = device if backend == "auto" else backend   # the sensor where the frames are
    sim = Simulator(cam, backend=backend, seed=args.seed)  # an unavailable backend fails first
    frames, source, steps = frames_from_source(args, cam, sim.backend_name, settings)
    check_free_space(args, cam, steps)
    log.info("simulating on backend %s, %dx%d, from %s", sim.backend_name, cam.width, cam.height,
             source.get("scene") or source.get("source"))
    try:
        with outputs.output_file(args.out), writing_outputs(args), _user_records_aside(args):  # a failed run leaves
            # no new empty folder, and the user's files as they were
            t0 = time.perf_counter()  # after the wait for another writer of -o (round eighteen)
            if args.twin:
                from spikesim.simulate import TwinSimulator
                out, twin_out = TwinSimulator(sim, None).run_to_dat(
                    _progress(frames, args, steps), args.out, twin_path(args.out), keyframe_every=args.keyframe_every,
                    flip=not args.no_flip, extra={"irradiance": source}, max_steps=steps)
                log.info("wrote the noise-free twin %s", twin_out)
            else:
                out = sim.run_to_dat(_progress(frames, args, steps), args.out, keyframe_every=args.keyframe_every,
                                     flip=not args.no_flip, extra={"irradiance": source}, max_steps=steps)
    except ValueError as exc:  # a bad frame of an .npy: name the file (EXR frames name theirs)
        if args.scene is not None and str(exc).startswith("frame "):  # a device frame the sensor refused
            from spikesim.render.scene_checks import brightest_emitters
            from spikesim.render.errors import SceneError
            emitters = brightest_emitters(source.get("light", {}).get("emitters"))
            raise SceneError(source["files"]["xml"], f"a rendered frame cannot be simulated: {exc}; check the camera, "
                             "the materials and the emitters" + (f"; its emitters, brightest first: {emitters}"
                                                                 if emitters else "")) from exc
        if args.frames is None or Path(args.frames).is_dir():
            raise
        raise ValueError(f"{args.frames}: {exc}") from exc
    dt = time.perf_counter() - t0
    from spikesim.stream import DatReader
    reader = DatReader(out, cam.height, cam.width, flip=not args.no_flip)
    log.info("wrote %s: %d steps in %.2f s (%.3g pixel-steps/s)", out, len(reader), dt,
             len(reader) * cam.num_pixels / max(dt, 1e-9))
    s = summarize(reader, 0, len(reader), cam.readout_period_s, window=41)  # chunked: bounded memory
    if args.json:
        print(standard_json({"out": str(out), "seconds": dt, **s}, indent=2, default=float))
        return 0
    print(f"{out}: {s['num_steps']} steps of {s['width']}x{s['height']} ({s['duration_s'] * 1e3:.2f} ms), "
          f"mean rate {s['mean_rate_per_step']:.4f} spikes/step ({s['mean_rate_hz']:.0f} Hz), "
          f"dark pixels {s['dark_pixel_fraction']:.1%}")
    return 0


@contextlib.contextmanager
def writing_outputs(args: argparse.Namespace) -> Iterator[None]:
    """Hold the lock of each stream this run writes (-o, and its twin; spikesim.outputs.output_file_lock)
    while it writes them, and remove the partial streams and records (`.NAME.XXXXXXXX.part`) that a
    killed run writing the same file left: a stream of GBs stayed beside -o for good (round seventeen).
    Under the locks no other simulate writes them, so no temporary found is a live run's; and only
    where the killed run's lock is found, so a user's file of that form elsewhere is kept."""
    outs = [Path(args.out)] + ([twin_path(Path(args.out))] if args.twin else [])
    with contextlib.ExitStack() as held:
        left = [held.enter_context(outputs.output_file_lock(out)) for out in outs]
        for out, killed in zip(outs, left):
            if not killed:  # no killed simulate of this output: a file of that form is a user's (round eighteen)
                continue
            folder = out.parent
            outputs.remove_temporaries(folder, outputs.stale_temporaries(folder, [out.name, sidecar_path(out).name]),
                                       "simulate", log.info)
            _put_back_aside(args, out)
        yield


def _put_back_aside(args: argparse.Namespace, out: Path) -> None:
    """A user's record file that a killed `simulate --overwrite` had moved aside (_user_records_aside)
    goes back to its name, and the outputs are checked again with it there: it stayed hidden, and a
    rerun without --overwrite went ahead where the file would have stopped it (round twenty-three).
    Where something else now holds the name, the hidden copy is kept and named."""
    side = sidecar_path(out)
    for keep in outputs.stale_temporaries(out.parent, [side.name], ".aside"):
        if side.exists() or side.is_symlink():
            log.warning("%s: a copy of %s that a killed simulate --overwrite had moved aside; kept, since %s exists "
                        "again", keep, side.name, side.name)
            continue
        os.replace(keep, side)
        log.warning("%s: put back from %s, where a killed simulate --overwrite had moved it", side, keep.name)
        _check_output(args, out)


def check_folder_size(args: argparse.Namespace, cam: SpikeCamera) -> None:
    """A folder of EXR frames of another size than --height/--width (or a camera file) ask for:
    refused naming the frames' size and what to do (round ten: the error advised
    `SpikeCamera.realistic(height=..., width=...)`, a Python call, to a command-line user)."""
    from pipelines.render_folder import RECORD, listed_frames
    folder = Path(args.frames)
    size = frames_size(folder, args.keyframe_every)
    if size is None or size == (cam.height, cam.width):
        return
    first = (listed_frames(folder, args.keyframe_every) or exr_files(folder))[0]  # frames_size read it
    whose = ("the render folder's" if (folder / RECORD).is_file() or (folder.parent / RECORD).is_file()
             else "the folder's")
    given = ("--height/--width" if args.height is not None or args.width is not None
             else f"the --camera {args.camera}")
    raise ValueError(f"--frames {folder}: {whose} frames ({first.name} and on) are {size[0]} x {size[1]} (H x W), "
                     f"but {given} ask for {cam.height} x {cam.width}; drop --height/--width (the frames give the "
                     f"size), or give --height {size[0]} --width {size[1]}")


def check_free_space(args: argparse.Namespace, cam: SpikeCamera, steps: int) -> None:
    """The stream (and its twin) must fit on the disk: --steps 1e23 was simulated until the disk was
    full (round ten). Checked before the simulation; a stream replaced by this run frees its size."""
    import shutil

    from spikesim.stream import frame_bytes
    outs = [Path(args.out)] + ([twin_path(Path(args.out))] if args.twin else [])
    need = len(outs) * steps * frame_bytes(cam.height, cam.width)
    parent = next((p for p in Path(args.out).absolute().parents if p.exists()), None)
    if parent is None:
        return
    try:
        free = shutil.disk_usage(parent).free + sum(p.stat().st_size for p in outs if p.is_file())
    except OSError:
        return
    if need > free:
        raise ValueError(f"--out {args.out}: {steps:,} steps of {cam.height} x {cam.width} make "
                         f"{need / 1e9:.3g} GB of stream{'s' if len(outs) > 1 else ''}, but {parent} has "
                         f"{free / 1e9:.3g} GB free; simulate fewer --steps, or write elsewhere")


def twin_path(out: Path) -> Path:
    """Where `simulate --twin` writes the noise-free twin of stream `out`: NAME_twin.dat beside it."""
    return out.with_name(f"{out.stem}_twin{out.suffix or '.dat'}")


def _progress(frames: Iterator[np.ndarray], args: argparse.Namespace, steps: int) -> Iterator[np.ndarray]:
    from spikesim.progress import progress_bar
    yield from progress_bar(frames, total=keyframe_count(steps, args.keyframe_every), desc="frames", unit="frame",
                            quiet=args.quiet)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="irradiance frames -> spike stream (.dat + JSON sidecar)")
    src = p.add_argument_group("irradiance source (default: the built-in moving pattern)")
    src.add_argument("--frames", type=frames_path,
                     help="an (N, H, W) .npy array of y (floats), or a folder of EXR frames (a render -o folder: the "
                          "frames its render.json lists, in step order; another folder: its .exr files in natural "
                          "name order, numbers compared as numbers, so frame_2.exr comes before frame_10.exr)")
    src.add_argument("--scene", help="a bundled scene (ball, car, cook, fan, rotate) or a scene XML to render")
    src.add_argument("--light", default=None,
                     help="lighting condition of a --scene (default normal; low; a scene XML without a lights.json: "
                          "normal, its own emitters)")
    src.add_argument("--motion", type=existing_file, help="motion file (default: motion.json beside the XML)")
    src.add_argument("--lights", type=existing_file, help="lights file (default: lights.json beside the XML)")
    src.add_argument("--spp", type=positive_int, help="render samples per pixel (default: the scene's sampler, else 4)")
    add_light_power_factor_argument(src)
    add_device_argument(src, sensor="backend")
    src.add_argument("--peak-y", type=peak_y, default=None,
                     help=f"the built-in pattern's brightness: y of white (spikes/step; default {DEFAULT_PEAK_Y})")
    src.add_argument("--steps", type=sensor_steps,
                     help=f"sensor steps to simulate, whatever --keyframe-every is, at most 2**31 - 1 (default: "
                          f"{DEFAULT_STEPS} for the pattern and a scene; every step the --frames cover)")
    src.add_argument("--keyframe-every", type=sensor_steps, default=1,
                     help="frames are keyframes this many steps apart, at most 2**31 - 1; the sensor interpolates "
                          "(default 1)")
    add_camera_arguments(p)
    p.add_argument("--backend", default="auto", choices=["auto", "numpy", "llvm", "cuda"],
                   help="sensor backend: auto (cuda > llvm > numpy), the NumPy reference, Dr.Jit CPU or GPU")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the sensor's noise and fixed patterns")
    p.add_argument("--no-flip", action="store_true",
                   help="write rows top-down (SPCS/SCSim convention; default: rows stored bottom-up (flip), as real cameras)")
    p.add_argument("--twin", action="store_true",
                   help="also write the noise-free twin stream (every noise term off, the same frames and initial "
                        "state) as NAME_twin.dat beside -o, with its own sidecar")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the stream's summary as JSON")
    p.add_argument("-o", "--out", type=output_file, default=Path("out/stream.dat"),
                   help="the .dat file to write (its JSON sidecar goes beside it)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace -o even if it is not a stream simulate wrote (one is replaced without it)")
    p.set_defaults(func=run)


def frames_path(text: str) -> Path:
    """--frames: an existing .npy file or folder (of EXR frames)."""
    p = Path(text)
    if p.is_dir():
        if not os.access(p, os.R_OK | os.X_OK):
            raise argparse.ArgumentTypeError(f"{text}: folder cannot be read")
        return p
    p = existing_file(text)
    if p.suffix.lower() != ".npy":
        raise argparse.ArgumentTypeError(f"{text}: expected a .npy array or a folder of .exr files")
    return p


def peak_y(text: str) -> float:
    """--peak-y: y >= 0 that fits the float32 frames (beyond, the pattern would be infinite)."""
    v = nonnegative_float(text)
    if v > float(np.finfo(np.float32).max):
        raise argparse.ArgumentTypeError(f"must be at most {float(np.finfo(np.float32).max):.4g} (float32), got {text}")
    return v
