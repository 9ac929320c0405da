"""`spikesim camera`: write a camera file to start from, or check one.

    spikesim camera --write mine.toml                  # every field, its unit and the published default
    spikesim camera --write mine.toml --preset noiseless
    spikesim camera --write real.toml --preset measured  # plus the terms measured on a real recording
    spikesim camera mine.toml                          # check a camera file: the camera it describes

Edit the written file and pass it as `--camera mine.toml` to simulate, generate, demo or golden.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pipelines.argtypes import camera_spec, load_camera, output_file
from spikesim.camera import CAMERA_PRESETS
from spikesim import outputs


def run(args: argparse.Namespace) -> int:
    from spikesim.camera_file import GEOMETRY_FIELDS, camera_toml

    if args.write and args.file is not None:
        raise ValueError(f"give a camera to check ({args.file}) or --write FILE.toml to write one, not both: the "
                         "first would be ignored (--preset picks what --write writes)")
    if not args.write:  # ignored without --write, silently (round seventeen; golden --seeds likewise, round fourteen)
        if args.preset is not None:
            raise ValueError(f"--preset {args.preset} goes with --write (the values it writes); to print a preset's "
                             f"camera: spikesim camera {args.preset}")
        if args.overwrite:
            raise ValueError("--overwrite goes with --write (it replaces an existing file)")
    if args.write:
        preset = args.preset or "realistic"
        out: Path = args.write
        if out.suffix != ".toml":
            raise ValueError(f"--write {out}: a camera file written with comments is TOML; name it *.toml")
        outputs.check_replaceable(out)  # a FIFO or device is never replaced, --overwrite or not
        if out.exists() and not args.overwrite:
            raise FileExistsError(f"--write {out}: the file exists (--overwrite to replace it)")
        from spikesim.dataset import check_outside_datasets
        check_outside_datasets(out, [], "--write")  # a camera file written into a dataset (round eleven)
        with outputs.output_file(out):  # a link is refused; a failed write leaves nothing, naming the file
            outputs.atomic_write_text(out, camera_toml(preset=preset))
        print(f"[camera] wrote {out} ({preset}); edit it and pass --camera {out}", file=sys.stderr)
        return 0
    camera = load_camera(args.file or "realistic")
    fields = {k: v for k, v in camera.to_dict().items() if k not in GEOMETRY_FIELDS}
    print(json.dumps(fields, indent=2))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("camera", help="write a commented camera file to start from, or check one",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", nargs="?", type=camera_spec, default=None,
                   help="a camera file to check (or realistic / measured / noiseless): prints the camera it describes")
    p.add_argument("--write", type=output_file, metavar="FILE.toml",
                   help="write every field with its unit, meaning and published default")
    p.add_argument("--preset", choices=list(CAMERA_PRESETS), default=None,
                   help="with --write: the values to write (default: realistic, the published magnitudes)")
    p.add_argument("--overwrite", action="store_true", help="with --write: replace an existing file")
    p.set_defaults(func=run)
