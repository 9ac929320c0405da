"""The NumPy reference of the spike camera model: one readout step at a time, written for clarity.

Every backend implements exactly this update, in this order of floating-point operations, for
pixel x at step n (accumulator A and threshold theta in units of the nominal threshold):

    y      = Y_j (1 - w) + Y_{j+1} w        keyframe interpolation, w = (n mod k) / k; y = Y_j if k = 1
    y      = min(y, Y_MAX)                  bound far above saturation (camera.Y_MAX)
    e      = y g + d                        gain (PRNU) and dark current, docs/sensor.md
    e      = e + sqrt(e / N_e) z1           shot noise (gaussian; or Poisson(e N_e) / N_e)
                                            z1, z2: the step's Philox word, spikesim/philox.py
    e      = e (1 - r)   if x fired at n-1  reset/readout loss
    u      = e - c;  t = A + u              integrate (paper eq. 1), compensated (Kahan):
    c      = (t - A) - u;  A = t            c carries the low bits float32 drops
    fire   = A >= theta + sigma_c z2        comparator with temporal noise
    A      = A - theta   if fire            reset by subtraction: A mod theta (paper eq. 1)
             A - theta G if fire            renewal shot noise instead of the per-step term:
                                            G ~ Gamma(k)/k, k = theta N_e (Wilson-Hilferty)
    A      = min(max(A, -theta), 2 theta)   saturation: at most one spike per readout

Compensation: a plain float32 sum stalls when y is below half an ulp of A (at y = 1e-8 the
accumulator stayed at 0.25 forever) and drifts for small y (at y = 1e-4 one interval in two was
9999 steps instead of 10000-10001). With the compensation term the sum of e over any number of
steps is exact to float32 rounding of the total, so rates and intervals hold for any y > 0.

The bounds leave room for comparator noise: a comparator that fires early leaves a negative
residual and one that fires late a residual above theta, and both are kept, so charge is
conserved and the mean rate stays y (clamping to [0, theta] biased the rate by -2 % to +5 % at
sigma_c = 0.2, measured). Only y >= 1 (saturation) reaches the upper bound; it discards the
charge that one spike per step cannot carry.
"""
from __future__ import annotations

import numpy as np

from .camera import Y_MAX, SpikeCamera
from .fixed_pattern import PixelParameters
from .philox import (STEPS_PER_CALL, THRESHOLD_CHARGE_TAG, half_word_normals_numpy, philox4x32_numpy,
                     philox_key, popcount_normal_numpy, step_words_numpy, threshold_charge_scale)


class NumpySensor:
    """Reference backend. State: accumulator, last-step spikes, temporal-noise generator."""

    name = "numpy"

    def __init__(self, camera: SpikeCamera, params: PixelParameters, seed: int):
        self.camera = camera
        self.params = params
        self.dtype = params.dtype
        self.accumulator = params.initial_accumulator.copy()
        self.compensation = np.zeros_like(self.accumulator)
        self.fired = np.zeros(camera.num_pixels, dtype=bool)
        # Per-pixel-step normals (shot noise, comparator) and the renewal shot noise's threshold
        # charges: Philox counted by (pixel, step group) and (pixel, spike index), as the Dr.Jit
        # kernel draws them, so the two agree bit for bit and chunking changes nothing.
        self._key = philox_key(seed)
        self._pixels = np.arange(camera.num_pixels, dtype=np.uint64)
        self._words: tuple[int, tuple] | None = None  # the last Philox call's group and words
        self.spike_count = np.zeros(camera.num_pixels, dtype=np.uint64)
        # The exact per-step Poisson electrons (NumPy only): a sequential generator, so chunked
        # calls draw what one call would.
        self._rng = np.random.Generator(np.random.Philox(np.random.SeedSequence([int(seed), 2])))

    def run(self, keyframes: np.ndarray, phase: int, keyframe_every: int, num_steps: int,
            first_step: int) -> np.ndarray:
        """Simulate `num_steps` steps; step s reads keyframes around (phase + s) / keyframe_every.

        Returns the packed spike frames, uint8 (num_steps, ceil(H*W/8)), LSB first.
        """
        cam, p, dt = self.camera, self.params, self.dtype
        k = keyframe_every
        nbytes = (cam.num_pixels + 7) // 8
        out = np.empty((num_steps, nbytes), dtype=np.uint8)
        one = dt.type(1)
        inv_ne = dt.type(1.0 / cam.threshold_electrons)
        retain = dt.type(1.0 - cam.reset_loss)
        sigma_c = dt.type(cam.comparator_noise)
        threshold = p.threshold if p.threshold is not None else one
        y_max = dt.type(Y_MAX)
        A, c = self.accumulator, self.compensation
        draws = cam.shot_noise == "gaussian" or cam.comparator_noise > 0
        for s in range(num_steps):
            t = phase + s
            j, r = divmod(t, k)
            y = keyframes[j].astype(dt, copy=False)
            if r:
                w = dt.type(r) / dt.type(k)
                y = y * (one - w) + keyframes[j + 1].astype(dt, copy=False) * w
            y = np.minimum(y, y_max)
            e = y * p.gain if p.gain is not None else y
            if p.dark_per_step is not None:
                e = e + p.dark_per_step
            if draws:
                z_shot, z_comparator = self._step_normals(first_step + s)
            if cam.shot_noise == "gaussian":
                e = e + np.sqrt(e * inv_ne) * z_shot.astype(dt, copy=False)
            elif cam.shot_noise == "poisson":
                e = (self._rng.poisson(e.astype(np.float64) * cam.threshold_electrons) * (1.0 / cam.threshold_electrons)).astype(dt)
            if cam.reset_loss > 0:
                e = np.where(self.fired, e * retain, e)
            u = e - c
            total = A + u
            c = (total - A) - u
            A = total
            noise = sigma_c * z_comparator.astype(dt, copy=False) if cam.comparator_noise > 0 else None
            fire = A >= threshold + noise if noise is not None else A >= threshold
            if cam.shot_noise == "renewal":
                taken = threshold * self._threshold_charge(threshold, fire)
            else:
                taken = threshold
            if noise is not None and cam.reset_rule == "fired":  # the level it fired at (SCSim's reset)
                taken = taken + noise
            A = np.where(fire, A - taken, A)
            A = np.minimum(np.maximum(A, -threshold), threshold + threshold)
            self.fired = fire
            out[s] = np.packbits(fire, bitorder="little")
        self.accumulator = A.astype(dt, copy=False)
        self.compensation = c.astype(dt, copy=False)
        return out

    def _step_normals(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        """(shot, comparator) normals of absolute step `step`: its word of Philox call step // 4."""
        group, q = divmod(int(step), STEPS_PER_CALL)
        if self._words is None or self._words[0] != group:
            self._words = (group, step_words_numpy(self._key, self._pixels, group))
        return half_word_normals_numpy(self._words[1][q])

    def _threshold_charge(self, threshold, fire: np.ndarray) -> np.ndarray:
        """The charge (over the threshold) of the interval each firing pixel starts: Gamma(k)/k,
        k = threshold x N_e electrons, by the Wilson-Hilferty cube (1 - s^2 + s z)^3, s = 1/(3 sqrt
        k) (quantiles within 1e-3 of the Gamma's for k >= 10, the camera's least); z the popcount
        normal of 64 bits of Philox4x32-7 counted by (pixel, spike index, 64 bits). Counts the
        spikes. Returns a full-size array (1 where a pixel did not fire)."""
        dt = self.dtype
        idx = np.flatnonzero(fire)
        self.spike_count[idx] += np.uint64(1)
        c = self.spike_count[idx]
        w = philox4x32_numpy(self._key, (idx.astype(np.uint64), c & np.uint64(0xFFFFFFFF), c >> np.uint64(32),
                                         THRESHOLD_CHARGE_TAG))
        s = threshold_charge_scale(threshold if np.ndim(threshold) == 0 else np.asarray(threshold)[idx],
                                   self.camera.threshold_electrons, dt)
        g = (dt.type(1) - s * s) + s * popcount_normal_numpy(w[0], w[1]).astype(dt)
        out = np.ones(fire.shape, dtype=dt)
        out[idx] = (g * g) * g
        return out

    # state access shared with the Dr.Jit backend
    def get_state(self) -> dict[str, np.ndarray]:
        state = {"accumulator": self.accumulator.copy(), "compensation": self.compensation.copy(),
                 "fired": self.fired.copy()}
        if self.camera.shot_noise == "renewal":
            state["spike_count"] = self.spike_count.copy()
        return state


__all__ = ["NumpySensor"]
