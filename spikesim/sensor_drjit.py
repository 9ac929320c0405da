"""The spike camera model as a Dr.Jit kernel (LLVM on the CPU, CUDA on NVIDIA GPUs).

The update is the one documented in `sensor_numpy` (same operations, same order, same fixed
patterns), so without temporal noise the stream is bit-identical to the reference.

Layout: one SIMD lane simulates 32 consecutive pixels (in row-major order) and writes one
UInt32 per step, whose little-endian bytes are exactly the packed spike bits (LSB first). This
avoids atomic OR-scatters into shared words (4x slower, measured) and makes the output the
`.dat` frame layout directly. Terms that are switched off are left out when the kernel is traced;
everything that changes between calls (step counts, phases) is opaque, so one kernel is
compiled per configuration and reused (see `tests/test_sensor_backends.py`).
"""
from __future__ import annotations

import math

import numpy as np

from ._drjit import dr
from .camera import SpikeCamera
from .fixed_pattern import PixelParameters

LANE_PIXELS = 32


def _module(backend: str):
    if backend == "llvm":
        import drjit.llvm as m
    elif backend == "cuda":
        import drjit.cuda as m
    else:
        raise ValueError(f"unknown Dr.Jit backend {backend!r}; expected 'llvm' or 'cuda'")
    return m


class InvalidFrames(ValueError):
    """Raised by a backend before any state changes; the Simulator then names the frame."""


def _owned(arrays: list) -> list:
    """Copies in Dr.Jit-allocated (64-byte aligned) memory. Arrays wrapping NumPy buffers are
    traced with unaligned loads, which would compile a second kernel once the state is replaced
    by the kernel's own (aligned) outputs."""
    # An operation with an opaque (evaluated) zero cannot be simplified away, so it allocates.
    out = [(dr.opaque(type(a), False, dr.width(a)) | a) if dr.is_mask_v(a)
           else (dr.opaque(type(a), 0, dr.width(a)) + a) for a in arrays]
    dr.eval(*out)
    return out


class DrJitSensor:
    """Dr.Jit backend; state (accumulators, last spikes) stays on the device between calls."""

    def __init__(self, camera: SpikeCamera, params: PixelParameters, seed: int, backend: str = "llvm"):
        if camera.shot_noise == "poisson":
            raise ValueError("shot_noise='poisson' is implemented by the NumPy reference only; "
                             "use shot_noise='gaussian' with the Dr.Jit backends")
        m = _module(backend)
        self.name = backend
        self.camera = camera
        self.m = m
        self.Float = m.Float64 if camera.precision == "float64" else m.Float32
        self.UInt32 = m.UInt32
        self.dtype = np.dtype(camera.precision)
        P = camera.num_pixels
        self.num_lanes = (P + LANE_PIXELS - 1) // LANE_PIXELS
        self.padded = self.num_lanes * LANE_PIXELS
        # Philox key: the seed mixed with a constant so it differs from NumPy's streams.
        self._key = m.UInt64((int(seed) * 0x9E3779B97F4A7C15 + 0x5DEECE66D) % (1 << 64))

        def lanes(arr: np.ndarray | None, fill: float):
            """(P,) -> 32 device arrays, column j holding pixel lane*32 + j."""
            if arr is None:
                return None
            pad = np.full(self.padded, fill, dtype=self.dtype)
            pad[:P] = arr
            cols = pad.reshape(self.num_lanes, LANE_PIXELS)
            return _owned([self.Float(np.ascontiguousarray(cols[:, j])) for j in range(LANE_PIXELS)])

        # Padded pixels: no input, no dark current, threshold 1, empty: they never fire.
        self._gain = lanes(params.gain, 1.0)
        self._dark = lanes(params.dark_per_step, 0.0)
        self._threshold = lanes(params.threshold, 1.0)
        self._acc = lanes(params.initial_accumulator, 0.0)
        self._fired = [dr.zeros(m.Bool, self.num_lanes) for _ in range(LANE_PIXELS)]
        # Evaluated, not literal, so the first call traces the same kernel as later ones.
        dr.make_opaque(*self._fired)

    # ------------------------------------------------------------------------------------------
    def run(self, keyframes: np.ndarray, phase: int, keyframe_every: int, num_steps: int,
            first_step: int) -> np.ndarray:
        cam, m, Float, UInt32 = self.camera, self.m, self.Float, self.UInt32
        P, L = cam.num_pixels, self.num_lanes
        k = int(keyframe_every)
        if first_step // (1 << 32) != (first_step + num_steps - 1) // (1 << 32):
            raise ValueError("a chunk may not straddle a multiple of 2^32 steps (the Simulator splits chunks there)")
        frames = m.Float32(np.ascontiguousarray(keyframes, dtype=np.float32).ravel())
        n_op = dr.opaque(UInt32, num_steps)
        phase_op = dr.opaque(UInt32, phase)
        k_op = dr.opaque(UInt32, k)
        step_lo = dr.opaque(UInt32, first_step % (1 << 32))
        step_hi = dr.opaque(UInt32, first_step >> 32)
        lane = dr.arange(UInt32, L)
        out = dr.zeros(UInt32, L * num_steps)

        shot = cam.shot_noise == "gaussian"
        comparator = cam.comparator_noise > 0
        reset_loss = cam.reset_loss > 0
        interpolate = k > 1
        inv_ne = 1.0 / cam.threshold_electrons
        retain = 1.0 - cam.reset_loss
        sigma_c = cam.comparator_noise
        padded_tail = P % LANE_PIXELS != 0
        gain, dark, thr = self._gain, self._dark, self._threshold

        def body(s, acc, fired, bad):
            acc, fired = list(acc), list(fired)
            t = phase_op + s
            if interpolate:
                j = t // k_op
                r = t - j * k_op
                w = Float(r) / Float(k_op)
                base_a = j * P
                base_b = dr.select(r > 0, base_a + P, base_a)
            else:
                base_a = t * P
            bits = UInt32(0)
            for p in range(LANE_PIXELS):
                pix = lane * LANE_PIXELS + p
                active = pix < P if padded_tail else True
                y = Float(dr.gather(m.Float32, frames, base_a + pix, active))
                # Input validation for free while the value is in a register: NaN, +-inf and
                # negative y flag the chunk, which is then rejected without touching the state.
                bad |= ~((y >= 0.0) & (y < math.inf))
                if interpolate:
                    yb = Float(dr.gather(m.Float32, frames, base_b + pix, active))
                    y = dr.select(r > 0, y * (1.0 - w) + yb * w, y)
                e = y * gain[p] if gain is not None else y
                if dark is not None:
                    e = e + dark[p]
                if shot or comparator:
                    if p % 2 == 0:
                        # One Philox call gives four uniforms: two for this pixel, two for the next.
                        u4 = m.Philox4x32(self._key, lane * (LANE_PIXELS // 2) + p // 2, step_lo + s, step_hi).next_float32x4()
                    u0, u1 = (u4[0], u4[1]) if p % 2 == 0 else (u4[2], u4[3])
                    # Box-Muller: two independent standard normals from two uniforms.
                    radius = dr.sqrt(-2.0 * dr.log(1.0 - Float(u0)))
                    sin_, cos_ = dr.sincos(2.0 * math.pi * Float(u1))
                if shot:
                    e = e + dr.sqrt(e * inv_ne) * (radius * cos_)
                if reset_loss:
                    e = dr.select(fired[p], e * retain, e)
                a = acc[p] + e
                threshold = thr[p] if thr is not None else Float(1.0)
                if comparator:
                    f = a >= threshold + sigma_c * (radius * sin_)
                else:
                    f = a >= threshold
                a = dr.select(f, a - threshold, a)
                acc[p] = dr.minimum(dr.maximum(a, -threshold), threshold + threshold)
                if reset_loss:
                    fired[p] = f
                bits |= dr.select(f, UInt32(1 << p), UInt32(0))
            dr.scatter(out, bits, s * L + lane)
            return s + 1, acc, fired, bad

        s0 = UInt32(0)
        bad0 = dr.opaque(m.Bool, False, L)
        # The last-step spikes are loop state only where the reset loss reads them.
        fired0 = self._fired if reset_loss else []
        _, acc, fired, bad = dr.while_loop((s0, self._acc, fired0, bad0), lambda s, a, f, b: s < n_op, body)
        if not reset_loss:
            fired = self._fired
        dr.eval(out, acc, fired, bad)
        if bool(dr.any(bad)):
            raise InvalidFrames("a frame holds NaN, infinite or negative irradiance")
        self._acc, self._fired = list(acc), list(fired)
        words = out.numpy().reshape(num_steps, L)
        return words.view(np.uint8)[:, : (P + 7) // 8]

    # ------------------------------------------------------------------------------------------
    def _gather_state(self, cols: list) -> np.ndarray:
        arr = np.stack([np.asarray(c.numpy()) for c in cols], axis=1).reshape(-1)
        return arr[: self.camera.num_pixels]

    def get_state(self) -> dict[str, np.ndarray]:
        return {"accumulator": self._gather_state(self._acc).astype(self.dtype),
                "fired": self._gather_state(self._fired).astype(bool)}

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        P, m = self.camera.num_pixels, self.m
        acc = np.zeros(self.padded, dtype=self.dtype)
        acc[:P] = state["accumulator"]
        fired = np.zeros(self.padded, dtype=bool)
        fired[:P] = state["fired"]
        acc, fired = acc.reshape(self.num_lanes, -1), fired.reshape(self.num_lanes, -1)
        self._acc = _owned([self.Float(np.ascontiguousarray(acc[:, j])) for j in range(LANE_PIXELS)])
        self._fired = _owned([m.Bool(np.ascontiguousarray(fired[:, j])) for j in range(LANE_PIXELS)])


__all__ = ["DrJitSensor", "InvalidFrames", "LANE_PIXELS"]
