"""`spikesim panel`: several methods side by side on one frame of a recording that has no ground
truth (a real camera's), with no-reference measures beside each (model/noref.py).

    spikesim panel recording.dat --height 250 --width 250 --methods tfp tfp:205 lrrep -o panel.png

Every method sees the same windows (all the whole windows of the stream, or --num-windows from
--start); the frame shown is the middle one (--frame to choose). Each image is stretched to its
own 99.5th percentile, since methods differ in gain. Flat regions and edges are chosen on TFP over
all the windows read, so every method is measured on the same pixels: right for a still or slow
scene, where that long average is sharp; say so where it is not.

A simulated stream has a ground truth: --gt IMAGE (EXR, .npy or an 8/16-bit picture, times
--gt-scale, as `evaluate --gt` reads it) puts it first in the panel, and each method's aligned PSNR
against it (clipped at saturation, as `evaluate` scores) joins the measures. The image must show the
frame's centre step, which the command prints:

    spikesim panel data/llr/cook_low/spikes.dat --frame 10 --gt data/llr/cook_low/gt/step_000430.exr -o cook.png
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from model.threads import set_cpu_threads
from pipelines.argtypes import (add_threads_argument, existing_file, nonnegative_int, output_file_in, positive_float,
                                positive_int, window_steps)
from pipelines.inspect_cmd import header_columns_arg, open_stream
from spikesim import outputs
from spikesim.config_io import standard_json


def panel_frames(path: Path, specs: list[str], height: int | None = None, width: int | None = None,
                 header_columns: int | str | None = "auto", flip: bool | None = None, start: int = 0,
                 num_windows: int | None = None, frame: int | None = None, window: int = 41,
                 device: str = "cpu", drop_partial: bool = False) -> tuple[dict[str, np.ndarray], np.ndarray, dict]:
    """({method name: frame (H, W) y}, reference (H, W): TFP over every window read, what was read)."""
    from model.methods import method_from_spec
    from model.streaming import StepWindows

    reader, header = open_stream(Path(path), height, width, flip, header_columns, drop_partial)
    from model.noref import FLAT_BLOCK_PX as block
    if min(reader.height, reader.width) < block:  # said before the methods run, naming the stream (round ten)
        raise ValueError(f"{path}: a {reader.height} x {reader.width} stream; panel's scores find flat regions in "
                         f"{block} x {block} blocks, so frames need at least {block} x {block} pixels")
    available = (reader.num_steps - start) // window
    if available < 1:
        raise ValueError(f"{path}: {reader.num_steps} steps leave no full {window}-step window after --start {start}")
    n = available if num_windows is None else min(num_windows, available)
    index = n // 2 if frame is None else frame
    if not 0 <= index < n:
        raise ValueError(f"--frame {frame}: the {n} windows read are numbered 0..{n - 1}")
    source = StepWindows(lambda a, b: reader.read(a, b).unpack(), start, window, n)
    frames = {}
    for spec in specs:
        method = method_from_spec(spec, window, device=device)
        if method.name in frames:  # a second tile of that name would replace the first, silently
            raise ValueError(f"--methods: two methods are labelled {method.name!r}; name them with label=spec")
        frames[method.name] = np.asarray(next(f for i, f in method.frames(source) if i == index), dtype=np.float64)
        bad = int(frames[method.name].size - np.count_nonzero(np.isfinite(frames[method.name])))
        if bad:  # drawn, NaN is a black tile: no picture of the method
            raise ValueError(f"method {method.name}: frame {index} has {bad} NaN or infinite pixel(s); no panel was written")
    total = None  # spikes per pixel over every window read, summed as read: memory flat in the stream's length
    for i in range(n):
        count = source.windows(i, i + 1)[0].sum(dim=0, dtype=torch.int64)
        total = count if total is None else total + count
    reference = total.numpy().astype(np.float64) / (n * window)
    read = {"input": str(path), "height": reader.height, "width": reader.width, "flip": reader.flip,
            "header_columns": header, "start": start, "windows": n, "window": window, "frame": index,
            "frame_centre_step": start + index * window + window // 2,
            "mean_rate": float(reference.mean())}
    return frames, reference, read


def compose_panel(frames: dict[str, np.ndarray], captions: dict[str, str], percentile: float = 99.5):  # -> PIL.Image
    """The frames left to right, each stretched to its own percentile (gamma 2.2), captioned below."""
    from PIL import Image, ImageDraw

    from spikesim.imageio import to_display

    tiles = [Image.fromarray(to_display(f, percentile=percentile)) for f in frames.values()]
    h, w = tiles[0].height, tiles[0].width
    pad, text_h = 6, 44  # the name, then the caption's two lines (noise, edge): narrow tiles do not overlap
    canvas = Image.new("L", (len(tiles) * (w + pad) + pad, h + 2 * pad + text_h), 255)
    draw = ImageDraw.Draw(canvas)
    for i, (name, tile) in enumerate(zip(frames, tiles)):
        x = pad + i * (w + pad)
        canvas.paste(tile, (x, pad))
        draw.text((x, h + pad + 2), name, fill=0)
        draw.text((x, h + pad + 15), captions.get(name, ""), fill=0)
    return canvas


GT_TILE = "ground truth"


def with_ground_truth(frames: dict[str, np.ndarray], gt: np.ndarray, source: str = "--gt"
                      ) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """The tiles with the ground truth first, and each method's aligned PSNR against it (clipped at
    saturation, as `evaluate` scores). A ground truth of another size, or one a method is named
    after, is refused: the panel would compare pictures of different things."""
    from model.metrics import psnr_aligned
    from spikesim.dataset import SATURATION_Y

    shape = next(iter(frames.values())).shape
    if gt.shape != shape:
        raise ValueError(f"{source} is {gt.shape[0]} x {gt.shape[1]} but the frames are {shape[0]} x {shape[1]}; "
                         "give the ground truth of this stream (and --height/--width as it was recorded)")
    if GT_TILE in frames:
        raise ValueError(f"--methods: a method is labelled {GT_TILE!r}, the ground truth's tile; name it otherwise")
    target = np.clip(np.asarray(gt, dtype=np.float64), 0.0, SATURATION_Y)
    return {GT_TILE: target, **frames}, {name: float(psnr_aligned(f, target)) for name, f in frames.items()}


def run(args: argparse.Namespace) -> int:
    from model.noref import no_reference_scores
    from model.training import resolve_device

    device = str(resolve_device(args.device))
    outputs.check_not_link(args.out)  # refused before the work, not after
    out_path = Path(args.out)
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(out_path)  # a panel written into a dataset, which verify then reports (round ten)
    outputs.check_results_owned(out_path.parent, [out_path.name], "panel")  # a user's PNG there is refused (round eight)
    set_cpu_threads(args.threads)
    gt = None
    if args.gt is not None:  # read before the methods run: a bad image costs nothing
        from spikesim.imageio import read_image_y
        gt = read_image_y(args.gt, args.gt_scale)
    header = None if args.header_columns == "auto" else args.header_columns
    frames, reference, read = panel_frames(args.input, args.methods, args.height, args.width, header, args.flip,
                                           args.start, args.num_windows, args.frame, args.window, device,
                                           args.drop_partial)
    scores = {name: no_reference_scores(f, reference) for name, f in frames.items()}
    captions = {n: f"noise {s['flat_noise']:.3f}\nedge {s['edge_sharpness']:.3f}" for n, s in scores.items()}
    tiles = frames
    if gt is not None:
        tiles, aligned = with_ground_truth(frames, gt, f"--gt {args.gt}")
        for name, value in aligned.items():
            scores[name]["psnr_aligned"] = value
    image = compose_panel(tiles, captions)
    with outputs.output_file(args.out) as out:
        # again, as it is written: a PNG the user put there while the methods ran was replaced (round ten)
        # recorded as it is written (round twelve: a full disk at the record orphaned it)
        with outputs.results_writing(out_path.parent, [out_path.name], "panel"):
            outputs.atomic_write_with(out, lambda tmp: image.save(tmp, format="PNG"))
    doc = {"read": read, "scores": scores, "out": str(out),
           "measures": {"flat_noise": "std / mean in the flattest 10 % of 16 x 16 blocks of the reference (lower: "
                                      "less noise)",
                        "edge_sharpness": "mean |gradient| / mean level on the reference's strongest 5 % of "
                                          "gradients (higher: sharper)",
                        "edge_to_noise": "edge_sharpness / flat_noise",
                        "reference": f"TFP over all {read['windows']} windows read"}}
    if gt is not None:
        doc["ground_truth"] = {"path": str(args.gt), "scale": args.gt_scale}
        doc["measures"]["psnr_aligned"] = ("aligned PSNR (dB) against --gt, clipped at saturation (higher: closer; "
                                           "docs/model.md, \"The aligned PSNR\")")
    if args.json:
        print(standard_json(doc, indent=2))
    else:
        print(f"{read['input']}: {read['height']} x {read['width']}, frame {read['frame']} of {read['windows']} windows "
              f"(centre step {read['frame_centre_step']}), mean rate {read['mean_rate']:.4f} spikes/step")
        aligned = " aligned PSNR (dB) |" if gt is not None else ""
        print(f"| method | flat noise (lower) | edge sharpness (higher) | edge / noise |{aligned}\n"
              f"|---|---|---|---|{'---|' if gt is not None else ''}")
        for name, s in scores.items():
            extra = f" {s['psnr_aligned']:.2f} |" if gt is not None else ""
            print(f"| {name} | {s['flat_noise']:.4f} | {s['edge_sharpness']:.4f} | {s['edge_to_noise']:.2f} |{extra}")
        if not args.quiet:
            print(f"[panel] wrote {out}", file=sys.stderr)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("panel", help="methods side by side on a recording without ground truth, with no-reference measures",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", help=".dat spike stream")
    p.add_argument("-o", "--out", type=output_file_in("panel.png"), required=True,
                   help="the panel PNG to write (a folder: panel.png in it)")
    p.add_argument("--methods", nargs="+", default=["tfp", "tfp:205", "lrrep"],
                   help="methods as evaluate takes them (tfp, tfi, stp, snm, tfp:N, lrrep, checkpoint paths; label=spec)")
    p.add_argument("--frame", type=nonnegative_int, help="which window to show (default: the middle one)")
    p.add_argument("--start", type=nonnegative_int, default=0, help="first step of the first window")
    p.add_argument("--num-windows", type=positive_int, help="windows read (default: every whole window)")
    p.add_argument("--window", type=window_steps, default=41, help="readout steps per window")
    p.add_argument("--height", type=positive_int, help="rows (default: as recorded, else 250)")
    p.add_argument("--width", type=positive_int, help="columns without header (default: as recorded, else 400)")
    p.add_argument("--header-columns", type=header_columns_arg, default="auto",
                   help="columns to drop at the end of each row (auto: as recorded, else detected)")
    p.add_argument("--drop-partial", action="store_true",
                   help="ignore a partial last frame (a recording cut off mid-frame) instead of failing")
    flip = p.add_mutually_exclusive_group()
    flip.add_argument("--flip", dest="flip", action="store_true", default=None,
                      help="rows stored bottom-up (a real PKU camera's files; the default where nothing is recorded)")
    flip.add_argument("--no-flip", dest="flip", action="store_false",
                      help="rows stored top-down (SPCS/SCSim); default: as recorded, else rows stored bottom-up (flip)")
    p.add_argument("--gt", type=existing_file,
                   help="the ground truth of the frame shown (PNG/JPEG/TIFF, EXR or .npy, at its centre step): drawn "
                        "first, and each method's aligned PSNR against it")
    p.add_argument("--gt-scale", type=positive_float, default=1.0,
                   help="y = scale x the --gt image's value (an 8/16-bit picture: of its full scale; default 1)")
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N or mps")
    add_threads_argument(p)
    p.add_argument("--json", action="store_true", help="print the measures as JSON")
    p.add_argument("--quiet", action="store_true", help="no line on stderr (panel has no progress bar)")
    p.set_defaults(func=run)
