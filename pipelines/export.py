"""`spikesim export`: write a dataset this project generated in another toolbox's layout.

    spikesim export data/llr_paper --format spikezoo -o out/llr_spikezoo      # the test split
    spikesim export data/rllr_paper --format spikezoo --split train --steps 41 --gt-stride 41 -o out/llr_spikezoo
    spikesim evaluate --spikezoo out/llr_spikezoo --methods tfp tfi               # scored back here

Spike-Zoo's layout (spikesim/spikezoo.py names the file of its code each convention comes from):
OUT/{train,test}/spike/NAME.dat and OUT/{train,test}/gt/NAME.png, one pair per ground-truth step
whose window of --steps steps (301, Spike-Zoo's REDS test length) fits in its stream, the ground
truth at the window's middle step (index steps // 2); NAME is <scene>_step<gt step>. Streams
keep the dataset's height and width (give them to Spike-Zoo's config) and are read as Spike-Zoo's
load_vidar_dat reads them. PNG = round(255 clip(y / rate, 0, 1)) with a rate per scene (its
brightest ground truth, so low light keeps its grey levels) unless --rate gives one for all;
OUT/spikezoo.json records every pair's rate and source, OUT/README.md the rates, each scene's
light and the licence. OUT must be new, empty, or an earlier export (a split is added or replaced).
"""
from __future__ import annotations

import argparse
import sys

from pipelines.argtypes import output_dir, png_rate, positive_int

FORMATS = ("spikezoo",)


def rate_arg(text: str) -> float | None:
    """--rate: "auto" (a rate per scene) or a y in argtypes.PNG_RATE_RANGE."""
    if text == "auto":
        return None
    try:
        return png_rate(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"must be auto or {str(exc).removeprefix('must be ')}") from None


def run(args: argparse.Namespace) -> int:
    from spikesim.spikezoo import export_spikezoo

    record = export_spikezoo(args.dataset, args.out, split=args.split, steps=args.steps, rate=args.rate,
                             scenes=args.scenes, gt_stride=args.gt_stride)
    entry = record["splits"][args.split]
    rates = sorted({s["rate"] for s in entry["scenes"].values()})
    print(f"[export] wrote {len(entry['pairs'])} pair(s) of {args.steps} steps, {record['height']} x {record['width']}, "
          f"into {args.out}/{args.split} (rate {', '.join(f'{r:g}' for r in rates)}; {args.out}/README.md)",
          file=sys.stderr)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write a dataset in another toolbox's layout (Spike-Zoo)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", help="a dataset this project generated (its root folder)")
    p.add_argument("--format", required=True, choices=FORMATS, help="the layout to write: spikezoo")
    p.add_argument("-o", "--out", required=True, type=output_dir,
                   help="the folder to write (new, empty, or an earlier export)")
    p.add_argument("--split", choices=("train", "test"), default="test", help="the Spike-Zoo split to write")
    p.add_argument("--steps", type=positive_int, default=301,
                   help="steps per stream, the ground truth at index steps // 2 (Spike-Zoo's REDS test streams: 301)")
    p.add_argument("--gt-stride", type=positive_int, default=1,
                   help="keep ground-truth steps at least this many steps apart (an RLLR scene has ground truth at "
                        "every step; --gt-stride 41 gives one pair per 41-step window)")
    p.add_argument("--rate", type=rate_arg, default=None,
                   help="y that the PNG's white stands for: a number (Spike-Zoo's REDS: 0.6), or auto (default): a "
                        "rate per scene, its brightest ground truth capped at saturation")
    p.add_argument("--scenes", nargs="+", help="only these scenes (all by default; one frame size per export)")
    p.set_defaults(func=run)
