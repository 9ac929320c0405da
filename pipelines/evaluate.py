"""`spikesim evaluate`: PSNR and SSIM of reconstruction methods on a dataset, per scene, per light
condition (low, then normal) and overall, as tables like the paper's Table 1 (CSV + Markdown), in
three conventions (ours, the authors' 8-bit one, light-normalised: model/metrics.py).

Three inputs: a dataset in the project's layout (`--data`), one external pair (`--dat` stream +
`--gt` image at step `--center`, e.g. a Spk2ImgNet sample or a user's own recording), or every
pair of a folder in Spike-Zoo's layout (`--spikezoo`, as `spikesim export` writes it). Trivial
floors `black` and `mean` can be listed beside the methods, so every table shows what an image
with no structure scores.

Which frames (`--data`): per scene, the longest run of consecutive windows (T steps each, centres T apart)
whose centres all have ground truth, starting at the earliest such centre (an LLR scene: its 21
windows). Every method sees exactly these windows; a network sees the whole run as one sequence
(exact chunked streaming inference, model/streaming.py). Ground truth is clipped at the sensor's
saturation (y = 1 spike per step) before any metric.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Sequence

from model.data import open_scenes
# the library (model/evaluation.py); re-exported here for callers of pipelines.evaluate
from model.evaluation import (ALL, CONDITIONS, CSV_FIELDS, DEFAULT_OUT, RESULT_FILES, TABLE_ROWS, Score,  # noqa: F401
                              check_results, evaluate, evaluate_pair, evaluate_scene, evaluation_run, group_name,
                              json_safe, light_condition, markdown_table, method_label, notes_markdown, pair_table,
                              pooled, scores_json, training_scene_notes, write_results)
from model.methods import Method, inference_record, method_from_spec
from model.threads import set_cpu_threads
from pipelines.argtypes import (add_horizon_arguments, add_threads_argument, existing_file, nonnegative_int, png_rate, positive_float,
                                positive_int, window_steps)
from pipelines.inspect_cmd import header_columns_arg

def cmd_evaluate(args: argparse.Namespace) -> int:
    from model.training import resolve_device
    device = str(resolve_device(args.device))
    set_cpu_threads(args.threads)
    methods = [method_from_spec(s, args.window, args.chunk, device, args.horizon, args.horizon_stride)
               for s in args.methods]
    names = [m.name for m in methods]
    if len(set(names)) != len(names):
        raise ValueError(f"method names must be unique, got {names}; name them with label=spec")
    target = _results_folder(args)
    if target is not None:  # links and a user's files where the results go: refused before the work
        from spikesim.dataset import check_outside_datasets
        from spikesim.outputs import check_results_owned
        check_outside_datasets(target, [d for d in (args.data, args.spikezoo) if d is not None])  # round nine
        check_results(target)
        check_results_owned(target, RESULT_FILES, "evaluate")
    if args.rate is not None and args.spikezoo is None:
        raise ValueError("--rate goes with --spikezoo (a Spike-Zoo folder without spikezoo.json)")
    if args.dat is not None:
        return _evaluate_pair_cmd(args, methods, names)
    if args.spikezoo is not None:
        return _evaluate_spikezoo_cmd(args, methods, names)
    if args.gt is not None or args.center is not None:
        raise ValueError("--gt and --center go with --dat (one external stream), not with --data")
    from spikesim.dataset import select_scenes
    scenes = select_scenes(open_scenes(args.data), args.scenes, args.data)
    rows = evaluate(scenes, methods, args.window, progress=not (args.quiet or args.json))
    return _report(args, rows, names, {"data": str(args.data)}, training_scene_notes(methods, scenes), methods)


def horizon_markdown(horizons: dict[str, str]) -> str:
    """metrics.md's line on how each network ran over the streams ("" without networks)."""
    if not horizons:
        return ""
    return ("\n**Inference** (`--horizon`): " + "; ".join(f"{name}: {how}" for name, how in horizons.items())
            + ".\n")


def _report(args: argparse.Namespace, rows: Sequence[Score], names: Sequence[str], source: dict,
            notes: Sequence[str] = (), methods: Sequence[Method] = ()) -> int:
    """Print the tables (or JSON) and write metrics.csv and metrics.md, as --data does. `notes`
    (a checkpoint scored on scenes it trained on: round ten) go to stderr, the JSON's "notes" and
    metrics.md; how each network ran over the streams (its horizon) to the JSON and metrics.md."""
    for note in notes:
        print(f"[evaluate] note: {note}", file=sys.stderr)
    horizons = inference_record(list(methods))
    table = markdown_table(rows, names) + notes_markdown(notes) + horizon_markdown(horizons)
    if args.json:
        print(json.dumps(json_safe(scores_json(rows, names, {**source, "notes": list(notes), "horizon": horizons})),
                         indent=2))
    else:
        print(table)
    _write(args, rows, names, markdown=table)
    return 0


def _results_folder(args: argparse.Namespace) -> Path | None:
    """Where metrics.csv and metrics.md go: -o; without it DEFAULT_OUT, except with --json or
    --dat, which then only print."""
    if args.out is not None:
        return Path(args.out)
    return None if (args.json or args.dat is not None) else Path(DEFAULT_OUT)


def _write(args: argparse.Namespace, rows: Sequence[Score], names: Sequence[str], markdown: str | None = None) -> None:
    """metrics.csv and metrics.md, replacing only an earlier evaluation's (the folder's record says
    which files evaluate wrote): a user's metrics.md of the same name was replaced (round eight)."""
    from spikesim.outputs import results_writing
    target = _results_folder(args)
    if target is None:
        return
    # each table recorded as it is written: a full disk at the record orphaned both (round twelve)
    with results_writing(target, RESULT_FILES, "evaluate") as replaced:
        csv_path, md_path = write_results(rows, names, target, markdown=markdown)
    again = "; -o DIR to keep each" if args.out is None else ""
    print(f"[evaluate] wrote {csv_path} and {md_path}" + (f" (replacing an earlier evaluation's{again})"
                                                            if replaced else ""), file=sys.stderr)


def _evaluate_spikezoo_cmd(args: argparse.Namespace, methods: Sequence[Method], names: Sequence[str]) -> int:
    """Every pair of a Spike-Zoo folder scored as --dat/--gt scores one (centre: the key step;
    ground truth: rate x PNG / 255, spikesim.spikezoo), pooled per light condition and overall."""
    from spikesim.spikezoo import read_layout

    if args.gt is not None or args.center is not None or args.scenes:
        raise ValueError("--gt, --center and --scenes do not go with --spikezoo: each pair's ground truth, key step "
                         "and scene come from the folder")
    layout = read_layout(args.spikezoo, args.split, args.height, args.width, args.rate)
    rows: list[Score] = []
    for pair in layout.pairs:
        try:
            got, _ = evaluate_pair(pair.spike, pair.ground_truth(), pair.key_step, methods, args.window,
                                   layout.height, layout.width, 0, True, center_is="its key step")
        except ValueError as exc:
            raise ValueError(f"{pair.spike}: {exc}") from None
        rows += [replace(r, scene=pair.name) for r in got if r.scene != ALL]
        if not (args.quiet or args.json):
            print(f"[evaluate] {pair.name}: aligned PSNR " + ", ".join(f"{r.method} {r.psnr_aligned:.2f} dB"
                                                                    for r in rows[-len(methods):]), file=sys.stderr)
    condition = {p.name: light_condition(p.scene or p.name) for p in layout.pairs}
    groups = [pooled(mine, group_name(c), m) for c in CONDITIONS for m in names
              if (mine := [r for r in rows if r.method == m and condition[r.scene] == c])]
    rows += groups + [pooled([r for r in rows if r.method == m], ALL, m) for m in names]
    scenes = list(dict.fromkeys(p.scene or p.name for p in layout.pairs))
    return _report(args, rows, names, {"spikezoo": str(args.spikezoo), "split": args.split,
                                       "rates": {p.name: p.rate for p in layout.pairs}},
                   training_scene_notes(methods, scenes), methods)


def _evaluate_pair_cmd(args: argparse.Namespace, methods: Sequence[Method], names: Sequence[str]) -> int:
    from spikesim.imageio import read_image_y

    if args.gt is None or args.center is None:
        raise ValueError("--dat needs --gt IMAGE and --center STEP (the step the image shows)")
    header = None if args.header_columns == "auto" else args.header_columns
    gt = read_image_y(args.gt, args.gt_scale)
    rows, read = evaluate_pair(Path(args.dat), gt, args.center, methods, args.window, args.height, args.width,
                               header, False if args.no_flip else None)
    horizons = inference_record(list(methods))
    table = pair_table(rows, names, read) + horizon_markdown(horizons)
    if args.json:
        doc = scores_json(rows, names, {"input": {**read, "gt": str(args.gt), "gt_scale": args.gt_scale},
                                        "horizon": horizons})
        print(json.dumps(json_safe(doc), indent=2))
    else:
        print(table)
    _write(args, rows, names, markdown=table)  # only with -o: else printed only
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `evaluate` on the CLI's subparsers."""
    p = subparsers.add_parser("evaluate", help="PSNR / SSIM of methods on a dataset (Table 1)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--data", help="dataset root (project layout)")
    src.add_argument("--dat", type=existing_file, help="one external spike stream (.dat); needs --gt and --center")
    src.add_argument("--spikezoo", help="a folder in Spike-Zoo's layout ({train,test}/spike/NAME.dat, gt/NAME.png), as "
                                        "spikesim export writes it: every pair, each at its key step")
    p.add_argument("--split", choices=("train", "test"), default="test", help="with --spikezoo: the split to score")
    p.add_argument("--rate", type=png_rate,
                   help="with --spikezoo, a folder without spikezoo.json: the y of the PNG's white "
                        "(default 0.6, Spike-Zoo's)")
    p.add_argument("--gt", type=existing_file, help="with --dat: the ground-truth image (PNG/JPEG/TIFF, EXR or .npy)")
    p.add_argument("--center", type=nonnegative_int, help="with --dat: the step the ground truth shows (0-based)")
    p.add_argument("--gt-scale", type=positive_float, default=1.0,
                   help="with --dat: ground truth in y = S x image / full scale (8/16-bit) or S x value (EXR, .npy); "
                        "Spk2ImgNet's simulator uses 0.6")
    p.add_argument("--height", type=positive_int, help="with --dat or --spikezoo: rows (default: as recorded, else 250)")
    p.add_argument("--width", type=positive_int,
                   help="with --dat or --spikezoo: columns without header (default: as recorded, else 400)")
    p.add_argument("--header-columns", type=header_columns_arg, default="auto",
                   help="with --dat: columns to drop at the end of each row (auto: as recorded, else detected)")
    p.add_argument("--no-flip", action="store_true",
                   help="with --dat: rows stored top-down (SPCS/SCSim); default as recorded, else bottom-up")
    p.add_argument("--methods", nargs="+", default=["tfp", "tfi"],
                   help="tfp, tfi, stp, snm (the traditional STP and SNM), tfp:N (TFP over N steps centred on each "
                        "frame, N an odd number of windows: "
                        "the span a network sees), lrrep (the shipped network), black, mean (floors), or checkpoint "
                        "paths; 'label=spec' names a column")
    p.add_argument("--json", action="store_true", help="print the scores as JSON (every metric convention)")
    p.add_argument("--scenes", nargs="+", help="only these scenes")
    p.add_argument("-o", "--out", help=f"folder for metrics.csv and metrics.md (with --data or --spikezoo, default "
                                        f"{DEFAULT_OUT} unless --json; with --dat, written only when -o is given)")
    p.add_argument("--window", type=window_steps, default=41, help="readout steps per window")
    p.add_argument("--chunk", type=positive_int, default=8, help="windows held in memory by a network")
    add_horizon_arguments(p)
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N or mps")
    add_threads_argument(p)
    p.add_argument("--quiet", action="store_true", help="no per-scene progress lines")
    p.set_defaults(func=cmd_evaluate)
    return p


__all__ = ["cmd_evaluate", "add_parser",
           # the library's names, for callers of pipelines.evaluate
           "ALL", "CONDITIONS", "CSV_FIELDS", "DEFAULT_OUT", "RESULT_FILES", "TABLE_ROWS", "Score", "check_results",
           "evaluate", "evaluate_pair", "evaluate_scene", "evaluation_run", "group_name", "json_safe",
           "light_condition", "markdown_table", "method_label", "pair_table", "pooled", "scores_json", "write_results"]
