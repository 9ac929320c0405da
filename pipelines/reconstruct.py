"""`spikesim reconstruct`: a `.dat` spike stream (simulated, or a real 400x250 / 416-wide
recording) to PNG frames and a GIF (and an MP4 with the `video` extra: imageio-ffmpeg).

The stream is cut into consecutive windows of T steps from --start; each window gives one frame
at its centre step. Methods: tfp, tfi, the traditional stp and snm (causal recurrences over the
stream), or a trained checkpoint (exact chunked inference); every method holds --chunk windows at once. Display:
y * scale, clipped, 1/gamma encoded; --enhance stretch maps a percentile of each frame to white
for very dark results (as the paper does for display), and the default --enhance auto does so for
the frames that would otherwise be near black. The enhancement touches only the pictures:
--save-npy keeps the linear frames for metrics.

Geometry (--height, --width, row order) defaults to what the stream's sidecar or dataset
meta.json records, else 250 x 400 bottom-up. A rerun into the same --out replaces the previous
run's outputs (png/step_*.png, frames.gif/.mp4/.npy, reconstruct.json), so the folder and its JSON
describe exactly the last run; other files there are left alone, and so is an output whose content
is no longer what the run wrote (reconstruct.json records each one's sha256): the rerun refuses. Outputs are built in a hidden
folder inside --out and moved into place only when the run succeeds.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from model.methods import method_from_spec
from model.streaming import StepWindows
from model.threads import set_cpu_threads
from pipelines.argtypes import (add_horizon_arguments, add_threads_argument, float_in, nonnegative_int, positive_float, positive_int,
                                window_steps)
from pipelines.inspect_cmd import header_columns_arg, open_stream
from spikesim._optional import require
from spikesim.errors import UnavailableError
from spikesim.imageio import DARK_PREVIEW_Y
from spikesim.outputs import make_dirs, move_into, output_folder, remove, writable, writing
from spikesim.stream import HEADER_COLUMNS as PKU_HEADER
from spikesim.stream import detect_header_columns  # noqa: F401  (callers and tests reach it here)

PKU_HEIGHT, PKU_WIDTH = 250, 400
# What a run writes in --out: a rerun replaces exactly these (reconstruct.json last).
OUTPUT_FILES = ("frames.gif", "frames.mp4", "frames.npy", "reconstruct.json")
PNG_DIR, PNG_PATTERN = "png", "step_*.png"


def percentage(text: str) -> float:
    """A percentile in (0, 100]."""
    v = positive_float(text)
    if v > 100:
        raise argparse.ArgumentTypeError(f"must be in (0, 100], got {text}")
    return v


def display_frame(y: np.ndarray, enhance: str, gamma: float, scale: float, percentile: float) -> np.ndarray:
    """Linear y (H, W) -> uint8 display image; never used for metrics."""
    from spikesim.imageio import to_display
    if enhance == "none":
        return to_display(y, gamma=1.0, scale=scale)
    if enhance == "gamma":
        return to_display(y, gamma=gamma, scale=scale)
    if enhance == "stretch":
        return to_display(y, gamma=gamma, percentile=percentile)
    if enhance == "auto":  # gamma where the frame is bright enough to see, else stretched
        dark = float(np.percentile(y, percentile)) * scale < AUTO_STRETCH_BELOW_Y
        return display_frame(y, "stretch" if dark else "gamma", gamma, scale, percentile)
    raise ValueError(f"enhance must be none, gamma, stretch or auto, got {enhance!r}")


#: --enhance auto stretches a frame whose `percentile` (99.5th) is below this y (x --scale), as
#: every preview does (spikesim.imageio.DARK_PREVIEW_Y).
AUTO_STRETCH_BELOW_Y = DARK_PREVIEW_Y


def even_sides(img: np.ndarray) -> np.ndarray:
    """The image with its last row and column repeated where a side is odd: H.264 in the yuv420p
    pixel format every player reads takes even sides only (a 200 x 125 frame made a 0-byte MP4)."""
    h, w = img.shape[:2]
    pad = [(0, h % 2), (0, w % 2)] + [(0, 0)] * (img.ndim - 2)
    return np.pad(img, pad, mode="edge") if (h % 2 or w % 2) else img


class _Video:
    """GIF and/or MP4 written frame by frame (nothing accumulates in memory)."""

    def __init__(self, out: Path, fps: float, gif: bool, mp4: bool, shown: Path | None = None) -> None:
        import imageio.v2 as imageio
        self.writers = []
        self.names: list[str] = []
        self.shown = out if shown is None else shown  # the folder errors name (the user's --out)
        if gif:
            with writing(self.shown / "frames.gif"):
                self.writers.append(imageio.get_writer(out / "frames.gif", mode="I", duration=1000.0 / fps, loop=0))
            self.names.append("frames.gif")
        if mp4:
            try:
                require("imageio_ffmpeg", "video", "MP4 output")
            except UnavailableError as exc:  # the MP4 is on by default: a note, the GIF and PNGs go on
                print(f"[reconstruct] no MP4: {exc} (--no-mp4 skips it)", file=sys.stderr)
            else:
                with writing(self.shown / "frames.mp4"):
                    self.writers.append(imageio.get_writer(out / "frames.mp4", fps=fps, codec="libx264",
                                                           quality=8, macro_block_size=1))
                self.names.append("frames.mp4")

    def add(self, img: np.ndarray) -> None:
        for w, name in zip(self.writers, self.names):
            with writing(self.shown / name):
                w.append_data(even_sides(img) if name.endswith(".mp4") else img)

    def close(self) -> None:
        for w, name in zip(self.writers, self.names):
            with writing(self.shown / name):
                w.close()


def reconstruct_file(path: Path, out: Path, method_spec: str = "tfp", height: int | None = None,
                     width: int | None = None, header_columns: int | None = None, flip: bool | None = None,
                     start: int = 0, num_windows: int | None = None, window: int = 41, chunk: int = 8,
                     device: str = "cpu", enhance: str = "auto", gamma: float = 2.2, scale: float = 1.0,
                     percentile: float = 99.5, fps: float = 10.0, gif: bool = True, mp4: bool = True,
                     save_npy: bool = False, progress: bool = True, drop_partial: bool = False,
                     horizon: int | str = "trained", horizon_stride: int | None = None) -> dict:
    """Reconstruct `path` into `out`; returns a summary (also written to out/reconstruct.json).

    height / width / flip None: as recorded beside the stream, else 250 x 400 bottom-up;
    header_columns None: detected (spikesim.stream.detect_header_columns).
    """
    path, out = Path(path), Path(out)
    if not (isinstance(fps, (int, float)) and 0.01 <= fps <= 1000.0):  # a GIF frame lasts at most 655.35 s
        raise ValueError(f"fps: expected 0.01 to 1000 frames per second, got {fps!r}")
    reader, header_columns = open_stream(path, height, width, flip, header_columns, drop_partial)
    height, width, flip = reader.height, reader.width, reader.flip
    method = method_from_spec(method_spec, window, chunk, device, horizon, horizon_stride)
    window = method.window
    available = (reader.num_steps - start) // window
    if start < 0 or available < 1:
        raise ValueError(f"{path}: {reader.num_steps} steps leave no full {window}-step window after --start {start}")
    n = available if num_windows is None else min(num_windows, available)
    notes = []  # said in the record and on stderr: a run that made other than asked said nothing (round seven)
    if num_windows is not None and num_windows > available:
        notes.append(f"--num-windows {num_windows}: only {available} full {window}-step window(s) fit in "
                     f"{reader.num_steps} steps after --start {start}; made {available}")
    source = StepWindows(lambda a, b: reader.read(a, b).unpack(), start, window, n)
    from spikesim.generation.lock import output_lock
    # one run per folder: two runs into one -o left one run's frames under the other's reconstruct.json
    from spikesim.signals import sigterm_raises
    # SIGTERM as Ctrl-C: the stage folder and the lock are removed (it left both, round nine)
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(out, [], "--out")  # frames written into a dataset, which verify reported (round eleven)
    with sigterm_raises(), output_folder(out), output_lock(out, f"reconstruct {path}", what="reconstruct run"):
        check_outputs(out)  # a link where an output goes: refused before any work
        check_record(out)  # a reconstruct.json that is no run's record (a folder, the user's notes)
        check_ownership(out)  # and a file of the user's where one goes
        for stale in out.glob(".reconstruct.*.part"):  # a run killed before its clean-up (round nine): under the lock,
            if stale.is_dir() and not stale.is_symlink():  # none is another run's
                remove(out, stale.name)
        with writing(out):
            stage = Path(tempfile.mkdtemp(prefix=".reconstruct.", suffix=".part", dir=out))
        try:
            _render_frames(method, source, stage, n, start, window, (height, width),
                           lambda y: display_frame(y, enhance, gamma, scale, percentile), fps, gif, mp4, save_npy,
                           progress, shown=out)
            summary = {"input": str(path), "method": method.name, "frames": n, "window": window, "start": start,
                       "height": height, "width": width, "header_columns": header_columns, "flip": flip,
                       "display": {"enhance": enhance, "gamma": gamma, "scale": scale, "percentile": percentile},
                       "outputs": sorted([p.name for p in stage.iterdir()] + ["reconstruct.json"]),
                       "png_frames": sorted(p.name for p in (stage / PNG_DIR).glob(PNG_PATTERN)),
                       "sha256": output_digests(stage)}
            if "frames.mp4" in summary["outputs"] and (height % 2 or width % 2):
                notes.append(f"frames.mp4 is {height + height % 2} x {width + width % 2}: video needs even sides, so "
                             f"the last row or column is repeated (the PNGs and the GIF are {height} x {width})")
            summary["notes"] = notes
            with writing(out / "reconstruct.json"):
                (stage / "reconstruct.json").write_text(json.dumps(summary, indent=2))
            replace_outputs(stage, out)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
    return summary


def _render_frames(method, source: StepWindows, stage: Path, n: int, start: int, window: int,
                   shape: tuple[int, int], to_image, fps: float, gif: bool, mp4: bool, save_npy: bool,
                   progress: bool, shown: Path | None = None) -> None:
    """Write the frames of `method` on `source` into `stage`: PNGs, video, optional .npy. An OS
    error (a full disk) names the file as it will be in `shown` (the user's --out)."""
    from PIL import Image

    shown = stage if shown is None else shown
    (stage / PNG_DIR).mkdir()
    with writing(shown / "frames.npy"):
        npy = (np.lib.format.open_memmap(stage / "frames.npy", mode="w+", dtype=np.float32, shape=(n, *shape))
               if save_npy else None)
    video = _Video(stage, fps, gif, mp4, shown)
    try:
        for i, frame in method.frames(source):
            y = frame.numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
            bad = int(y.size - np.count_nonzero(np.isfinite(y)))
            if bad:  # a black PNG from NaN is no reconstruction: refuse before anything is moved into --out
                raise ValueError(f"method {method.name}: frame {i} (step {start + i * window + window // 2}) has {bad} "
                                 "NaN or infinite pixel(s); nothing was written")
            if npy is not None:
                npy[i] = y
            img = to_image(y)
            centre = start + i * window + window // 2
            name = f"step_{centre:06d}.png"
            with writing(shown / PNG_DIR / name):
                Image.fromarray(img).save(stage / PNG_DIR / name)
            video.add(img)
            if progress and (i + 1) % 10 == 0:
                print(f"[reconstruct] {i + 1}/{n} frames", file=sys.stderr)
    finally:
        video.close()
        if npy is not None:
            with writing(shown / "frames.npy"):
                npy.flush()
            del npy


def check_outputs(out: Path) -> None:
    """Every path a run writes or deletes in `out` (png/, its frames, the video, .npy and JSON)
    is inside it and no symlink: a link there is refused, naming it, not followed
    (spikesim.outputs)."""
    for name in (PNG_DIR, *OUTPUT_FILES):
        writable(out, name)
    png = out / PNG_DIR
    if png.is_dir():
        for old in png.glob(PNG_PATTERN):
            writable(out, PNG_DIR, old.name)


def output_digests(folder: Path) -> dict[str, str]:
    """The sha256 of every output a run wrote in `folder` but its record (frames.gif/.mp4/.npy,
    png/step_*.png), by its name in the folder: a rerun replaces only files that still hold what
    the run wrote (round ten: a user's array saved over a run's frames.npy was deleted)."""
    from spikesim.dataset import sha256_file
    names = [n for n in OUTPUT_FILES if n != "reconstruct.json" and (folder / n).is_file()]
    names += [f"{PNG_DIR}/{p.name}" for p in sorted((folder / PNG_DIR).glob(PNG_PATTERN)) if p.is_file()]
    return {n: sha256_file(folder / n) for n in names}


def check_record(out: Path) -> None:
    """reconstruct.json in `out` is absent or an earlier run's record: a regular file of JSON
    with its "outputs" and "method". Anything else is the user's, refused before any work (round
    ten: a user's notes there were overwritten; a folder there was found only after the frames were
    moved in, rc 2 with png/ and frames.gif left behind)."""
    from spikesim.config_io import read_json_object
    path = out / "reconstruct.json"
    if not path.exists() and not path.is_symlink():
        return
    advice = "a run would replace it: move it, or choose another --out"
    if not path.is_file() or path.is_symlink():
        kind = "a directory" if path.is_dir() else "a link" if path.is_symlink() else "not a regular file"
        raise FileExistsError(f"{path}: is {kind}, where a reconstruct run writes its record; {advice}")
    try:
        record = read_json_object(path, "reconstruct record", finite=False)
    except (OSError, ValueError) as exc:
        raise FileExistsError(f"{path}: not a reconstruct record ({exc}); {advice}") from None
    if not {"outputs", "method"} <= record.keys():
        raise FileExistsError(f"{path}: not a reconstruct record (no \"outputs\" and \"method\"); {advice}")


def recorded_outputs(out: Path) -> tuple[set[str], set[str] | None, dict[str, str] | None]:
    """(the outputs an earlier run's reconstruct.json lists, the PNG frames it lists: None for a
    record made before it listed them, which took every png/step_*.png for its own, and the sha256
    of each: None for a record made before it held them, round ten). The record is read as every
    small file is (a FIFO or a link to /dev/zero is refused, not waited on)."""
    from spikesim.config_io import read_json_object
    try:
        record = read_json_object(out / "reconstruct.json", "reconstruct record", finite=False)
    except (OSError, ValueError):
        return set(), set(), {}
    outputs, frames, digests = record.get("outputs", []), record.get("png_frames"), record.get("sha256")
    listed = {str(x) for x in outputs} if isinstance(outputs, list) else set()
    return (listed, ({str(x) for x in frames} if isinstance(frames, list) else None),
            ({str(k): v for k, v in digests.items()} if isinstance(digests, dict) else None))


def check_ownership(out: Path) -> None:
    """A rerun replaces only what an earlier reconstruct run wrote, as its reconstruct.json lists:
    a user's own frames.npy in the folder (the README's simulate --frames example makes one) was
    deleted, a png/step_*.png of theirs removed (rounds seven and nine: a step_009999.png of the
    user's beside a run's frames). A listed file whose content is no longer what the run wrote
    (its sha256) is the user's too (round ten). Anything else is refused, named."""
    listed, frames, digests = (recorded_outputs(out) if (out / "reconstruct.json").exists()
                               else (set(), set(), {}))
    theirs = [name for name in OUTPUT_FILES if name != "reconstruct.json" and (out / name).exists() and name not in listed]
    png = out / PNG_DIR
    if png.is_dir():
        mine = frames if frames is not None else ({p.name for p in png.glob(PNG_PATTERN)} if PNG_DIR in listed else set())
        theirs += [f"{PNG_DIR}/{p.name}" for p in sorted(png.glob(PNG_PATTERN)) if p.name not in mine]
    changed: list[str] = []
    if digests is not None:  # a record before round ten holds no digests: its names are the rule
        from spikesim.dataset import sha256_file
        ours = [n for n in OUTPUT_FILES if n != "reconstruct.json" and n in listed and (out / n).exists()]
        ours += [f"{PNG_DIR}/{p.name}" for p in sorted(png.glob(PNG_PATTERN)) if p.name in (frames or set())] \
            if png.is_dir() else []
        changed = [n for n in ours if n not in theirs
                   and (not (out / n).is_file() or digests.get(n) != sha256_file(out / n))]
    if changed:
        shown = ", ".join(changed[:3]) + (f" and {len(changed) - 3} more" if len(changed) > 3 else "")
        raise FileExistsError(f"{out}: holds {shown}, changed since the reconstruct run wrote it (the sha256 differs "
                              "from its reconstruct.json's), so yours now; a run would replace or remove it: choose "
                              "another --out, or move it")
    if theirs:
        shown = ", ".join(theirs[:3]) + (f" and {len(theirs) - 3} more" if len(theirs) > 3 else "")
        raise FileExistsError(f"{out}: holds {shown}, which no reconstruct.json there says a reconstruct run wrote; "
                              "a run would replace or remove them: choose another --out, or move them")


def replace_outputs(stage: Path, out: Path) -> None:
    """Move a finished run's outputs from `stage` into `out`, removing what an earlier run wrote
    there that this one did not (stale frames, a video or .npy no longer asked for); files
    that are not outputs of this command are left alone. reconstruct.json moves last. Every
    path is checked first (`check_outputs`): nothing moves if one is a link."""
    check_outputs(out)
    png = make_dirs(out, PNG_DIR)
    fresh = {p.name for p in (stage / PNG_DIR).glob(PNG_PATTERN)}
    for old in png.glob(PNG_PATTERN):
        if old.name not in fresh:
            remove(out, PNG_DIR, old.name)
    for name in sorted(fresh):  # by the folder's descriptor: a folder swapped for a link is not followed
        move_into(stage / PNG_DIR / name, out, PNG_DIR, name)
    for name in OUTPUT_FILES:
        if (stage / name).exists():
            move_into(stage / name, out, name)
        else:
            remove(out, name)


def cmd_reconstruct(args: argparse.Namespace) -> int:
    from model.training import resolve_device
    device = str(resolve_device(args.device))
    set_cpu_threads(args.threads)
    header = None if args.header_columns == "auto" else args.header_columns
    summary = reconstruct_file(Path(args.input), Path(args.out), args.method, args.height, args.width, header,
                               args.flip, args.start, args.num_windows, args.window, args.chunk,
                               device, args.enhance, args.gamma, args.scale,
                               args.percentile, args.fps, not args.no_gif, not args.no_mp4, args.save_npy,
                               progress=not args.quiet, drop_partial=args.drop_partial,
                               horizon=args.horizon, horizon_stride=args.horizon_stride)
    for note in summary.get("notes", []):
        print(f"[reconstruct] note: {note}", file=sys.stderr)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:  # the record is in the output folder; one line says what was made
        print(f"[reconstruct] {summary.get('frames', '?')} frame(s) of {args.input} by {args.method} -> {args.out}")
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `reconstruct` on the CLI's subparsers."""
    p = subparsers.add_parser("reconstruct", help="a .dat spike stream to PNG frames and a GIF/MP4",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", help=".dat spike stream")
    p.add_argument("-o", "--out", required=True, help="output folder")
    p.add_argument("--method", default="tfp",
                   help="tfp, tfi, stp, snm (the traditional STP and SNM), tfp:N (TFP over N steps), lrrep (the "
                        "shipped network), black, mean (floors) or a "
                        "checkpoint path")
    p.add_argument("--height", type=positive_int, help=f"rows (default: as recorded, else {PKU_HEIGHT})")
    p.add_argument("--width", type=positive_int,
                   help=f"image width without header columns (default: as recorded, else {PKU_WIDTH})")
    p.add_argument("--header-columns", type=header_columns_arg, default="auto",
                   help=f"columns to drop at the end of each row: auto (as recorded; else 0, or {PKU_HEADER} for "
                        "416-wide files, deciding by content when the size fits both) or a number")
    flip = p.add_mutually_exclusive_group()
    flip.add_argument("--flip", dest="flip", action="store_true", default=None,
                      help="rows stored bottom-up (real cameras; the default unless recorded otherwise)")
    flip.add_argument("--no-flip", dest="flip", action="store_false",
                      help="rows stored top-down (SPCS/SCSim/LR-Rep authors); default: as recorded, else rows stored bottom-up (flip)")
    p.add_argument("--drop-partial", action="store_true",
                   help="ignore a partial last frame (a recording cut off mid-frame) instead of failing")
    p.add_argument("--start", type=nonnegative_int, default=0, help="first step of the first window")
    p.add_argument("--num-windows", type=positive_int, help="frames to make (default: as many as fit)")
    p.add_argument("--window", type=window_steps, default=41,
                   help="steps per window for tfp/tfi/stp/snm (a model uses its own)")
    p.add_argument("--chunk", type=positive_int, default=8, help="windows held in memory at once, by every method (the frames do not depend on it)")
    add_horizon_arguments(p)
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N or mps")
    add_threads_argument(p)
    p.add_argument("--enhance", choices=["auto", "none", "gamma", "stretch"], default="auto",
                   help="display only: auto (default: gamma, or stretch for a frame whose 99.5th percentile is below "
                        f"y = {AUTO_STRETCH_BELOW_Y}), none (linear), gamma (1/gamma encode), stretch (percentile to "
                        "white + gamma)")
    p.add_argument("--gamma", type=positive_float, default=2.2, help="display gamma of --enhance gamma")
    p.add_argument("--scale", type=positive_float, default=1.0, help="display gain on y before clipping (e.g. 1/0.6)")
    p.add_argument("--percentile", type=percentage, default=99.5,
                   help="percentile mapped to white by --enhance stretch, in (0, 100]")
    # a GIF frame lasts at most 655.35 s (a 16-bit count of 10 ms): --fps 0.001 crashed inside PIL (round eight)
    p.add_argument("--fps", type=float_in(0.01, 1000.0, "frames per second"), default=10.0,
                   help="frames per second of the GIF and MP4 (0.01 to 1000)")
    p.add_argument("--no-gif", action="store_true", help="do not write the GIF")
    p.add_argument("--no-mp4", action="store_true", help="do not write the MP4")
    p.add_argument("--save-npy", action="store_true", help="also write the linear frames to frames.npy")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the run's record (also written to the output folder) as JSON")
    p.set_defaults(func=cmd_reconstruct)
    return p
