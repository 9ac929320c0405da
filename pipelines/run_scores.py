"""Score a comparison's trained runs where `compare` cannot: on someone else's stream with one
ground-truth frame, and on a real recording with none.

    python -m pipelines.run_scores runs/study \
        --pair 203_part1_key_id151.dat 203_part1_key_id151.png 151 0.6 \
        --real uhsr_helicopter.dat 250 250

For every `<runs>/runs/<label>/seed<k>/last.pt` (compare's layout): aligned and plain PSNR on the
pair (as `evaluate --dat`), and flat-region noise, edge sharpness and edge/noise on the real
recording (as `panel`), then the mean and sample standard deviation over seeds per label, with the
baselines (TFP, TFP over the network's span) once. Writes <runs>/external.json and prints a table.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np


def pair_scores(methods: Sequence[Any], dat: Path, gt_path: Path, center: int, scale: float) -> dict[str, dict]:
    from model.evaluation import ALL, evaluate_pair
    from spikesim.imageio import read_image_y

    gt = read_image_y(gt_path, scale)
    rows, _ = evaluate_pair(dat, gt, center, methods, 41)
    return {r.method: {"psnr_aligned": r.psnr_aligned, "psnr": r.psnr, "ssim": r.ssim} for r in rows if r.scene != ALL}


def real_scores(specs: Sequence[str], dat: Path, height: int, width: int) -> dict[str, dict]:
    """panel's no-reference scores (its frames, its reference) on the middle whole window."""
    from model.noref import no_reference_scores
    from pipelines.panel import panel_frames

    frames, reference, _ = panel_frames(dat, specs, height, width, None, None, 0, None, None, 41)
    return {name: no_reference_scores(f, reference) for name, f in frames.items()}


def main(argv: Sequence[str] | None = None) -> int:
    from model.methods import method_from_spec
    from model.threads import set_cpu_threads

    p = argparse.ArgumentParser(prog="python -m pipelines.run_scores", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", type=Path, help="a compare output folder (holding runs/<label>/seed<k>/last.pt)")
    p.add_argument("--pair", nargs=4, metavar=("DAT", "GT", "CENTER", "SCALE"), help="an external stream and its truth")
    p.add_argument("--real", nargs=3, metavar=("DAT", "HEIGHT", "WIDTH"), help="a real recording (rows bottom-up)")
    p.add_argument("--baselines", nargs="*", default=["tfp", "tfp:205", "lrrep"])
    p.add_argument("--threads", type=int, default=0)
    args = p.parse_args(argv)
    set_cpu_threads(args.threads)
    runs = sorted(args.runs.glob("runs/*/seed*/last.pt"))
    if not runs:
        p.error(f"{args.runs}: no runs/<label>/seed<k>/last.pt")
    specs = list(args.baselines) + [f"{r.parent.parent.name}#{r.parent.name.removeprefix('seed')}={r}" for r in runs]
    methods = [method_from_spec(s) for s in specs]
    doc: dict[str, Any] = {}
    if args.pair:
        dat, gt, center, scale = args.pair
        doc["pair"] = pair_scores(methods, Path(dat), Path(gt), int(center), float(scale))
    if args.real:
        dat, h, w = args.real
        doc["real"] = real_scores(specs, Path(dat), int(h), int(w))
    labels = list(dict.fromkeys(m.name.split("#")[0] for m in methods))
    summary: dict[str, dict[str, list[float]]] = {}
    for part, scores in doc.items():
        for name, vals in scores.items():
            for k, v in vals.items():
                summary.setdefault(name.split("#")[0], {}).setdefault(f"{part}.{k}", []).append(float(v))
    doc["summary"] = {lab: {k: {"mean": float(np.mean(v)), "std": float(np.std(v, ddof=1)) if len(v) > 1 else 0.0,
                                "n": len(v)} for k, v in d.items()} for lab, d in summary.items()}
    (args.runs / "external.json").write_text(json.dumps(doc, indent=1))
    keys = sorted({k for d in doc["summary"].values() for k in d})
    print("| method | " + " | ".join(keys) + " |")
    print("|---|" + "---|" * len(keys))
    for lab in labels:
        cells = []
        for k in keys:
            s = doc["summary"][lab].get(k)
            cells.append("" if s is None else (f"{s['mean']:.3f}" + (f" ± {s['std']:.3f}" if s["n"] > 1 else "")))
        print(f"| {lab} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
