"""Where a refining network trusts the window average: its gates, scene by scene.

A network with output "refine" makes each frame as Y = g * C + (1 - g) * N: N its own frame, C the
classic estimate (TFP and TFI of the window, blended by the gate m; with a span gate s, TFP is first
blended with the span's mean rate), g the gate between them (model.arch.refine_parts). The gates
say where the network does its own work and where it reproduces a window average; the PSNR of N
alone and of C alone says what each branch is worth on its own. That is how the budget runs'
loss on the darkest natural scene was traced to N (docs/model.md, "Direct first, then the refining
head"): there N was negative and alone scored the black floor.

    from model.data import open_scenes
    from model.gates import gate_scene
    from model.methods import method_from_spec
    score, maps = gate_scene(open_scenes("data/test_nat6")[0], method_from_spec("lrrep"))

The frames are those `evaluate` scores (model.evaluation.evaluation_run), made by the same exact
streaming inference, so Y here is the frame evaluate scores.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
import torch

from model.arch import RefineParts
from model.data import Scene
from model.evaluation import evaluation_run
from model.metrics import psnr, psnr_aligned
from model.streaming import StepWindows
from spikesim.dataset import SATURATION_Y

#: g above this: the pixel's frame is mostly the classic estimate.
MOSTLY_CLASSIC_GATE = 0.5


@dataclass(frozen=True)
class GateScore:
    """One scene's gates and branch scores, means over its frames' pixels (PSNR: over its frames).
    `span_gate` is NaN for a head without one. PSNR is plain (evaluate's "PSNR") and aligned
    (evaluate's "PSNR aligned"), of the frame Y, the network's own frame N and the classic C."""

    scene: str
    frames: int
    gt_mean_y: float
    net_mean_y: float
    classic_gate: float
    mostly_classic: float
    tfp_share: float
    span_gate: float
    psnr_frame: float
    psnr_net: float
    psnr_classic: float
    psnr_aligned_frame: float
    psnr_aligned_net: float
    psnr_aligned_classic: float

    def as_row(self) -> dict[str, Any]:
        return asdict(self)


GATE_FIELDS = tuple(f.name for f in fields(GateScore))


@dataclass(frozen=True)
class GateMaps:
    """The middle frame of a scene's run, each (H, W) float32: the ground truth, Y, N, C and g."""

    window_index: int
    ground_truth: np.ndarray
    frame: np.ndarray
    net: np.ndarray
    classic: np.ndarray
    classic_gate: np.ndarray


def refining_network(method: Any) -> torch.nn.Module:
    """The network of a method spec's method, if it has a refining head; else a ValueError that says
    why there are no gates to read (a window average, a direct network, a published one)."""
    if hasattr(method, "inner"):  # model.methods.FlipEnsembleMethod
        raise ValueError(f"{method.name}: a flip self-ensemble averages four passes, each with its own gates; "
                         f"read the gates of the network itself ({method.inner.name})")
    net = getattr(method, "model", None)
    cfg = getattr(net, "cfg", None)
    if net is None or not hasattr(net, "refine_observer"):
        raise ValueError(f"{method.name}: not one of this project's networks; only a network with a refining head "
                         "(model.output 'refine') has gates")
    if cfg.output != "refine":
        raise ValueError(f"{method.name}: its config's model.output is {cfg.output!r}: its frame is the network's "
                         "own, with no gates; gates reads a network with output 'refine'")
    return net


def gate_scene(scene: Scene, method: Any) -> tuple[GateScore, GateMaps]:
    """The gates of `method` (a ModelMethod whose network refines) on `scene`'s evaluation run."""
    net = refining_network(method)
    window = net.cfg.window
    first, n = evaluation_run(scene, window)
    source = StepWindows(scene.spikes, first - window // 2, window, n)
    seen: list[RefineParts] = []
    sums = {k: 0.0 for k in ("gt", "net", "gate", "mostly", "mix", "span")}
    scores: dict[str, list[float]] = {k: [] for k in ("frame", "net", "classic")}
    aligned: dict[str, list[float]] = {k: [] for k in ("frame", "net", "classic")}
    middle = n // 2
    maps: GateMaps | None = None
    frames = 0
    net.refine_observer = seen.append
    try:
        for i, frame in method.frames(source):
            if len(seen) != 1:  # one decode per frame, just before it is yielded (model.streaming)
                raise RuntimeError(f"{scene.name}: {len(seen)} decoded batches for frame {i}")
            y = frame.numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
            h, w = y.shape
            p = seen[-1]
            crop = {k: v[0, :h, :w].detach().float().cpu().numpy() for k, v in p._asdict().items() if v is not None}
            gt = np.clip(np.asarray(scene.ground_truth(first + i * window), dtype=np.float32), 0.0, SATURATION_Y)
            g = crop["classic_gate"]
            sums["gt"] += float(gt.mean())
            sums["net"] += float(crop["net"].mean())
            sums["gate"] += float(g.mean())
            sums["mostly"] += float((g > MOSTLY_CLASSIC_GATE).mean())
            sums["mix"] += float(crop["tfp_share"].mean())
            sums["span"] += float(crop["span_gate"].mean()) if "span_gate" in crop else math.nan
            for key, image in (("frame", y), ("net", crop["net"]), ("classic", crop["classic"])):
                scores[key].append(psnr(image, gt))
                aligned[key].append(psnr_aligned(image, gt))
            if i == middle:
                maps = GateMaps(i, gt, y.astype(np.float32), crop["net"], crop["classic"], g)
            frames += 1
            seen.clear()
    finally:
        net.refine_observer = None
    assert maps is not None
    return GateScore(
        scene.name, frames, sums["gt"] / frames, sums["net"] / frames, sums["gate"] / frames,
        sums["mostly"] / frames, sums["mix"] / frames, sums["span"] / frames,
        *(float(np.mean(scores[k])) for k in ("frame", "net", "classic")),
        *(float(np.mean(aligned[k])) for k in ("frame", "net", "classic"))), maps


def gates_markdown(rows: list[GateScore]) -> str:
    """The table `spikesim gates` prints and writes to gates.md."""
    head = ("| scene | frames | mean y | N mean y | gate g (classic) | pixels g > 0.5 | TFP share m | span gate s "
            "| PSNR Y | PSNR N | PSNR C | aligned Y | aligned N | aligned C |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for r in rows:
        span = "-" if math.isnan(r.span_gate) else f"{r.span_gate:.3f}"
        lines.append(f"| {r.scene} | {r.frames} | {r.gt_mean_y:.2e} | {r.net_mean_y:.2e} | {r.classic_gate:.3f} "
                     f"| {100 * r.mostly_classic:.1f} % | {r.tfp_share:.3f} | {span} | {r.psnr_frame:.2f} "
                     f"| {r.psnr_net:.2f} | {r.psnr_classic:.2f} | {r.psnr_aligned_frame:.2f} "
                     f"| {r.psnr_aligned_net:.2f} | {r.psnr_aligned_classic:.2f} |")
    return "\n".join(lines) + "\n"


__all__ = ["GateScore", "GateMaps", "GATE_FIELDS", "MOSTLY_CLASSIC_GATE", "gate_scene", "gates_markdown",
           "refining_network"]
