"""`spikesim calibrate`: a camera file fitted from your own recordings.

    spikesim calibrate --dark DARK.dat --flat FLAT.dat --height H --width W -o mine.toml
    spikesim calibrate --dark DARK.dat --flat LOW.dat --flat HIGH.dat --scene SCENE.dat ... -o mine.toml
    spikesim calibrate --scene recording.dat -o mine.toml   # a scene alone: the recorded period only

- DARK: the lens capped. Gives dark_current_hz, dark_current_spread, and the hot pixels (counted).
- FLAT: uniform light, below half the saturation rate. Gives gain_spread (which holds the threshold
  mismatch and offset: they act on light alike; the file sets them to 0) and the outlier pixels
  (outlier_pixel_fraction, outlier_gain_spread; 0 where one normal explains the pixels). A second
  flat is combined.
- SCENE: a lit recording; checked (a dark one is refused), but nothing is fitted from it.
  row_gain_spread and column_gain_spread keep the --camera's values: a scene's texture that varies
  by row or column is in every part of one recording, as a fixed row or column pattern is, so
  the two cannot be told apart (a car scene of a camera with neither read as 0.24 and 0.16).

Each fitted value is written with its standard error and the recording it came from; every other
field keeps the --camera it starts from (default: the published realistic camera), and the file
says so. Use the file as `--camera mine.toml` in simulate, generate, golden and demo.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from pipelines.argtypes import (StoreOnce, camera_spec, existing_file, load_camera, output_file, positive_int,
                                readout_period_s)
from pipelines.inspect_cmd import header_columns_arg
from spikesim import outputs


def read_half_rates(path: Path, height: int | None, width: int | None, flip: bool | None,
                    header_columns: int | str = "auto") -> Any:
    """The recording read as every other command reads it (spikesim.stream.open_stream): a
    --height/--width that its record contradicts is refused, naming both (round eight: calibrate
    read a 32 x 32 recording as 16 x 64 and wrote other spreads, rc 0)."""
    from spikesim.calibrate import half_rates
    from spikesim.stream import open_stream

    reader, _ = open_stream(path, height, width, flip, header_columns)
    return half_rates(lambda a, b: reader.read(a, b).unpack(), reader.num_steps, str(path))


def recorded_readout_period_s(path: Path) -> float | None:
    """The readout period the recording's record gives (its sidecar's, or a dataset scene's
    meta.json's: the camera's, else a top-level readout_period_s), None when it gives none. The
    one reader of a stream's period: inspect takes it too (round ten: inspect read a sidecar only,
    so a dataset scene recorded at 1e-4 s was shown at 25e-6 s)."""
    from spikesim.config_io import read_json_object
    from spikesim.stream import META_LIMIT, check_stream_record, recorded_geometry

    rec = recorded_geometry(path)
    if rec is None:
        return None
    info = check_stream_record(read_json_object(rec["source"], "stream description", finite=False, limit=META_LIMIT),
                               rec["source"])  # types and range checked, naming the file
    camera = info.get("camera")
    from spikesim.camera import READOUT_PERIOD_RANGE_S
    lo, hi = READOUT_PERIOD_RANGE_S
    for period in (camera.get("readout_period_s") if isinstance(camera, dict) else None, info.get("readout_period_s")):
        if isinstance(period, (int, float)) and not isinstance(period, bool):
            if not lo <= period <= hi:  # the flag's range: inspect showed 1e-300 s as 1e300 Hz (round eleven)
                raise ValueError(f"{rec['source']}: readout_period_s {period:g} s is outside {lo:g} to {hi:g} s "
                                 "(10 MHz to 1 Hz), the range of any camera: the record is damaged; correct that field")
            return float(period)
    return None


def readout_period_of(recordings: list[Path], asked: float | None, starting: float) -> tuple[float, str]:
    """The readout period the rates are converted with, and where it came from: the recordings'
    records, which must agree with each other and with --readout-period-s (round eight: the
    default 25e-6 s was taken for a 1e-4 s recording, a dark current 4 times too high)."""
    import math
    recorded = {p: v for p in recordings if (v := recorded_readout_period_s(p)) is not None}
    periods = sorted(set(recorded.values()))
    if len(periods) > 1:
        raise ValueError("the recordings record different readout periods ("
                         + ", ".join(f"{p.name}: {v:g} s" for p, v in recorded.items())
                         + "); calibrate recordings of one camera at one readout period")
    if periods:
        period, source = periods[0], next(iter(recorded))
        if asked is not None and not math.isclose(asked, period, rel_tol=1e-9):
            raise ValueError(f"--readout-period-s {asked:g}: {source.name}'s record gives {period:g} s; drop the "
                             "flag (the record is taken) or give the period it records")
        return period, f"readout_period_s {period:g} s from {source.name}'s record"
    if asked is not None:
        return asked, f"readout_period_s {asked:g} s from --readout-period-s"
    return starting, (f"readout_period_s {starting:g} s: the starting camera's (no recording records one; "
                      "--readout-period-s sets it)")


def calibrated_toml(camera: Any, fitted: list[Any], notes: list[str]) -> str:
    """The camera file (spikesim.camera_file.camera_toml) with each fitted field's line annotated:
    value +- one standard error, and the recording."""
    from spikesim.camera_file import camera_toml

    by = {f.field: f for f in fitted}
    lines = []
    for line in camera_toml(camera).splitlines():
        name = line.split(" = ", 1)[0]
        if name in by and not line.startswith("#"):
            f = by[name]
            lines.append(f"{name} = {f.value!r}  # fitted: {f.value:.4g} +- {f.uncertainty:.2g} (one standard "
                         f"error), from {f.source}")
        else:
            lines.append(line)
    head = ["# Calibrated by `spikesim calibrate` from the recordings named below (docs/sensor.md, \"Calibrating",
            "# a camera\"). Fields marked `fitted` were measured; every other field keeps the starting camera's",
            "# value (the published default unless --camera said otherwise).", *(f"# {n}" for n in notes), ""]
    return "\n".join(head + lines) + "\n"


def run(args: argparse.Namespace) -> int:
    from spikesim.calibrate import calibrated_camera, check_scene_lit, combine, fit_dark, fit_flat, fit_outliers

    if args.dark is None and not args.flat and args.scene is None:
        raise ValueError("calibrate needs at least one recording: --dark (lens capped), --flat (uniform light) "
                         "or --scene")
    if args.out.suffix != ".toml":
        raise ValueError(f"-o {args.out}: a camera file is TOML; name it *.toml")
    if args.out.exists() and not args.overwrite:
        raise FileExistsError(f"-o {args.out}: the file exists (--overwrite to replace it)")
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(args.out)  # a camera file written into a dataset (round eleven)
    if len(args.flat) > 2:
        raise ValueError(f"--flat: given {len(args.flat)} times; calibrate combines one or two flats (two light levels)")
    given = [p for p in (args.dark, *args.flat) if p is not None]  # a flat may also serve as the --scene
    from spikesim.dataset import sha256_file

    def same_recording(p: Path, q: Path) -> bool:  # by path, link or content (a copy passed in round seven)
        if p.resolve() == q.resolve():
            return True
        return p.stat().st_size == q.stat().st_size and sha256_file(p) == sha256_file(q)
    same = [p for i, p in enumerate(given) if any(same_recording(p, q) for q in given[:i])]
    if same:  # one recording counted as two independent ones: its errors came out too small (round six)
        raise ValueError(f"{same[0]}: given twice (the same recording, by path or content); --dark and each --flat "
                         "must be different recordings")
    if args.scene is not None and args.dark is not None and same_recording(args.scene, args.dark):
        raise ValueError(f"{args.scene}: given as --dark and as --scene (the same recording, by path or content); a "
                         "scene recording is lit")
    base = load_camera(args.camera)
    recordings = [p for p in (args.dark, *args.flat, args.scene) if p is not None]
    period, period_note = readout_period_of(recordings, args.readout_period_s, base.readout_period_s)
    base = base.replace(readout_period_s=period)
    flip = False if args.no_flip else None
    fitted, notes = [], [period_note]
    dark = None
    if args.dark is not None:
        dark = read_half_rates(args.dark, args.height, args.width, flip, args.header_columns)
        dark_fit = fit_dark(dark, base.readout_period_s)
        fitted += dark_fit.fitted
        notes.append(f"{args.dark.name}: {int(dark_fit.hot.sum())} hot pixel(s) of {dark_fit.hot.size} (log dark "
                     "rate 5 robust deviations above the median), left out of the dark-current fit")
    else:
        notes.append("not fitted: dark_current_hz and dark_current_spread need a dark recording (--dark)")
    if args.flat:
        flats = []
        for path in args.flat:
            fits, y = fit_flat(read_half_rates(path, args.height, args.width, flip, args.header_columns), dark, base)
            flats += fits
            notes.append(f"{path.name}: light y = {y:.4g} spikes per step (dark subtracted)")
        gain = combine(flats)
        first = read_half_rates(args.flat[0], args.height, args.width, flip, args.header_columns)
        outliers = fit_outliers(first, dark, base)
        if outliers[0].value > 0:  # the pixels' own spread is the mixture's narrow part
            gain = outliers[2]
            notes.append(f"{args.flat[0].name}: an outlier population found (a share of pixels with an extra gain "
                         "factor); gain_spread is the spread without them")
        fitted += [gain, *outliers[:2]]
        notes.append("gain_spread holds the threshold mismatch and offset (a flat cannot tell them apart): "
                     "threshold_mismatch and threshold_offset are set to 0")
    else:
        notes.append("not fitted: gain_spread needs a flat recording (--flat)")
    # round ten: row and column spreads fitted from a scene were its texture (0.24 and 0.16 from a car
    # scene of a camera with none; a still textured frame was refused as above the maximum 0.3). One
    # recording cannot tell a fixed row/column pattern from texture that varies by row or column, so
    # none is fitted from a scene: the starting camera's values are kept, and the file says so
    kept = f"they keep the starting camera's values ({base.row_gain_spread:g} and {base.column_gain_spread:g})"
    if args.scene is not None:
        check_scene_lit(read_half_rates(args.scene, args.height, args.width, flip, args.header_columns), dark,
                        dark_rate=base.dark_current_hz * base.readout_period_s)
        notes.append(f"not fitted: row_gain_spread and column_gain_spread from {args.scene.name}: a scene's texture "
                     "that varies by row or column cannot be told apart from a fixed row or column gain pattern in "
                     f"one recording; {kept}")
    else:
        notes.append(f"not fitted: row_gain_spread and column_gain_spread (calibrate fits them from no recording: "
                     f"in a scene they cannot be told apart from its texture); {kept}")
    notes.append("not fitted from any recording: comparator and shot noise, reset loss (python -m "
                 "pipelines.real_camera compares a recording with its simulated twin)"
                 + ("" if args.flat else "; outlier pixels need a flat (--flat)"))
    camera = calibrated_camera(base, fitted)
    text = calibrated_toml(camera, fitted, notes)
    with outputs.output_file(args.out):
        outputs.atomic_write_text(args.out, text)
    if args.json:
        print(json.dumps({"out": str(args.out), "fitted": [f.to_dict() for f in fitted], "notes": notes}, indent=2))
    else:
        for f in fitted:
            print(f"{f.field} = {f.value:.4g} +- {f.uncertainty:.2g}  ({f.source})")
        for n in notes:
            print(n)
    print(f"[calibrate] wrote {args.out}; use it as --camera {args.out}", file=sys.stderr)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="fit a camera file from your own dark and flat recordings",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dark", type=existing_file, action=StoreOnce, help="a recording with the lens capped (.dat)")
    p.add_argument("--flat", type=existing_file, action="append", default=[],
                   help="a recording of uniform light (.dat); give it twice for two light levels")
    p.add_argument("--scene", type=existing_file, action=StoreOnce,
                   help="a lit scene recording (.dat): checked, nothing fitted from it (row and column spreads keep "
                        "--camera's values: one recording cannot tell them from the scene's texture)")
    p.add_argument("--height", type=positive_int, help="rows (default: the stream's sidecar, else 250)")
    p.add_argument("--width", type=positive_int, help="columns (default: the stream's sidecar, else 400)")
    p.add_argument("--header-columns", type=header_columns_arg, default="auto",
                   help="columns to drop at the end of each row (auto: as recorded, else detected)")
    p.add_argument("--no-flip", action="store_true",
                   help="rows stored top-down (SPCS/SCSim); default: as recorded, else rows stored bottom-up (flip)")
    p.add_argument("--readout-period-s", type=readout_period_s,
                   help="the recordings' readout period in seconds (default: what their records give, else the "
                        "starting camera's, 25e-6; refused where a record gives another)")
    p.add_argument("--camera", type=camera_spec, default="realistic",
                   help="the camera whose other fields the file keeps (a preset or a camera file; default realistic)")
    p.add_argument("-o", "--out", type=output_file, required=True, help="the camera file to write (*.toml)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing -o")
    p.add_argument("--json", action="store_true", help="print the fitted values as JSON")
    p.set_defaults(func=run)
