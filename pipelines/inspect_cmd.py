"""`spikesim inspect`: shape, duration, firing rate, dark pixels and ISIs of a `.dat` stream.

The stream is read in chunks of about a million pixel-steps and summarised as it goes, so memory
stays a few MB plus a handful of numbers per pixel, whatever the stream's length. The figures
are those of `spikesim.stats.summary` (which needs the whole stream in memory), over every
interval of the stream; ISI percentiles above 65,536 steps are resolved to 1/64 of an octave.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from pipelines.argtypes import nonnegative_int, output_file_in, positive_int, readout_period_s
from spikesim.stream import (DatReader, check_recorded_layout, detect_header_columns, open_stream, read_sidecar,
                             recorded_geometry, sidecar_path, stream_geometry)

CHUNK_PIXEL_STEPS = 1 << 20  # pixels x steps unpacked at a time (1 MB of bits)


class IsiHistogram:
    """Counts of inter-spike intervals: one bin per step below EXACT, 1/PER_OCTAVE-octave bins
    above, so its size never depends on the stream's length; count, sum, min and max are exact."""

    EXACT, PER_OCTAVE, OCTAVES = 1 << 16, 64, 48

    def __init__(self) -> None:
        self.exact = np.zeros(self.EXACT, dtype=np.int64)
        self.log = np.zeros(self.PER_OCTAVE * self.OCTAVES, dtype=np.int64)
        self.count, self.total, self.min, self.max = 0, 0, None, None

    def add(self, isi: np.ndarray) -> None:
        if isi.size == 0:
            return
        self.count += int(isi.size)
        self.total += int(isi.sum())
        lo, hi = int(isi.min()), int(isi.max())
        self.min = lo if self.min is None else min(self.min, lo)
        self.max = hi if self.max is None else max(self.max, hi)
        small = isi < self.EXACT
        self.exact += np.bincount(isi[small], minlength=self.EXACT)
        if not small.all():
            k = np.floor(np.log2(isi[~small] / self.EXACT) * self.PER_OCTAVE).astype(np.int64)
            np.add.at(self.log, np.minimum(k, self.log.size - 1), 1)

    def percentile(self, q: float) -> float:
        """As np.percentile (linear interpolation between the two nearest ranks)."""
        values = np.concatenate([np.arange(self.EXACT, dtype=np.float64),
                                 np.ceil(self.EXACT * 2.0 ** (np.arange(self.log.size) / self.PER_OCTAVE))])
        cum = np.cumsum(np.concatenate([self.exact, self.log]))
        rank = (self.count - 1) * q / 100.0
        lo = int(np.floor(rank))
        at = np.searchsorted(cum, [lo, min(lo + 1, self.count - 1)], side="right")
        a, b = values[at[0]], values[at[1]]
        return float(a + (rank - lo) * (b - a))


class StreamSummary:
    """Per-pixel counts, ISIs and per-window dark fractions of a stream fed in consecutive chunks."""

    def __init__(self, height: int, width: int, window: int) -> None:
        pixels = height * width
        self.height, self.width, self.window = height, width, window
        self.steps = 0
        self.counts = np.zeros(pixels, dtype=np.int64)
        self.last_spike = np.full(pixels, -1, dtype=np.int64)
        self.isi = IsiHistogram()
        self.window_counts = np.zeros(pixels, dtype=np.int64)
        self.window_fill, self.windows, self.dark_sum = 0, 0, 0.0

    def add(self, bits: np.ndarray) -> None:
        """The next steps, bool (n, pixels)."""
        self.counts += bits.sum(axis=0, dtype=np.int64)
        self._add_intervals(bits)
        self._add_windows(bits)
        self.steps += bits.shape[0]

    def _add_intervals(self, bits: np.ndarray) -> None:
        pixel, step = np.nonzero(bits.T)  # ordered by pixel, then step
        if pixel.size == 0:
            return
        step = step + self.steps
        first = np.empty(pixel.size, dtype=bool)
        first[0] = True
        np.not_equal(pixel[1:], pixel[:-1], out=first[1:])
        prev = np.empty_like(step)
        prev[1:] = step[:-1]
        prev[first] = self.last_spike[pixel[first]]
        self.isi.add((step - prev)[prev >= 0])
        last = np.empty(pixel.size, dtype=bool)
        last[-1] = True
        last[:-1] = first[1:]
        self.last_spike[pixel[last]] = step[last]

    def _add_windows(self, bits: np.ndarray) -> None:
        a = 0
        while a < bits.shape[0]:
            take = min(bits.shape[0] - a, self.window - self.window_fill)
            self.window_counts += bits[a:a + take].sum(axis=0, dtype=np.int64)
            self.window_fill += take
            a += take
            if self.window_fill == self.window:
                self.dark_sum += float((self.window_counts == 0).mean())
                self.windows += 1
                self.window_counts[:] = 0
                self.window_fill = 0

    def result(self, readout_period_s: float) -> dict[str, Any]:
        """The keys and values of `spikesim.stats.summary`."""
        rate = self.counts / self.steps
        out: dict[str, Any] = {
            "num_steps": self.steps, "height": self.height, "width": self.width,
            "duration_s": self.steps * readout_period_s,
            "spikes": int(self.counts.sum()),
            "mean_rate_per_step": float(rate.mean()),
            "mean_rate_hz": float(rate.mean() / readout_period_s),
            "rate_percentiles_per_step": {p: float(np.percentile(rate, p)) for p in (1, 50, 99)},
            "dark_pixel_fraction": float((self.counts == 0).mean()),
        }
        if self.windows:
            out[f"dark_pixel_fraction_{self.window}_step_window"] = self.dark_sum / self.windows
        h = self.isi
        out["isi_steps"] = {"count": 0} if h.count == 0 else {
            "count": h.count, "mean": h.total / h.count, "min": h.min, "median": h.percentile(50),
            "p99": h.percentile(99), "max": h.max}
        return out


def summarize(reader: DatReader, start: int, stop: int, readout_period_s: float, window: int,
              chunk: int | None = None) -> dict[str, Any]:
    """`spikesim.stats.summary` of steps [start, stop) of a file, read `chunk` steps at a time."""
    pixels = reader.height * reader.width
    chunk = chunk or max(1, CHUNK_PIXEL_STEPS // pixels)
    acc = StreamSummary(reader.height, reader.width, window)
    for a in range(start, stop, chunk):
        b = min(stop, a + chunk)
        acc.add(reader.read(a, b).unpack().reshape(b - a, pixels))
    return acc.result(readout_period_s)


def step_range(path: Path, num_steps: int, start: int, stop: int | None) -> tuple[int, int]:
    """[start, stop) inside the stream, --stop clipped to its end; a range with no step is an
    error naming the flag."""
    if num_steps == 0:
        raise ValueError(f"{path}: the stream holds no frames")
    if start >= num_steps:
        raise ValueError(f"--start {start} is at or past the end of {path} ({num_steps} frames)")
    stop = num_steps if stop is None else min(stop, num_steps)
    if stop <= start:
        raise ValueError(f"--stop {stop} must be greater than --start {start}")
    return start, stop


def _readout_period(args: argparse.Namespace) -> float:
    """--readout-period-s, else the period the stream's record gives (a sidecar's, or a dataset
    scene's meta.json's), else 25e-6; a flag the record contradicts is refused."""
    # the record read as calibrate reads it (round ten: inspect read a sidecar only, so a dataset
    # scene recorded at 1e-4 s was shown at 40,000 Hz and a contradicting flag was taken)
    from pipelines.calibrate_cmd import recorded_readout_period_s
    recorded = recorded_readout_period_s(args.path)
    if args.readout_period_s is not None and recorded and not math.isclose(args.readout_period_s, recorded, rel_tol=1e-9):
        # taken silently over the record (round nine); calibrate refuses the same contradiction
        side = sidecar_path(args.path)
        source = side if side.exists() else args.path.parent / "meta.json"
        raise ValueError(f"--readout-period-s {args.readout_period_s:g}: {args.path}'s record gives {recorded:g} s "
                         f"({source}); drop the flag (the record is taken) or give the period it records")
    return args.readout_period_s or recorded or 25e-6


#: The first bytes of image files that `inspect` might be given instead of a spike stream.
IMAGE_MAGIC = {b"\x76\x2f\x31\x01": "an OpenEXR image", b"\x89PNG": "a PNG image", b"\x93NUMPY": "a NumPy array"}


def refuse_images(path: Path) -> None:
    """A ValueError when `path` is an image or an array rather than a spike stream (a .dat has no
    header: its size alone would be checked, and blamed), suggesting what reads it."""
    if not path.is_file():  # open_stream reports it, naming the file: a FIFO's open waited forever (round seventeen)
        return
    try:
        with open(path, "rb") as f:
            head = f.read(6)
    except OSError:
        return  # open_stream reports it, naming the file
    for magic, what in IMAGE_MAGIC.items():
        if head.startswith(magic):
            raise ValueError(f"{path} is {what}, not a spike stream: inspect reads a .dat stream; to simulate one "
                             "from rendered frames, spikesim simulate --frames <the folder of .exr frames, or the "
                             ".npy array> -o stream.dat")


def run(args: argparse.Namespace) -> int:
    refuse_images(args.path)
    reader, header = open_stream(args.path, args.height, args.width, args.flip, args.header_columns,
                                 args.drop_partial)
    flip = reader.flip
    start, stop = step_range(args.path, len(reader), args.start, args.stop)
    side = read_sidecar(args.path) or {}
    period = _readout_period(args)
    s = summarize(reader, start, stop, period, args.window)
    s.update({"path": str(args.path), "flip": flip, "header_columns": header, "readout_period_s": period,
              "start": start})
    if side:
        s["sidecar"] = {k: side[k] for k in ("seed", "backend", "keyframe_every", "irradiance") if k in side}
    if args.preview:
        from spikesim.imageio import PREVIEW_PERCENTILE, auto_percentile, write_png
        from spikesim.outputs import check_not_link, check_results_owned, output_file, results_writing
        from spikesim.dataset import check_outside_datasets
        preview_path = check_not_link(args.preview)
        # a preview written into a dataset, which verify then reported as an extra file (round ten)
        check_outside_datasets(preview_path, [], "--preview")
        check_results_owned(preview_path.parent, [preview_path.name], "inspect", "--preview")  # a user's PNG: refused (round eight)
        a = max(start, (start + stop) // 2 - args.window // 2)
        tfp = reader.read(a, min(stop, a + args.window)).unpack().mean(axis=0)
        # a dark stream's preview is stretched to its 99.5th percentile (it was near-black in low light)
        percentile = PREVIEW_PERCENTILE if args.enhance else auto_percentile(tfp)
        with output_file(args.preview) as preview:  # never through a link; no new empty folder on failure
            # again just before the write: a file the user put there while the stream was read was
            # overwritten (round ten); recorded under the record's lock as it is written (round twelve:
            # concurrent previews into one folder lost entries)
            with results_writing(preview_path.parent, [preview_path.name], "inspect", "--preview"):
                write_png(preview, tfp, percentile=percentile)
        s["preview"] = str(args.preview)
        s["preview_stretched"] = percentile is not None
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    _print_summary(args, s, flip, period)
    return 0


def _duration(seconds: float) -> str:
    return f"{seconds:.4g} s" if seconds >= 1 else f"{seconds * 1e3:.4g} ms"


def _print_summary(args: argparse.Namespace, s: dict[str, Any], flip: bool, period: float) -> None:
    print(f"{args.path}")
    print(f"  frames       {s['num_steps']} x {s['height']} x {s['width']} (flip={flip}), "
          f"{_duration(s['duration_s'])} at {1 / period:,.0f} Hz")
    print(f"  spikes       {s['spikes']}  mean rate {s['mean_rate_per_step']:.5f}/step = {s['mean_rate_hz']:.4g} Hz")
    pr = s["rate_percentiles_per_step"]
    print(f"  rate p1/p50/p99  {pr[1]:.5f} / {pr[50]:.5f} / {pr[99]:.5f} per step")
    key = f"dark_pixel_fraction_{args.window}_step_window"
    print(f"  dark pixels  {s['dark_pixel_fraction']:.2%} over the stream"
          + (f", {s[key]:.2%} per {args.window}-step window" if key in s else ""))
    isi = s["isi_steps"]
    if isi["count"]:
        print(f"  ISI (steps)  n={isi['count']} mean {isi['mean']:.2f} min {isi['min']} median {isi['median']:.0f} "
              f"p99 {isi['p99']:.0f} max {isi['max']}")
    else:
        print("  ISI          no pixel fired twice")
    if args.preview:
        stretched = " (dark: stretched to its 99.5th percentile, for display only)" if s.get("preview_stretched") else ""
        print(f"  TFP preview  {args.preview}{stretched}")


def header_columns_arg(text: str) -> str | int:
    """--header-columns: "auto" or a number of columns >= 0."""
    return "auto" if text == "auto" else nonnegative_int(text)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="statistics of a .dat spike stream (and a TFP preview)")
    p.add_argument("path", type=Path, help="the .dat spike stream")
    p.add_argument("--height", type=positive_int, help="rows (default: as recorded beside the file, else 250)")
    p.add_argument("--width", type=positive_int,
                   help="image columns without header (default: as recorded beside the file, else 400)")
    p.add_argument("--header-columns", type=header_columns_arg, default="auto",
                   help="columns to drop at the end of each row: auto (default: as recorded; else 0, or 16 for "
                        "416-wide files, deciding by content when the size fits both) or a number")
    flip = p.add_mutually_exclusive_group()
    flip.add_argument("--flip", dest="flip", action="store_true", default=None, help="rows stored bottom-up (real cameras)")
    flip.add_argument("--no-flip", dest="flip", action="store_false",
                      help="rows stored top-down (SPCS/SCSim); default: as recorded, else rows stored bottom-up (flip)")
    p.add_argument("--drop-partial", action="store_true", help="ignore a partial last frame instead of failing")
    p.add_argument("--start", type=nonnegative_int, default=0, help="first step (default 0)")
    p.add_argument("--stop", type=positive_int, help="step after the last (default: the end; clipped to it)")
    p.add_argument("--window", type=positive_int, default=41,
                   help="window for TFP preview and per-window dark fraction")
    p.add_argument("--readout-period-s", type=readout_period_s,
                   help="seconds per readout step, for rates in Hz (default: as recorded, else 25e-6)")
    p.add_argument("--preview", type=output_file_in("preview.png"),
                   help="save a TFP preview PNG of the middle window (*.png, or a folder: preview.png in it)")
    p.add_argument("--enhance", action="store_true",
                   help="stretch the preview to its 99.5th percentile (display only; a dark one is stretched anyway)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)
