"""`spikesim reconstruct`: a `.dat` spike stream (simulated, or a real 400x250 / 416-wide
recording) to PNG frames and a GIF (and an MP4 when imageio-ffmpeg is installed).

The stream is cut into consecutive windows of T steps from --start; each window gives one frame
at its centre step. Methods: tfp, tfi, or a trained checkpoint (exact chunked inference, memory
bounded by --chunk). Display: y * scale, clipped, 1/gamma encoded; --enhance stretch maps a
percentile of each frame to white for very dark results (as the paper does for display). The
enhancement touches only the pictures: --save-npy keeps the linear frames for metrics.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from model.methods import method_from_spec
from model.streaming import StepWindows

PKU_HEIGHT, PKU_WIDTH, PKU_HEADER = 250, 400, 16


def detect_header_columns(path: Path, height: int, width: int) -> int:
    """0 when the file is whole frames of `width` columns, else 16 when it is whole frames of
    width + 16 (real recordings with a header); an error naming both sizes otherwise."""
    size = path.stat().st_size
    plain = (height * width + 7) // 8
    wide = (height * (width + PKU_HEADER) + 7) // 8
    if size % plain == 0:
        return 0
    if size % wide == 0:
        return PKU_HEADER
    raise ValueError(f"{path}: {size} bytes is neither whole {height}x{width} frames ({plain} bytes) nor "
                     f"whole {height}x{width + PKU_HEADER} frames ({wide} bytes); check --height/--width")


def display_frame(y: np.ndarray, enhance: str, gamma: float, scale: float, percentile: float) -> np.ndarray:
    """Linear y (H, W) -> uint8 display image; never used for metrics."""
    from spikesim.imageio import to_display
    if enhance == "none":
        return to_display(y, gamma=1.0, scale=scale)
    if enhance == "gamma":
        return to_display(y, gamma=gamma, scale=scale)
    if enhance == "stretch":
        return to_display(y, gamma=gamma, percentile=percentile)
    raise ValueError(f"enhance must be none, gamma or stretch, got {enhance!r}")


class _Video:
    """GIF and/or MP4 written frame by frame (nothing accumulates in memory)."""

    def __init__(self, out: Path, fps: float, gif: bool, mp4: bool) -> None:
        import imageio.v2 as imageio
        self.writers = []
        if gif:
            self.writers.append(imageio.get_writer(out / "frames.gif", mode="I", duration=1000.0 / fps, loop=0))
        if mp4:
            try:
                import imageio_ffmpeg  # noqa: F401
            except ImportError:
                print("[reconstruct] imageio-ffmpeg is not installed: no MP4 (pip install imageio-ffmpeg)",
                      file=sys.stderr)
            else:
                self.writers.append(imageio.get_writer(out / "frames.mp4", fps=fps, codec="libx264",
                                                       quality=8, macro_block_size=1))

    def add(self, img: np.ndarray) -> None:
        for w in self.writers:
            w.append_data(img)

    def close(self) -> None:
        for w in self.writers:
            w.close()


def reconstruct_file(path: Path, out: Path, method_spec: str = "tfp", height: int = PKU_HEIGHT,
                     width: int = PKU_WIDTH, header_columns: int | None = None, flip: bool = True,
                     start: int = 0, num_windows: int | None = None, window: int = 41, chunk: int = 8,
                     device: str = "cpu", enhance: str = "gamma", gamma: float = 2.2, scale: float = 1.0,
                     percentile: float = 99.5, fps: float = 10.0, gif: bool = True, mp4: bool = True,
                     save_npy: bool = False, progress: bool = True) -> dict:
    """Reconstruct `path` into `out`; returns a summary (also written to out/reconstruct.json)."""
    from PIL import Image
    from spikesim.stream import DatReader

    path = Path(path)
    if header_columns is None:
        header_columns = detect_header_columns(path, height, width)
    reader = DatReader(path, height, width, flip=flip, header_columns=header_columns)
    method = method_from_spec(method_spec, window, chunk, device)
    window = method.window
    available = (reader.num_steps - start) // window
    if start < 0 or available < 1:
        raise ValueError(f"{path}: {reader.num_steps} steps leave no full {window}-step window after --start {start}")
    n = available if num_windows is None else min(num_windows, available)
    source = StepWindows(lambda a, b: reader.read(a, b).unpack(), start, window, n)
    out.mkdir(parents=True, exist_ok=True)
    (out / "png").mkdir(exist_ok=True)
    npy = (np.lib.format.open_memmap(out / "frames.npy", mode="w+", dtype=np.float32, shape=(n, height, width))
           if save_npy else None)
    video = _Video(out, fps, gif, mp4)
    try:
        for i, frame in method.frames(source):
            y = frame.numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
            if npy is not None:
                npy[i] = y
            img = display_frame(y, enhance, gamma, scale, percentile)
            centre = start + i * window + window // 2
            Image.fromarray(img).save(out / "png" / f"step_{centre:06d}.png")
            video.add(img)
            if progress and (i + 1) % 10 == 0:
                print(f"[reconstruct] {i + 1}/{n} frames", file=sys.stderr)
    finally:
        video.close()
        if npy is not None:
            npy.flush()
    summary = {"input": str(path), "method": method.name, "frames": n, "window": window, "start": start,
               "height": height, "width": width, "header_columns": header_columns, "flip": flip,
               "display": {"enhance": enhance, "gamma": gamma, "scale": scale, "percentile": percentile},
               "outputs": sorted(p.name for p in out.iterdir())}
    (out / "reconstruct.json").write_text(json.dumps(summary, indent=2))
    return summary


def cmd_reconstruct(args: argparse.Namespace) -> int:
    from pipelines.train import resolve_device
    if args.threads:
        torch.set_num_threads(args.threads)
    header = None if args.header_columns == "auto" else int(args.header_columns)
    summary = reconstruct_file(Path(args.input), Path(args.out), args.method, args.height, args.width, header,
                               not args.no_flip, args.start, args.num_windows, args.window, args.chunk,
                               str(resolve_device(args.device)), args.enhance, args.gamma, args.scale,
                               args.percentile, args.fps, not args.no_gif, not args.no_mp4, args.save_npy,
                               progress=not args.quiet)
    print(json.dumps(summary, indent=2))
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `reconstruct` on the CLI's subparsers."""
    p = subparsers.add_parser("reconstruct", help="a .dat spike stream to PNG frames and a GIF/MP4",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", help=".dat spike stream")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--method", default="tfp", help="tfp, tfi or a checkpoint path (default tfp)")
    p.add_argument("--height", type=int, default=PKU_HEIGHT)
    p.add_argument("--width", type=int, default=PKU_WIDTH, help="image width without header columns")
    p.add_argument("--header-columns", default="auto",
                   help="columns to drop at the start of each row: auto (0, or 16 for 416-wide files) or a number")
    p.add_argument("--no-flip", action="store_true",
                   help="rows stored top-down (SPCS/SCSim/LR-Rep authors); default: real-camera bottom-up")
    p.add_argument("--start", type=int, default=0, help="first step of the first window")
    p.add_argument("--num-windows", type=int, help="frames to make (default: as many as fit)")
    p.add_argument("--window", type=int, default=41, help="steps per window for tfp/tfi (a model uses its own)")
    p.add_argument("--chunk", type=int, default=8, help="windows held in memory by a network")
    p.add_argument("--device", default="auto")
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--enhance", choices=["none", "gamma", "stretch"], default="gamma",
                   help="display only: none (linear), gamma (1/gamma encode; default), stretch (percentile to white + gamma)")
    p.add_argument("--gamma", type=float, default=2.2)
    p.add_argument("--scale", type=float, default=1.0, help="display gain on y before clipping (e.g. 1/0.6)")
    p.add_argument("--percentile", type=float, default=99.5, help="percentile mapped to white by --enhance stretch")
    p.add_argument("--fps", type=float, default=10.0)
    p.add_argument("--no-gif", action="store_true")
    p.add_argument("--no-mp4", action="store_true")
    p.add_argument("--save-npy", action="store_true", help="also write the linear frames to frames.npy")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_reconstruct)
    return p
