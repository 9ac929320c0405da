"""Steps and keyframes: the one place that says how many frames cover how many sensor steps.

With keyframes k steps apart, frame j is the irradiance at step j k and the sensor interpolates
linearly in between (docs/sensor.md). Every frame source (the moving pattern, a rendered scene, an
.npy array, an EXR folder, generation, the trade study) asks `keyframe_count` how many frames to
produce for N steps, and the simulator asks `steps_covered` how many steps m frames give; the two
agree, so N requested steps are N steps written.
"""
from __future__ import annotations


def _check(name: str, value: int, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name}={value!r} must be an integer >= {minimum}")
    return value


def keyframe_count(steps: int, keyframe_every: int = 1) -> int:
    """Frames needed for `steps` steps with keyframes `keyframe_every` steps apart:
    ceil((steps - 1) / k) + 1, so the last keyframe reaches or passes the last step (the stream is
    then cut to `steps`)."""
    _check("steps", steps, 1)
    k = _check("keyframe_every", keyframe_every, 1)
    return -(-(steps - 1) // k) + 1


def steps_covered(frames: int, keyframe_every: int = 1, keep_last: bool = False) -> int:
    """Steps that `frames` keyframes `keyframe_every` apart give: (m - 1) k + 1. With `keep_last`
    the last keyframe only closes the interval before it (it opens the next chunk), so its own step
    is not run yet: (m - 1) k. With k = 1 every frame is its own step and none is held back."""
    m = _check("frames", frames, 0)
    k = _check("keyframe_every", keyframe_every, 1)
    if m == 0:
        return 0
    if k == 1:
        return m
    return (m - 1) * k + (0 if keep_last else 1)


def keyframe_steps(start: int, steps: int, keyframe_every: int = 1) -> range:
    """The steps at which the frames for steps start .. start + steps - 1 are taken."""
    k = keyframe_every
    return range(start, start + keyframe_count(steps, k) * k, k)


__all__ = ["keyframe_count", "steps_covered", "keyframe_steps"]
