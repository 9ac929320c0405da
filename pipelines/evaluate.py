"""`spikesim evaluate`: PSNR and SSIM of reconstruction methods on a dataset, per scene, per light
condition (low, then normal) and overall, as tables like the paper's Table 1 (CSV + Markdown), in
three conventions (ours, the authors' 8-bit one, light-normalised: model/metrics.py).

Which frames: per scene, the longest run of consecutive windows (T steps each, centres T apart)
whose centres all have ground truth, starting at the earliest such centre (an LLR scene: its 21
windows). Every method sees exactly these windows; a network sees the whole run as one sequence
(exact chunked streaming inference, model/streaming.py). Ground truth is clipped at the sensor's
saturation (y = 1 spike per step) before any metric.
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from model.data import Scene, open_scenes
from model.methods import Method, method_from_spec
from model.metrics import AUTHORS_CONVENTION, METRIC_CONVENTION, METRICS, NORMALISED_CONVENTION
from model.streaming import StepWindows
from pipelines.argtypes import nonnegative_int, positive_int
from spikesim.dataset import SATURATION_Y

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
    """Mean scores of one method over `frames` frames of one scene, or of a group of scenes
    (scene ALL, or ALL_<condition>); the metrics are model.metrics.METRICS."""

    scene: str
    method: str
    psnr: float
    ssim: float
    frames: int
    psnr_8bit: float = math.nan
    ssim_8bit: float = math.nan
    psnr_norm: float = math.nan
    ssim_norm: float = math.nan

    def value(self, metric: str) -> float:
        return float(getattr(self, metric))


CONDITIONS = ("low", "normal")
"""Light conditions told apart in the tables, from the scene name's last part (LLR: ball_low)."""


def light_condition(scene_name: str) -> str | None:
    """'low' or 'normal' for an LLR-style name (<scene>_<light>), else None."""
    last = scene_name.rsplit("_", 1)[-1] if "_" in scene_name else ""
    return last if last in CONDITIONS else None


def group_name(condition: str | None) -> str:
    """The scene column of a group's rows: ALL (every scene) or ALL_<condition>."""
    return ALL if condition is None else f"{ALL}_{condition}"


def evaluate_scene(scene: Scene, methods: Sequence[Method], window: int) -> list[Score]:
    """Every metric of every method on the scene's evaluation run; ground truth clipped at the
    sensor's saturation (y = 1 spike per step: above it no stream differs, model/data.py)."""
    first, n = evaluation_run(scene, window)
    source = StepWindows(scene.spikes, first - window // 2, window, n)
    gts = [np.clip(np.asarray(scene.ground_truth(first + i * window), dtype=np.float32), 0.0, SATURATION_Y)
           for i in range(n)]
    out = []
    for m in methods:
        values: dict[str, list[float]] = {k: [] for k in METRICS}
        for i, frame in m.frames(source):
            pred = frame.numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
            for k, (fn, _, _) in METRICS.items():
                values[k].append(fn(pred, gts[i]))
        out.append(Score(scene.name, m.name, frames=len(values["psnr"]),
                         **{k: float(np.mean(v)) for k, v in values.items()}))
    return out


def pooled(rows: Sequence[Score], scene: str, method: str) -> Score:
    """The frame-weighted mean of `rows` (one method), labelled `scene`."""
    frames = sum(r.frames for r in rows)
    return Score(scene, method, frames=frames,
                 **{k: sum(r.value(k) * r.frames for r in rows) / frames for k in METRICS})


def evaluate(scenes: Sequence[Scene], methods: Sequence[Method], window: int, progress: bool = True) -> list[Score]:
    """Per-scene scores, then per method the mean over all frames of the low-light scenes
    (ALL_low) and of the normal-light ones (ALL_normal) where there are such, then overall (ALL)."""
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
    per_scene = list(rows)
    for cond in CONDITIONS:
        for m in names:
            mine = [r for r in per_scene if r.method == m and light_condition(r.scene) == cond]
            if mine:
                rows.append(pooled(mine, group_name(cond), m))
    for m in names:
        rows.append(pooled([r for r in per_scene if r.method == m], ALL, m))
    return rows


def _cell(value: float, fmt: str, best: bool) -> str:
    text = fmt.format(value)
    return f"**{text}**" if best else text


def _group_table(rows: Sequence[Score], methods: Sequence[str], group: str) -> list[str]:
    """Table 1 layout (metrics x methods) for one group of scenes; the best of each row in bold."""
    by = {r.method: r for r in rows if r.scene == group}
    lines = ["| Metric | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for key, (_, label, fmt) in METRICS.items():
        best = max(by[m].value(key) for m in methods)
        lines.append(f"| {label} | " + " | ".join(_cell(by[m].value(key), fmt, len(methods) > 1 and by[m].value(key) == best)
                                                 for m in methods) + " |")
    return lines


def markdown_table(rows: Sequence[Score], methods: Sequence[str]) -> str:
    """The low-light scenes, the normal-light ones (where the names say which), then all scenes, in
    Table 1 layout; then every metric per scene. The 8-bit rows are the convention of the paper's
    Table 1; docs/model.md says how to read the three."""
    lines: list[str] = []
    for cond in CONDITIONS + (None,):
        group = group_name(cond)
        present = [r for r in rows if r.scene == group]
        if not present:
            continue
        title = "All scenes" if cond is None else f"{cond.capitalize()} light"
        lines += [f"**{title}** ({present[0].frames} frames)", ""] + _group_table(rows, methods, group) + [""]
    lines += ["| Scene | frames | " + " | ".join(f"{m} PSNR / SSIM | {m} 8-bit | {m} light-norm." for m in methods) + " |",
              "|---|---|" + "---|" * (3 * len(methods))]
    scenes = [r.scene for r in rows if not r.scene.startswith(ALL) and r.method == methods[0]]
    for sc in scenes:
        by = {r.method: r for r in rows if r.scene == sc}
        cells = []
        for m in methods:
            r = by[m]
            cells += [f"{r.psnr:.3f} / {r.ssim:.5f}", f"{r.psnr_8bit:.3f} / {r.ssim_8bit:.5f}",
                      f"{r.psnr_norm:.3f} / {r.ssim_norm:.5f}"]
        lines.append(f"| {sc} | {by[methods[0]].frames} | " + " | ".join(cells) + " |")
    lines += ["", f"Metric conventions. PSNR, SSIM: {METRIC_CONVENTION} {AUTHORS_CONVENTION} "
                  f"{NORMALISED_CONVENTION} Ground truth clipped at saturation (y = {SATURATION_Y:g}). "
                  "Groups = mean over all frames of their scenes."]
    return "\n".join(lines) + "\n"


CSV_FIELDS = ("scene", "method", *METRICS, "frames")


def write_results(rows: Sequence[Score], methods: Sequence[str], out: Path) -> tuple[Path, Path]:
    """metrics.csv (every row, every metric) and metrics.md, each written whole (temporary file,
    then rename)."""
    out.mkdir(parents=True, exist_ok=True)
    csv_path, md_path = out / "metrics.csv", out / "metrics.md"
    tmp = out / ".metrics.csv.part"
    with tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_FIELDS)
        for r in rows:
            w.writerow([r.scene, r.method, *(f"{r.value(k):.6f}" for k in METRICS), r.frames])
    os.replace(tmp, csv_path)
    tmp = out / ".metrics.md.part"
    tmp.write_text(markdown_table(rows, methods))
    os.replace(tmp, md_path)
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
