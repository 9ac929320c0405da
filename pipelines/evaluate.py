"""`spikesim evaluate`: PSNR and SSIM of reconstruction methods on a dataset, per scene and overall,
as a table like the paper's Table 1 (CSV + Markdown).

Which frames: per scene, the longest run of consecutive windows (T steps each, centres T apart)
whose centres all have ground truth, starting at the earliest such centre (an LLR scene: its 21
windows). Every method sees exactly these windows; a network sees the whole run as one sequence
(exact chunked streaming inference, model/streaming.py). Metric conventions: model/metrics.py.
"""
from __future__ import annotations

import argparse
import csv
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from model.data import Scene, open_scenes
from model.methods import Method, method_from_spec
from model.metrics import METRIC_CONVENTION, psnr, ssim
from model.streaming import StepWindows
from pipelines.argtypes import nonnegative_int, positive_int

ALL = "ALL"


def evaluation_run(scene: Scene, window: int) -> tuple[int, int]:
    """(first centre, number of windows) of the longest run of ground-truth window centres."""
    half = window // 2
    gt = set(int(s) for s in scene.gt_steps)
    best = (0, 0)
    for c in sorted(gt):
        if c - half < 0 or ((c - window) in gt and c - window - half >= 0):
            continue  # not inside the stream, or not the start of a run
        n = 0
        while (c + n * window) in gt and c + n * window + half <= scene.num_steps - 1:
            n += 1
        if n > best[1]:
            best = (c, n)
    if best[1] == 0:
        raise ValueError(f"scene {scene.name!r}: no ground-truth step is the centre of a full "
                         f"{window}-step window inside its {scene.num_steps} steps")
    return best


@dataclass
class Score:
    scene: str
    method: str
    psnr: float
    ssim: float
    frames: int


def evaluate_scene(scene: Scene, methods: Sequence[Method], window: int) -> list[Score]:
    first, n = evaluation_run(scene, window)
    source = StepWindows(scene.spikes, first - window // 2, window, n)
    gts = [np.asarray(scene.ground_truth(first + i * window), dtype=np.float32) for i in range(n)]
    out = []
    for m in methods:
        p, s = [], []
        for i, frame in m.frames(source):
            pred = frame.numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
            p.append(psnr(pred, gts[i]))
            s.append(ssim(pred, gts[i]))
        out.append(Score(scene.name, m.name, float(np.mean(p)), float(np.mean(s)), len(p)))
    return out


def evaluate(scenes: Sequence[Scene], methods: Sequence[Method], window: int, progress: bool = True) -> list[Score]:
    """Per-scene scores, then per method the overall mean over all frames of all scenes."""
    windows = {m.name: m.window for m in methods}
    if any(w != window for w in windows.values()):
        raise ValueError(f"all methods must use {window}-step windows; got {windows}")
    names = [m.name for m in methods]
    if len(set(names)) != len(names):
        raise ValueError(f"method names must be unique, got {names}; name them with label=spec")
    rows: list[Score] = []
    for sc in scenes:
        rows += evaluate_scene(sc, methods, window)
        if progress:
            print(f"[evaluate] {sc.name}: " + ", ".join(f"{r.method} {r.psnr:.2f} dB" for r in rows[-len(methods):]),
                  file=sys.stderr)
    for m in methods:
        mine = [r for r in rows if r.method == m.name]
        frames = sum(r.frames for r in mine)
        rows.append(Score(ALL, m.name, sum(r.psnr * r.frames for r in mine) / frames,
                          sum(r.ssim * r.frames for r in mine) / frames, frames))
    return rows


def markdown_table(rows: Sequence[Score], methods: Sequence[str]) -> str:
    """Table 1 layout (metrics x methods) for the overall scores, then PSNR / SSIM per scene."""
    overall = {r.method: r for r in rows if r.scene == ALL}
    lines = ["| Metric | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for metric, fmt in (("psnr", "{:.3f}"), ("ssim", "{:.5f}")):
        best = max(getattr(overall[m], metric) for m in methods)
        cells = []
        for m in methods:
            v = getattr(overall[m], metric)
            cells.append(f"**{fmt.format(v)}**" if v == best and len(methods) > 1 else fmt.format(v))
        lines.append(f"| {metric.upper()} | " + " | ".join(cells) + " |")
    lines += ["", "| Scene | frames | " + " | ".join(f"{m} PSNR / SSIM" for m in methods) + " |",
              "|---|---|" + "---|" * len(methods)]
    scenes = [r.scene for r in rows if r.scene != ALL and r.method == methods[0]]
    for sc in scenes:
        by = {r.method: r for r in rows if r.scene == sc}
        lines.append(f"| {sc} | {by[methods[0]].frames} | "
                     + " | ".join(f"{by[m].psnr:.3f} / {by[m].ssim:.5f}" for m in methods) + " |")
    lines += ["", f"Metric conventions: {METRIC_CONVENTION} Overall = mean over all frames of all scenes."]
    return "\n".join(lines) + "\n"


def write_results(rows: Sequence[Score], methods: Sequence[str], out: Path) -> tuple[Path, Path]:
    out.mkdir(parents=True, exist_ok=True)
    csv_path, md_path = out / "metrics.csv", out / "metrics.md"
    with csv_path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "method", "psnr", "ssim", "frames"])
        for r in rows:
            w.writerow([r.scene, r.method, f"{r.psnr:.6f}", f"{r.ssim:.6f}", r.frames])
    md_path.write_text(markdown_table(rows, methods))
    return csv_path, md_path


def cmd_evaluate(args: argparse.Namespace) -> int:
    from pipelines.train import resolve_device
    device = str(resolve_device(args.device))
    if args.threads:
        torch.set_num_threads(args.threads)
    methods = [method_from_spec(s, args.window, args.chunk, device) for s in args.methods]
    scenes = open_scenes(args.data)
    if args.scenes:
        wanted = set(args.scenes)
        missing = sorted(wanted - {s.name for s in scenes})
        if missing:
            raise ValueError(f"--scenes: {', '.join(missing)} not in {args.data} (it has "
                             f"{', '.join(s.name for s in scenes)})")
        scenes = [s for s in scenes if s.name in wanted]
    rows = evaluate(scenes, methods, args.window, progress=not args.quiet)
    names = [m.name for m in methods]
    csv_path, md_path = write_results(rows, names, Path(args.out))
    print(markdown_table(rows, names))
    print(f"[evaluate] wrote {csv_path} and {md_path}", file=sys.stderr)
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `evaluate` on the CLI's subparsers."""
    p = subparsers.add_parser("evaluate", help="PSNR / SSIM of methods on a dataset (Table 1)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, help="dataset root (project layout)")
    p.add_argument("--methods", nargs="+", default=["tfp", "tfi"],
                   help="tfp, tfi, or checkpoint paths; 'label=spec' names a column (default: tfp tfi)")
    p.add_argument("--scenes", nargs="+", help="only these scenes")
    p.add_argument("--out", default="results/evaluate", help="folder for metrics.csv and metrics.md")
    p.add_argument("--window", type=positive_int, default=41, help="steps per window (default 41)")
    p.add_argument("--chunk", type=positive_int, default=8, help="windows held in memory by a network (default 8)")
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N or mps")
    p.add_argument("--threads", type=nonnegative_int, default=0, help="torch CPU threads (0: torch's default)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_evaluate)
    return p
