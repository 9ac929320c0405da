"""Built-in irradiance sources that need no renderer: for the demo, tests and benchmarks.

`moving_pattern` is a textured background with a disc crossing it and a spinning bar: sharp
moving edges, a range of brightness, every frame computed on demand (nothing held in memory).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np


@dataclass(frozen=True)
class MovingPattern:
    """A procedural high-speed scene in y units (expected spikes per step).

    `peak_y` is the brightest value (white); low light is the same pattern with a small peak_y.
    """

    height: int = 250
    width: int = 400
    peak_y: float = 0.25
    disc_speed_px_per_step: float = 0.05
    """0.05 px/step = 2000 px/s at 40 kHz: a fast object for a spike camera."""
    bar_rpm: float = 3000.0
    readout_period_s: float = 25e-6
    seed: int = 0

    def __post_init__(self) -> None:
        if self.height <= 0 or self.width <= 0:
            raise ValueError(f"pattern size must be positive, got {self.height}x{self.width}")
        if not np.isfinite(self.peak_y) or self.peak_y < 0:
            raise ValueError(f"peak_y must be finite and >= 0, got {self.peak_y}")

    def _background(self) -> np.ndarray:
        rng = np.random.default_rng(self.seed)
        h, w = self.height, self.width
        # Smooth texture: a few random low-frequency cosines plus a checkerboard, in [0.1, 0.6].
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        tex = np.zeros((h, w))
        for _ in range(6):
            fx, fy = rng.uniform(0.5, 6.0, 2) / max(h, w)
            ph = rng.uniform(0, 2 * np.pi)
            tex += np.cos(2 * np.pi * (fx * xx + fy * yy) + ph)
        tex = (tex - tex.min()) / max(np.ptp(tex), 1e-12)
        checker = ((xx // max(1, w // 16) + yy // max(1, h // 10)) % 2)
        return 0.1 + 0.35 * tex + 0.15 * checker

    def frame(self, step: int, background: np.ndarray | None = None) -> np.ndarray:
        h, w = self.height, self.width
        img = (self._background() if background is None else background).copy()
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
        # Disc moving left to right, wrapping around.
        r = 0.18 * min(h, w)
        cx = (0.2 * w + self.disc_speed_px_per_step * step) % (w + 2 * r) - r
        cy = 0.5 * h
        d = np.hypot(xx - cx, yy - cy)
        img = np.where(d < r, 0.95, img)
        # Bar spinning about the centre at bar_rpm.
        angle = 2 * np.pi * self.bar_rpm / 60.0 * step * self.readout_period_s
        c, s = np.cos(angle), np.sin(angle)
        u = (xx - 0.75 * w) * c + (yy - 0.5 * h) * s
        v = -(xx - 0.75 * w) * s + (yy - 0.5 * h) * c
        img = np.where((np.abs(u) < 0.2 * min(h, w)) & (np.abs(v) < 0.02 * min(h, w) + 1), 0.05, img)
        return (img * self.peak_y).astype(np.float32)

    def frames(self, num_steps: int, start: int = 0, every: int = 1) -> Iterator[np.ndarray]:
        """Frames at steps start, start+every, ... (`every` > 1 gives keyframes)."""
        bg = self._background()
        for i in range(num_steps):
            yield self.frame(start + i * every, bg)


def constant_frames(value: float | np.ndarray, num_steps: int, height: int, width: int) -> Iterator[np.ndarray]:
    """The same irradiance at every step (analytic tests, dark frames, benchmarks)."""
    frame = np.broadcast_to(np.asarray(value, dtype=np.float32), (height, width))
    for _ in range(num_steps):
        yield frame


__all__ = ["MovingPattern", "constant_frames"]
