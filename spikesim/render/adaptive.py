"""Adaptive temporal sampling: render a keyframe only when the image would otherwise change by
more than a tolerance, and let the sensor interpolate linearly in between.

Why: rendering is ~99 % of the cost of a rendered spike stream (docs/scenes.md section 6), and
most steps of most scenes are interpolated exactly enough. Two criteria, as event-camera
simulators choose their render times (ESIM, Rebecq et al., CoRL 2018: sample so that the image
changes by at most a bound between renders, refining where it does not):

1. Motion bound (always on): `renderer.motion_px(step)` is the largest image displacement of any
   moving object during one step; keyframes are placed so the accumulated displacement between
   two keyframes stays within `max_px_per_keyframe`. A static scene, or a static stretch, gets one
   render: its later keyframes reuse the frame, since the image cannot have changed.
2. Brightness check (optional): after the motion plan, the midpoint of every interval of >= 2 steps
   is rendered and compared with the linear interpolation of its ends; where the relative RMS
   difference exceeds `brightness_tolerance`, both halves are checked again. The rendered midpoint
   becomes a keyframe either way, so no render is wasted.

The output is (step, frame) pairs for `spikesim.simulate.Simulator.stream_keyframes`.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Iterator, Protocol

import numpy as np


class Renderable(Protocol):
    """What the planner needs from a renderer (SceneRenderer has it; tests use small fakes)."""

    def motion_px(self, step: int) -> float: ...

    def render_step(self, step: int, spp: int | None = None) -> np.ndarray: ...


@dataclass(frozen=True)
class AdaptivePolicy:
    """How far apart keyframes may be."""

    max_px_per_keyframe: float = 0.5
    """Largest accumulated image motion (pixels) between two keyframes. Half a pixel keeps the
    linear interpolation of a moving edge within half a pixel of its true position."""
    max_interval: int = 1024
    """Longest keyframe interval in steps, even for a static stretch (bounds what one
    interpolation spans if the motion estimate misses something, e.g. a changing light)."""
    brightness_tolerance: float | None = None
    """Relative RMS difference (to the mean of the rendered midpoint) allowed between a rendered
    midpoint and its interpolation; None = motion bound only. Must exceed the Monte Carlo noise
    of the check at `check_block` (the check compares two noisy renders)."""
    check_block: int = 4
    """The brightness check compares block means over `check_block` x `check_block` pixels, which
    averages Monte Carlo noise by that factor while keeping structure at that scale."""
    min_interval: int = 2
    """Intervals shorter than this are not checked (a 1-step interval has no interpolated step)."""

    def __post_init__(self) -> None:
        if not (isinstance(self.max_px_per_keyframe, (int, float)) and math.isfinite(self.max_px_per_keyframe)
                and self.max_px_per_keyframe > 0):
            raise ValueError(f"max_px_per_keyframe={self.max_px_per_keyframe!r} must be a positive finite number")
        for name in ("max_interval", "check_block", "min_interval"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name}={v!r} must be a positive integer")
        tol = self.brightness_tolerance
        if tol is not None and not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
            raise ValueError(f"brightness_tolerance={tol!r} must be None or a positive finite number")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class PlanRecord:
    """What a planner did, for logs and meta.json."""

    keyframe_steps: list[int] = field(default_factory=list)
    renders: int = 0
    reused: int = 0
    refinements: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"keyframes": len(self.keyframe_steps), "renders": self.renders, "reused": self.reused,
                "refinements": self.refinements,
                "mean_interval": ((self.keyframe_steps[-1] - self.keyframe_steps[0]) / (len(self.keyframe_steps) - 1)
                                  if len(self.keyframe_steps) > 1 else None)}


def motion_plan(renderer: Renderable, start: int, last: int,
                policy: AdaptivePolicy) -> list[tuple[int, bool]]:
    """Keyframe steps in [start, last] (both included) from the motion bound, each with whether
    the image may have changed since the previous keyframe (False: reuse the previous frame).

    The displacement between the mid-points of steps a and b is at most the motion of steps
    a .. b-1 summed (each `motion_px(s)` bounds the motion over step s), so b is the farthest step
    keeping that sum within the tolerance (and always at least a + 1).
    """
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or start < 0:
        raise ValueError(f"start={start!r} must be a non-negative integer")
    if last < start:
        raise ValueError(f"last step {last} is before the first {start}")
    plan: list[tuple[int, bool]] = [(int(start), True)]
    a, acc, moved, s = int(start), 0.0, False, int(start)
    while s < last:
        m = float(renderer.motion_px(s))
        if not math.isfinite(m) or m < 0:
            raise ValueError(f"motion_px({s}) = {m!r}: expected a finite displacement >= 0")
        if s > a and (acc + m > policy.max_px_per_keyframe or s - a >= policy.max_interval):
            plan.append((s, moved))
            a, acc, moved = s, 0.0, False
        acc += m
        moved = moved or m > 0
        s += 1
    plan.append((int(last), moved or float(renderer.motion_px(last)) > 0))
    if len(plan) >= 2 and plan[-1][0] == plan[-2][0]:
        plan.pop()
    return plan


def _rel_rms(a: np.ndarray, b: np.ndarray, block: int) -> float:
    """Relative RMS of a - b on block means (block x block), over the mean of b."""
    h, w = (a.shape[0] // block) * block, (a.shape[1] // block) * block
    if h == 0 or w == 0:  # smaller than a block: compare pixels
        h, w, block = a.shape[0], a.shape[1], 1
    def pool(x: np.ndarray) -> np.ndarray:
        return x[:h, :w].astype(np.float64).reshape(h // block, block, w // block, block).mean(axis=(1, 3))
    pa, pb = pool(a), pool(b)
    scale = max(float(pb.mean()), 1e-30)
    return float(np.sqrt(np.mean((pa - pb) ** 2)) / scale)


class AdaptiveKeyframes:
    """Plan and render keyframes for steps start .. start + num_steps - 1.

    >>> ak = AdaptiveKeyframes(AdaptivePolicy(max_px_per_keyframe=0.5))
    >>> parts = sim.stream_keyframes(ak.keyframes(renderer, 0, 861))  # doctest: +SKIP
    >>> ak.record.to_dict()                                           # renders, keyframes, ...
    """

    def __init__(self, policy: AdaptivePolicy | None = None, spp: int | None = None):
        self.policy = policy or AdaptivePolicy()
        self.spp = spp
        self.record = PlanRecord()

    def keyframes(self, renderer: Renderable, start: int, num_steps: int) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (step, y frame) in increasing step order; the first is `start`, the last the final
        step. Frames of static keyframes are the previous frame object itself (not a copy)."""
        if isinstance(num_steps, bool) or not isinstance(num_steps, (int, np.integer)) or num_steps < 1:
            raise ValueError(f"num_steps={num_steps!r} must be a positive integer")
        self.record = rec = PlanRecord()
        plan = motion_plan(renderer, start, start + int(num_steps) - 1, self.policy)

        def render(step: int) -> np.ndarray:
            rec.renders += 1
            return renderer.render_step(step, spp=self.spp)

        prev_step, prev = plan[0][0], render(plan[0][0])
        rec.keyframe_steps.append(prev_step)
        yield prev_step, prev
        for step, changed in plan[1:]:
            if not changed:
                rec.reused += 1
                rec.keyframe_steps.append(step)
                yield step, prev
                prev_step = step
                continue
            frame = render(step)
            for s, f in self._refine(renderer, render, prev_step, prev, step, frame):
                rec.keyframe_steps.append(s)
                yield s, f
            prev_step, prev = step, frame

    def _refine(self, renderer: Renderable, render: Any, a: int, fa: np.ndarray, b: int,
                fb: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
        """Keyframes in (a, b]: b itself, preceded by the midpoints the brightness check needed."""
        tol = self.policy.brightness_tolerance
        if tol is None or b - a < self.policy.min_interval:
            yield b, fb
            return
        m = (a + b) // 2
        fm = render(m)
        w = (m - a) / (b - a)
        interp = fa.astype(np.float64) * (1 - w) + fb.astype(np.float64) * w
        if _rel_rms(interp, fm, self.policy.check_block) <= tol:
            yield m, fm  # rendered anyway: a keyframe for free
            yield b, fb
            return
        self.record.refinements += 1
        yield from self._refine(renderer, render, a, fa, m, fm)
        yield from self._refine(renderer, render, m, fm, b, fb)


__all__ = ["AdaptivePolicy", "AdaptiveKeyframes", "PlanRecord", "motion_plan"]
