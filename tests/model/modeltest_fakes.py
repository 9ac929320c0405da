"""Test doubles for the model's tests: a scene with SceneRecord's methods, and a tiny exact
integrate-and-fire stream of a moving, dimly lit texture (the lead's simulator is not needed)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class FakeScene:
    """In-memory stand-in for spikesim.dataset.SceneRecord (same attributes and methods)."""

    name: str
    spike_array: np.ndarray  # bool (N, H, W)
    gt: dict[int, np.ndarray]
    meta: dict = field(default_factory=dict)

    @property
    def num_steps(self) -> int:
        return int(self.spike_array.shape[0])

    @property
    def height(self) -> int:
        return int(self.spike_array.shape[1])

    @property
    def width(self) -> int:
        return int(self.spike_array.shape[2])

    @property
    def gt_steps(self) -> list[int]:
        return sorted(self.gt)

    def spikes(self, start: int, stop: int) -> np.ndarray:
        if not 0 <= start <= stop <= self.num_steps:
            raise IndexError(f"steps [{start}, {stop}) outside [0, {self.num_steps})")
        return self.spike_array[start:stop]

    def ground_truth(self, step: int) -> np.ndarray:
        return self.gt[step]


def moving_texture(height: int, width: int, num_steps: int, brightness: float, velocity: float,
                   seed: int) -> np.ndarray:
    """y (N, H, W): a smooth random texture sliding sideways at `velocity` px/step, scaled so its
    mean is about `brightness` expected spikes per step (low light: well below 1)."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    t = np.arange(num_steps, dtype=np.float64)[:, None, None]
    img = np.zeros((num_steps, height, width))
    for _ in range(4):
        kx, ky = rng.uniform(0.05, 0.35, size=2)
        ph = rng.uniform(0, 2 * np.pi)
        img += np.sin(kx * (xs[None] - velocity * t) + ky * ys[None] + ph)
    img = 0.5 + img / 8.0  # in [0, 1]
    return (brightness * 2 * np.clip(img, 0.02, 1.0)).astype(np.float32).clip(0, 1)


def integrate_and_fire(y: np.ndarray, seed: int) -> np.ndarray:
    """Exact noiseless sensor: A += y each step, a spike when A crosses an integer (reset by
    subtraction), random initial A in [0, 1). Returns bool (N, H, W)."""
    a0 = np.random.default_rng(seed).uniform(0, 1, size=y.shape[1:])
    acc = a0[None] + np.cumsum(y.astype(np.float64), axis=0)
    prev = np.concatenate([a0[None], acc[:-1]], axis=0)
    return np.floor(acc) > np.floor(prev)


def make_scene(name: str = "scene", height: int = 32, width: int = 32, num_steps: int = 41 * 6,
               brightness: float = 0.15, velocity: float = 0.05, seed: int = 0,
               gt_every: int = 1) -> FakeScene:
    """A FakeScene with ground truth every `gt_every` steps."""
    y = moving_texture(height, width, num_steps, brightness, velocity, seed)
    spikes = integrate_and_fire(y, seed + 1)
    gt = {n: y[n] for n in range(0, num_steps, gt_every)}
    return FakeScene(name, spikes, gt, {"brightness": brightness})
