"""Ground truth to disk: linear y as float EXR (for metrics) and a tone-mapped PNG (for people).

File names follow docs/CONTRACTS.md: <folder>/step_{n:06d}.exr, the PNG beside it.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

from .renderer import SceneRenderer


def gt_path(folder: str | Path, step: int) -> Path:
    return Path(folder) / f"step_{int(step):06d}.exr"


def write_ground_truth(renderer: SceneRenderer, steps: Iterable[int], folder: str | Path, png: bool = True,
                       png_scale: float | None = None, png_percentile: float | None = None,
                       spp: int | None = None) -> list[Path]:
    """Render the ground truth at each step (renderer.ground_truth) and write EXR (+ PNG)."""
    from spikesim.imageio import auto_percentile, write_exr, write_png

    written = []
    for step in steps:
        y = renderer.ground_truth(step, spp=spp)
        path = write_exr(gt_path(folder, step), y)
        if png:
            write_png(path.with_suffix(".png"), y, scale=png_scale,
                      percentile=auto_percentile(y, png_scale, png_percentile))  # a dark one stretched
        written.append(path)
    return written


__all__ = ["write_ground_truth", "gt_path"]
