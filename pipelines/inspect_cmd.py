"""`spikesim inspect`: shape, duration, firing rate, dark pixels and ISIs of a `.dat` stream."""
from __future__ import annotations

import argparse
import json
from pathlib import Path


from spikesim.stream import DatReader, read_sidecar


def run(args: argparse.Namespace) -> int:
    from spikesim.stats import summary

    side = read_sidecar(args.path) or {}
    cam = side.get("camera", {})
    height = args.height or side.get("height") or 250
    width = args.width or side.get("width") or 400
    flip = side.get("flip", True) if args.flip is None else args.flip
    period = args.readout_period_s or cam.get("readout_period_s") or 25e-6
    reader = DatReader(args.path, height, width, flip=flip, header_columns=args.header_columns,
                       drop_partial=args.drop_partial)
    stop = len(reader) if args.stop is None else min(args.stop, len(reader))
    stream = reader.read(args.start, stop)
    s = summary(stream, period, window=args.window)
    s.update({"path": str(args.path), "flip": flip, "readout_period_s": period, "start": args.start})
    if side:
        s["sidecar"] = {k: side[k] for k in ("seed", "backend", "keyframe_every", "irradiance") if k in side}
    if args.preview:
        from spikesim.imageio import write_png
        a = max(args.start, (args.start + stop) // 2 - args.window // 2)
        tfp = stream.unpack(a - args.start, a - args.start + args.window).mean(axis=0)
        write_png(args.preview, tfp, percentile=99.5 if args.enhance else None)
        s["preview"] = str(args.preview)
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    print(f"{args.path}")
    print(f"  frames       {s['num_steps']} x {s['height']} x {s['width']} (flip={flip}), "
          f"{s['duration_s'] * 1e3:.3f} ms at {1 / period:.0f} Hz")
    print(f"  spikes       {s['spikes']}  mean rate {s['mean_rate_per_step']:.5f}/step = {s['mean_rate_hz']:.1f} Hz")
    pr = s["rate_percentiles_per_step"]
    print(f"  rate p1/p50/p99  {pr[1]:.5f} / {pr[50]:.5f} / {pr[99]:.5f} per step")
    print(f"  dark pixels  {s['dark_pixel_fraction']:.2%} over the stream"
          + (f", {s[f'dark_pixel_fraction_{args.window}_step_window']:.2%} per {args.window}-step window"
             if f"dark_pixel_fraction_{args.window}_step_window" in s else ""))
    isi = s["isi_steps"]
    if isi["count"]:
        print(f"  ISI (steps)  n={isi['count']} mean {isi['mean']:.2f} min {isi['min']} median {isi['median']:.0f} "
              f"p99 {isi['p99']:.0f} max {isi['max']}")
    else:
        print("  ISI          no pixel fired twice")
    if args.preview:
        print(f"  TFP preview  {args.preview}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="statistics of a .dat spike stream (and a TFP preview)")
    p.add_argument("path", type=Path)
    p.add_argument("--height", type=int, help="rows (default: sidecar, else 250)")
    p.add_argument("--width", type=int, help="image columns without header (default: sidecar, else 400)")
    p.add_argument("--header-columns", type=int, default=0, help="header columns per row to drop (16 for 416-wide recordings)")
    flip = p.add_mutually_exclusive_group()
    flip.add_argument("--flip", dest="flip", action="store_true", default=None, help="rows stored bottom-up (real cameras)")
    flip.add_argument("--no-flip", dest="flip", action="store_false", help="rows stored top-down (SPCS/SCSim)")
    p.add_argument("--drop-partial", action="store_true", help="ignore a partial last frame instead of failing")
    p.add_argument("--start", type=int, default=0)
    p.add_argument("--stop", type=int)
    p.add_argument("--window", type=int, default=41, help="window for TFP preview and per-window dark fraction")
    p.add_argument("--readout-period-s", type=float)
    p.add_argument("--preview", type=Path, help="save a TFP preview PNG of the middle window")
    p.add_argument("--enhance", action="store_true", help="stretch a dark preview (display only)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)
