"""Per-pixel parameters drawn once per camera instance: the fixed-pattern noise.

They are drawn here, in NumPy, from the simulator's seed, and shared by every backend; the temporal
noise is counter-based Philox drawn alike by each (spikesim/philox.py). So every configuration gives
bit-identical streams on NumPy, LLVM and CUDA.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import SpikeCamera

# Per-pixel thresholds are kept inside [0.5, 1.5] x nominal: beyond 10 sigma of the published
# spreads (docs/design.md section 2), so it only guards against a non-positive threshold.
_THRESHOLD_RANGE = (0.5, 1.5)

# Independent streams of the seed's SeedSequence: fixed patterns, then initial state;
# temporal noise uses its own keys inside each backend.
_STREAM_FIXED_PATTERN = 0
_STREAM_INITIAL_STATE = 1


@dataclass(frozen=True)
class PixelParameters:
    """Flat (H*W,) arrays in the accumulator's dtype; None where the term is off (so the
    kernels leave it out)."""

    gain: np.ndarray | None
    dark_per_step: np.ndarray | None
    threshold: np.ndarray | None
    initial_accumulator: np.ndarray

    @property
    def dtype(self) -> np.dtype:
        return self.initial_accumulator.dtype


def draw_pixel_parameters(camera: SpikeCamera, seed: int) -> PixelParameters:
    dtype = np.dtype(camera.precision)
    n = camera.num_pixels
    ss = np.random.SeedSequence([int(seed), _STREAM_FIXED_PATTERN])
    rng = np.random.Generator(np.random.Philox(ss))

    gain = None
    if camera.gain_spread > 0:
        # PRNU: gain ~ N(1, sigma); clipped at 0 (at 5.8 % spread this never triggers).
        gain = np.clip(rng.normal(1.0, camera.gain_spread, n), 0.0, None).astype(dtype)

    dark = None
    if camera.dark_current_hz > 0:
        mean = camera.dark_per_step
        if camera.dark_current_spread > 0 and camera.dark_current_law == "normal":
            # SCSim's law: normal with the given mean and coefficient of variation, clipped at 0 (a
            # negative current would drain the pixel; SCSim's pixels with one never fire in the dark).
            dark = np.clip(rng.normal(mean, mean * camera.dark_current_spread, n), 0.0, None).astype(dtype)
        elif camera.dark_current_spread > 0:
            # Lognormal with the given mean and coefficient of variation c:
            # sigma^2 = ln(1 + c^2), mu = ln(mean) - sigma^2 / 2.
            s2 = np.log1p(camera.dark_current_spread ** 2)
            dark = rng.lognormal(np.log(mean) - s2 / 2, np.sqrt(s2), n).astype(dtype)
        else:
            dark = np.full(n, mean, dtype=dtype)

    threshold = None
    if camera.threshold_mismatch > 0 or camera.threshold_offset > 0:
        # Capacitance mismatch (relative) plus comparator voltage offset (fraction of the swing).
        thr = 1.0 + rng.normal(0.0, 1.0, n) * camera.threshold_mismatch + rng.normal(0.0, 1.0, n) * camera.threshold_offset
        threshold = np.clip(thr, *_THRESHOLD_RANGE).astype(dtype)

    # Terms measured on a real recording (SpikeCamera.measured), drawn after every earlier term so a
    # camera without them draws exactly the maps it drew before they existed. They multiply the
    # pixel gain: a row's readout line, a column's amplifier, and a heavy tail of outlier pixels.
    extra = np.ones(n)
    if camera.row_gain_spread > 0:
        rows = rng.normal(1.0, camera.row_gain_spread, camera.height)
        extra *= np.repeat(rows, camera.width)
    if camera.column_gain_spread > 0:
        cols = rng.normal(1.0, camera.column_gain_spread, camera.width)
        extra *= np.tile(cols, camera.height)
    if camera.outlier_pixel_fraction > 0:
        outlier = rng.random(n) < camera.outlier_pixel_fraction
        extra *= np.where(outlier, rng.normal(1.0, camera.outlier_gain_spread, n), 1.0)
    if camera.row_gain_spread > 0 or camera.column_gain_spread > 0 or camera.outlier_pixel_fraction > 0:
        base = gain.astype(np.float64) if gain is not None else 1.0
        gain = np.clip(base * extra, 0.0, None).astype(dtype)

    if camera.random_initial_state:
        init_rng = np.random.Generator(np.random.Philox(np.random.SeedSequence([int(seed), _STREAM_INITIAL_STATE])))
        upper = threshold if threshold is not None else 1.0
        initial = (init_rng.random(n) * upper).astype(dtype)
    else:
        initial = np.zeros(n, dtype=dtype)
    return PixelParameters(gain=gain, dark_per_step=dark, threshold=threshold, initial_accumulator=initial)


__all__ = ["PixelParameters", "draw_pixel_parameters"]
