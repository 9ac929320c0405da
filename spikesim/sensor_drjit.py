"""The spike camera model as a Dr.Jit kernel (LLVM on the CPU, CUDA on NVIDIA GPUs).

The update is the one documented in `sensor_numpy` (same operations, same order, same fixed
patterns, same counter-based random numbers), so the stream is bit-identical to the reference.

Layout, chosen from the roofline in docs/performance.md:
- One lane per (stream, pixel): loads of irradiance and pixel parameters are contiguous across
  lanes (SIMD on the CPU, coalesced on the GPU), and several streams (scenes, seeds, RLLR
  samples) share one launch, so a small frame still fills a GPU.
- With a frame every step on the CPU, a launch of one 32-step word takes its frames as 32 input
  arrays (host rows wrapped in place, or the renderer's frames) and runs them unrolled: each
  read is a vector load, where an index computed in a loop compiles to a gather (16 scalar
  loads). Other launches (keyframes, a word cut by a call's end, the GPU) run the general loop.
- Each lane keeps the spikes of 32 consecutive steps in one UInt32 (bit i = step i) and writes
  one word per 32 steps. A second, cheap kernel transposes 32 x 32 bit blocks into the `.dat`
  frame layout (32 pixels per word, least significant bit first). Only packed words leave the
  device.
- Temporal noise is Philox4x32-7 keyed by the stream's seed, counted by (pixel, step // 4): one
  call serves 4 steps, a word a step, whose 16-bit halves give the step's shot-noise and
  comparator normals (popcount normals, no logarithm or sine); each renewal threshold charge has
  its own call, counted by (pixel, spike index). The NumPy reference draws the same
  (spikesim/philox.py), so every camera's stream is bit-identical across backends and does not
  depend on chunking or on which streams share a launch. The loop runs over groups of G steps unmasked; a group cut by a call's first
  or last step runs as a masked piece of its own, whose steps outside the call leave the state
  untouched.
- Everything that changes between calls (step counts, phases, offsets) is an opaque scalar, so
  one kernel is compiled per configuration and reused (tests/test_sensor_backends.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ._drjit import collector_held, dr
from .camera import Y_MAX, SpikeCamera
from .errors import InvalidFrames
from .fixed_pattern import PixelParameters
from .philox import (PHILOX_M, PHILOX_ROUNDS, PHILOX_W, STEPS_PER_CALL, THRESHOLD_CHARGE_TAG, philox_key,
                     threshold_charge_scale)

#: Steps whose spikes one lane collects in one output word.
WORD_STEPS = 32

_PHILOX_M, _PHILOX_W, _PHILOX_ROUNDS = PHILOX_M, PHILOX_W, PHILOX_ROUNDS


def _module(backend: str):
    if backend == "llvm":
        import drjit.llvm as m
    elif backend == "cuda":
        import drjit.cuda as m
    else:
        raise ValueError(f"unknown Dr.Jit backend {backend!r}; expected 'llvm' or 'cuda'")
    return m


def philox4x32(m, key: tuple, counter: tuple, rounds: int = _PHILOX_ROUNDS) -> tuple:
    """Philox4x32 unrolled: `key` = (hi, lo) UInt32 words of the 64-bit seed, `counter` = four
    UInt32 words. Bit-identical to Dr.Jit's `Philox4x32(seed, c0, c1, c2).next_uint32x4()`
    (tested), but with the rounds unrolled and the 32 x 32 -> 64-bit products split into
    `mul_hi` and a plain multiply, which the CPU runs about 1.6x faster inside the sensor loop."""
    s0, s1, s2, s3 = counter
    k0, k1 = key
    for _ in range(rounds):
        hi0, lo0 = dr.mul_hi(s0, m.UInt32(_PHILOX_M[0])), s0 * _PHILOX_M[0]
        hi1, lo1 = dr.mul_hi(s2, m.UInt32(_PHILOX_M[1])), s2 * _PHILOX_M[1]
        s0, s1, s2, s3 = hi1 ^ s1 ^ k0, lo1, hi0 ^ s3 ^ k1, lo0
        k0, k1 = k0 + _PHILOX_W[0], k1 + _PHILOX_W[1]
    return s0, s1, s2, s3


def half_word_normals(m, word):
    """(shot, comparator) normals of a step's 32-bit word: (popcount - 8) / 2 of its low and of its
    high 16 bits, Binomial(16, 1/2) standardised (spikesim.philox.half_word_normals_numpy is the
    NumPy twin, and the reason this is enough). Against two Box-Muller pairs per call serving two
    steps, 1.5x the realistic CPU kernel's speed (docs/performance.md)."""
    return ((m.Float32(dr.popcnt(word & 0xFFFF)) - 8.0) * 0.5,
            (m.Float32(dr.popcnt(word >> 16)) - 8.0) * 0.5)


def popcount_normal(m, *words):
    """A standard normal variate from 32 n random bits: (popcount - 16 n) / sqrt(8 n), a
    Binomial(32 n, 1/2) with a normal's mean and variance exactly (excess kurtosis -1/(16 n)), no
    logarithm or sine (spikesim.philox.popcount_normal_numpy is its NumPy twin). The renewal camera
    draws each spike's threshold charge (two words) this way; the golden check passes with it
    (docs/sensor.md)."""
    bits = dr.popcnt(words[0])
    for w in words[1:]:
        bits = bits + dr.popcnt(w)
    n = len(words)
    return (m.Float32(bits) - 16.0 * n) * (1.0 / math.sqrt(8.0 * n))


def draws_per_step(camera: SpikeCamera) -> bool:
    """Whether a step draws normals (shot noise or comparator): a Philox word a step, 4 steps a
    call. The renewal camera's threshold charges have their own call, counted by spike."""
    return camera.shot_noise == "gaussian" or camera.comparator_noise > 0


@dataclass
class DevicePacked:
    """Spikes of S streams over n steps, packed on the device: UInt32 words (S, n, G), G =
    ceil(H W / 32), word g of a frame holding pixels 32 g .. 32 g + 31 (row-major, top-down),
    least significant bit first: the `.dat` frame layout before the optional flip. Held as
    parts (S, n_i, G) that follow each other in time, joined on the way out: a join on the
    device costs a scatter kernel per part (docs/performance.md section 3c)."""

    parts: list
    part_steps: list
    num_streams: int
    height: int
    width: int
    _joined: Any = field(default=None, init=False, repr=False)

    @property
    def num_steps(self) -> int:
        return int(sum(self.part_steps))

    @property
    def words_per_frame(self) -> int:
        return (self.height * self.width + 31) // 32

    def _views(self):
        return [(p, n) for p, n in zip(self.parts, self.part_steps) if n]

    @property
    def words(self):
        """The words as one device array (S n G,), joined on the device once."""
        if self._joined is None:
            self._joined = self._join()
        return self._joined

    def _join(self):
        views = self._views()
        if len(views) <= 1:
            return views[0][0] if views else self.parts[0]
        S, G = self.num_streams, self.words_per_frame
        index, base = [], 0
        for _, n in views:  # part i's (s, j, g) word lands at (s, before_i + j, g)
            index.append(np.arange(S)[:, None, None] * (n * G) + np.arange(n * G).reshape(1, n, G) + base)
            base += S * n * G
        src = np.concatenate(index, axis=1).reshape(-1).astype(np.uint32)
        joined = dr.concat([p for p, _ in views])
        return dr.gather(type(joined), joined, dr.uint32_array_t(type(joined))(src))

    def to_numpy(self) -> np.ndarray:
        """uint8 (S, n, ceil(H W / 8)): the host copy, the only transfer off the device."""
        nbytes = (self.height * self.width + 7) // 8
        S, G = self.num_streams, self.words_per_frame
        parts = [np.asarray(p.numpy(), dtype=np.uint32).reshape(S, n, G) for p, n in self._views()]
        if not parts:
            return np.zeros((S, 0, nbytes), dtype=np.uint8)
        w = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
        b = w.view(np.uint8)
        return b if b.shape[2] == nbytes else np.ascontiguousarray(b[:, :, :nbytes])

    def to_torch(self):
        """A torch tensor (S, n, G) of `words`, sharing the device memory (DLPack, no copy).
        torch has no bit unpacking of its own: `spikesim.torch_interop.unpack_words` does it."""
        import torch
        return torch.from_dlpack(self.words).view(self.num_streams, self.num_steps, self.words_per_frame)


class FrameBlock:
    """Keyframes as the two kernels read them: one flat Float32 array (m S P,) for the general
    kernel, and frame i as an array of its own for the frame-per-step kernel, whose loads then
    need no gather. Neither is copied where the input allows: NumPy frames are wrapped in place
    on the CPU, and a list of device frames is joined only if the general kernel needs it."""

    def __init__(self, m, keyframes: Any, values: int):
        self._m, self._flat, self._host, self._list = m, None, None, None
        if isinstance(keyframes, np.ndarray):
            self._host = np.ascontiguousarray(keyframes, dtype=np.float32).reshape(-1, values)
        else:
            self._list = [p if isinstance(p, m.Float32) else m.Float32(p) for p in keyframes]

    @property
    def flat(self):
        if self._flat is None:
            if self._host is not None:
                self._flat = self._m.Float32(self._host.reshape(-1))
            else:
                self._flat = self._list[0] if len(self._list) == 1 else dr.concat(self._list)
        return self._flat

    def rows(self, lo: int, hi: int):
        """Frames [lo, hi) as one flat array: a view of host rows, or the device frames joined."""
        if self._host is not None:
            return self._m.Float32(self._host[lo:hi].reshape(-1))
        return self._list[lo] if hi - lo == 1 else dr.concat(self._list[lo:hi])

    def row(self, i: int):
        """Frame i (S P values) as its own array: a host row wrapped in place, or the device frame."""
        return self._m.Float32(self._host[i]) if self._host is not None else self._list[i]


class DrJitSensor:
    """Dr.Jit backend for S streams of one camera model, simulated in one launch.

    Each stream has its own seed (fixed patterns, initial state and temporal noise). State
    (accumulators, their compensation terms, last-step spikes) stays on the device between calls.
    """

    def __init__(self, camera: SpikeCamera, params: PixelParameters | Sequence[PixelParameters],
                 seed: int | Sequence[int], backend: str = "llvm", steps_per_launch: int | None = None):
        if camera.shot_noise == "poisson":
            raise ValueError("shot_noise='poisson' (per step) is implemented by the NumPy reference only; with "
                             "the Dr.Jit backends use shot_noise='renewal' (exact Poisson electrons, drawn per "
                             "spike) or 'gaussian'")
        params = [params] if isinstance(params, PixelParameters) else list(params)
        seeds = [seed] if isinstance(seed, (int, np.integer)) else [int(s) for s in seed]
        if len(params) != len(seeds) or not seeds:
            raise ValueError(f"{len(params)} pixel-parameter sets for {len(seeds)} seeds")
        m = _module(backend)
        self.name, self.camera, self.m = backend, camera, m
        self.Float = m.Float64 if camera.precision == "float64" else m.Float32
        self.dtype = np.dtype(camera.precision)
        self.num_streams = len(seeds)
        P = camera.num_pixels
        self.width_lanes = self.num_streams * P
        # Launch length: the CPU keeps each SIMD packet's inputs in cache and the TLB by walking
        # few steps per launch (measured: 32 steps 2.2x faster than 2048); a GPU wants long
        # launches so the Python-side launch cost (~0.1 ms) stays small.
        self.steps_per_launch = int(steps_per_launch or (WORD_STEPS if backend == "llvm" else 32 * WORD_STEPS))

        def lanes(arrays: list):
            if arrays[0] is None:
                return None
            return self._owned(self.Float(np.concatenate(arrays).astype(self.dtype, copy=False)))

        self._gain = lanes([p.gain for p in params])
        self._dark = lanes([p.dark_per_step for p in params])
        self._threshold = lanes([p.threshold for p in params])
        self._acc = lanes([p.initial_accumulator for p in params])
        self._comp = self._owned(dr.zeros(self.Float, self.width_lanes))
        self._fired = self._owned(dr.zeros(m.Bool, self.width_lanes))
        keys = np.array([philox_key(s) for s in seeds], dtype=np.uint32)
        self._key_hi = self._owned(m.UInt32(np.repeat(keys[:, 0], P)))
        self._key_lo = self._owned(m.UInt32(np.repeat(keys[:, 1], P)))
        # Pixel index within its stream: the Philox counter, so a stream's noise does not depend
        # on which streams share the launch.
        self._pixel = self._owned(m.UInt32(np.tile(np.arange(P, dtype=np.uint32), self.num_streams)))
        # Renewal shot noise: each spike's threshold charge is Gamma(k)/k, k = threshold x N_e
        # electrons, drawn by Wilson-Hilferty as (1 - s^2 + s z)^3 with s = 1/(3 sqrt(k)).
        # Steps one loop iteration runs: those that share a Philox call (4 steps run unrolled
        # without draws measured no faster: the noiseless loop is not bound by its overhead).
        self.group = STEPS_PER_CALL if draws_per_step(camera) else 1
        self.renewal = camera.shot_noise == "renewal"
        self._renewal_s = None
        if self.renewal and self._threshold is not None:
            self._renewal_s = self._owned(self.Float(threshold_charge_scale(
                np.concatenate([p.threshold for p in params]), camera.threshold_electrons, self.dtype)))
        # Renewal: each lane's spike count (64 bits as two words), the threshold charges' counter.
        self._counts = ((self._owned(dr.zeros(m.UInt32, self.width_lanes)),
                         self._owned(dr.zeros(m.UInt32, self.width_lanes))) if self.renewal else ())
        self._integrate = dr.freeze(self._integrate_traced, warn_after=20)
        self._integrate_rows = dr.freeze(self._integrate_rows_traced, warn_after=20)
        self._pack = dr.freeze(self._pack_traced, warn_after=20)

    @staticmethod
    def _owned(x):
        """A copy in Dr.Jit-allocated memory. Arrays wrapping NumPy buffers are traced with other
        alignment than the kernel's own outputs, which would compile a second kernel once the
        state is replaced by them."""
        out = (dr.opaque(type(x), False, dr.width(x)) | x) if dr.is_mask_v(x) else (dr.opaque(type(x), 0, dr.width(x)) + x)
        dr.eval(out)
        return out

    # ------------------------------------------------------------------------------------------
    def keyframe_block(self, keyframes: Any) -> "FrameBlock":
        """The keyframes the kernels read, (m, S, P): a NumPy array (wrapped without a copy on the
        CPU, copied once to a GPU) or a list of Dr.Jit arrays of S P values (the renderer's)."""
        return FrameBlock(self.m, keyframes, self.width_lanes)

    def run_device(self, block, first_key: int, phase: int, keyframe_every: int, num_steps: int,
                   first_step: int) -> DevicePacked:
        """Simulate `num_steps` steps starting at absolute step `first_step`; step s (0-based in
        this call) reads keyframes `first_key + (phase + s) // k` and the next one, interpolated.
        Returns the packed spikes on the device. Raises InvalidFrames (state untouched) if a value
        read is NaN, infinite or negative.

        Steps that share a Philox call (`group`) run in the unmasked kernel; only a group cut by
        the call's first or last step runs in the masked one, as a piece of its own (masking every
        step cost 15-30 % of the realistic kernel, docs/performance.md)."""
        G = self.group
        head = min((-first_step) % G, num_steps)
        tail = (num_steps - head) % G
        pieces = [(s0, n, n % G != 0 or (first_step + s0) % G != 0)
                  for s0, n in ((0, head), (head, num_steps - head - tail), (num_steps - tail, tail)) if n]
        state = (self._acc, self._comp, self._fired, *self._counts)
        bad = dr.opaque(self.m.Bool, False, self.width_lanes)
        parts = []
        with collector_held():  # the pieces call frozen functions (spikesim._drjit.collector_held)
            for s0, n, masked in pieces:
                state, bad, out = self._run_piece(block, first_key, phase + s0, keyframe_every, n, first_step + s0,
                                                  masked, state, bad)
                parts.append((out, n))
        if bool(dr.any(bad)[0]):
            raise InvalidFrames("a frame holds NaN, infinite or negative irradiance")
        # The state is committed only now: an invalid frame leaves it as it was.
        self._acc, self._comp, self._fired, *counts = state
        self._counts = tuple(counts)
        cam = self.camera
        return DevicePacked([p for p, _ in parts], [n for _, n in parts], self.num_streams, cam.height, cam.width)

    def _run_piece(self, block, first_key: int, phase: int, k: int, num_steps: int, first_step: int,
                   masked: bool, state: tuple, bad):
        """Launches over one piece of a call: the new state, invalid mask and packed words."""
        m, SP, L, G = self.m, self.width_lanes, self.steps_per_launch, self.group
        k = int(k)
        # Steps count from base = first_step, rounded down to a multiple of the steps that share
        # a Philox call. Launches cover [l L, (l + 1) L) of that count, so their words join
        # into one timeline of bits.
        offset = first_step % G
        span = offset + num_steps
        fixed = (self._gain, self._dark, self._threshold, self._key_hi, self._key_lo, self._pixel, self._renewal_s)
        op = lambda v: dr.opaque(m.UInt32, v)  # noqa: E731
        # A frame every step on the CPU: each launch reads its own frames, as row arrays where it
        # runs whole words unmasked, else as one flat array of just those frames.
        own_rows = self.row_kernel and k == 1
        words = []
        for a in range(0, span, L):
            lo, hi = max(a, offset), min(a + L, span)
            t, step = phase + lo - offset, first_step + lo - offset
            groups = (op((step // G) & 0xFFFFFFFF), op((step // G) >> 32 & 0xFFFFFFFF))
            if own_rows and not masked and lo == a and hi - lo == WORD_STEPS:
                rows = tuple(block.row(first_key + t + j) for j in range(WORD_STEPS))
                state, bad, w = self._integrate_rows(rows, fixed, state, bad, groups)
            elif own_rows:
                control = (op(0), op(0), op(1), op(hi - lo), op(lo - a), *groups)
                state, bad, w = self._integrate(False, masked, block.rows(first_key + t, first_key + t + hi - lo),
                                                fixed, state, bad, control)
            else:
                control = (op((first_key + t // k) * SP), op(t % k), op(k), op(hi - lo), op(lo - a), *groups)
                state, bad, w = self._integrate(k > 1, masked, block.flat, fixed, state, bad, control)
            words.append(w)
        words = self._concat(words)
        W = self._words_per_frame()
        blocks = (span + WORD_STEPS - 1) // WORD_STEPS
        out = self._pack(words, dr.arange(m.UInt32, blocks * self.num_streams * W),
                         dr.empty(m.UInt32, self.num_streams * num_steps * W), (op(offset), op(span), op(num_steps)))
        return tuple(state), bad, out

    def _concat(self, arrays: list):
        """Equal-sized launch outputs, one after the other, in one kernel (`dr.concat` runs a
        scatter kernel per array: 4 % of the noiseless sensor's time)."""
        if len(arrays) == 1:
            return arrays[0]
        n = dr.width(arrays[0])
        out = dr.empty(type(arrays[0]), n * len(arrays))
        lane = dr.arange(self.m.UInt32, n)
        for i, a in enumerate(arrays):  # disjoint writes: Permute keeps them in one kernel
            dr.scatter(out, a, i * n + lane, mode=dr.ReduceMode.Permute)
        dr.eval(out)
        return out

    @property
    def row_kernel(self) -> bool:
        """Whether whole-word launches with a frame every step read the rows as host arrays
        (packet loads): the CPU backend only, whose arrays wrap host memory without a copy."""
        return self.name == "llvm" and self.steps_per_launch == WORD_STEPS

    def _words_per_frame(self) -> int:
        return (self.camera.num_pixels + WORD_STEPS - 1) // WORD_STEPS

    # ------------------------------------------------------------------------------------------
    def _step_rules(self, fixed: tuple):
        """The readout step and its temporal-noise draws, in the order of sensor_numpy, shared by
        both kernels. `fixed` holds the pixel parameters, the key and the Philox pixel counter.
        Returns (step, group_normals)."""
        cam, m, Float, UInt32 = self.camera, self.m, self.Float, self.m.UInt32
        gain, dark, thr, key_hi, key_lo, pixel, renewal_s = fixed
        shot = cam.shot_noise == "gaussian"
        renewal = cam.shot_noise == "renewal"
        comparator = cam.comparator_noise > 0
        reset_fired = cam.reset_rule == "fired"
        reset_loss = cam.reset_loss > 0
        inv_ne = 1.0 / cam.threshold_electrons
        retain = 1.0 - cam.reset_loss
        sigma_c = cam.comparator_noise
        threshold = thr if thr is not None else Float(1.0)
        if renewal:
            s_shot = renewal_s if renewal_s is not None else Float(float(
                threshold_charge_scale(1.0, cam.threshold_electrons, self.dtype)))

        def group_normals(c, c_hi):
            """(shot, comparator) normals of the `group` steps of Philox call c (64 bits: c_hi,
            c): a word a step, a normal from each of its 16-bit halves."""
            u = philox4x32(m, (key_hi, key_lo), (pixel, c, c_hi, UInt32(0)))
            return [half_word_normals(m, u[q]) for q in range(self.group)]

        def threshold_charge(counts):
            """The charge of the interval that a spike now would start, over the threshold:
            Gamma(k)/k by the Wilson-Hilferty cube of a popcount normal (z >= -8 keeps it positive
            for k >= 10 electrons, the camera's least), drawn from Philox counted by the spike's
            index (count + 1, 64 bits), so the draw does not depend on the step it falls on."""
            lo, hi = counts
            nxt = lo + 1
            u = philox4x32(m, (key_hi, key_lo), (pixel, nxt, hi + dr.select(nxt == 0, UInt32(1), UInt32(0)),
                                                  UInt32(THRESHOLD_CHARGE_TAG)))
            g = (1.0 - s_shot * s_shot) + s_shot * Float(popcount_normal(m, u[0], u[1]))
            return threshold * (g * g * g)

        def step(y, z, acc, comp, fired, counts):
            """One readout step: the spikes, and the new accumulator, compensation and counts."""
            e = y * gain if gain is not None else y
            if dark is not None:
                e = e + dark
            if shot:
                e = e + dr.sqrt(e * inv_ne) * Float(z[0])
            if reset_loss:
                e = dr.select(fired, e * retain, e)
            # Compensated (Kahan) integration: float32 keeps tiny y exact over any length.
            u = e - comp
            total = acc + u
            comp = (total - acc) - u
            noise = sigma_c * Float(z[1]) if comparator else None
            f = (total >= threshold + noise) if comparator else (total >= threshold)
            if renewal:  # reset by the next interval's threshold charge; count the spike
                taken = threshold_charge(counts)
                lo, hi = counts
                lo2 = dr.select(f, lo + 1, lo)
                counts = (lo2, dr.select(f & (lo2 == 0), hi + 1, hi))
            else:
                taken = threshold
            if comparator and reset_fired:  # the level it fired at (SCSim's reset)
                taken = taken + noise
            total = dr.select(f, total - taken, total)
            return f, dr.minimum(dr.maximum(total, -threshold), threshold + threshold), comp, counts
        return step, group_normals

    @staticmethod
    def _invalid(y):
        """NaN, infinite or negative irradiance."""
        return ~((y >= 0.0) & (y < math.inf))

    def _integrate_rows_traced(self, rows: tuple, fixed: tuple, state: tuple, bad, control: tuple):
        """One launch over one whole 32-step word with a frame every step (the common case). Step
        j's frame is its own input array `rows[j]`, so each read is a packet load where
        `_integrate_traced` gathers (a gather per step bounded that kernel, docs/performance.md
        section 3c), and the 32 steps are unrolled. Bit-identical to `_integrate_traced`
        (tested); returns what it returns (the words of one launch, created inside: a frozen
        function copies an array passed in to be written, measured slower). `control`: the first
        step's Philox call (64 bits)."""
        m, UInt32, Float = self.m, self.m.UInt32, self.Float
        group_lo, group_hi = control
        step, group_normals = self._step_rules(fixed)
        acc, comp, fired, *counts = state
        counts = tuple(counts)
        bits = UInt32(0)
        G, draws = self.group, draws_per_step(self.camera)
        z = [(None, None)] * G
        for j in range(WORD_STEPS):
            if draws and j % G == 0:
                c = group_lo + (j // G)
                z = group_normals(c, group_hi + dr.select(c < group_lo, UInt32(1), UInt32(0)))
            y = Float(rows[j])
            bad = bad | self._invalid(y)
            f, acc, comp, counts = step(dr.minimum(y, Y_MAX), z[j % G], acc, comp, fired, counts)
            if self.camera.reset_loss > 0:
                fired = f
            bits = bits | dr.select(f, UInt32(1 << j), UInt32(0))
        new = (acc, comp, fired, *counts)
        dr.eval(bits, new, bad)
        return new, bad, bits

    def _integrate_traced(self, interpolate: bool, masked: bool, block, fixed: tuple, state: tuple, bad,
                          control: tuple):
        """One launch: integrate-and-fire over at most `steps_per_launch` steps. Returns the new
        state, the invalid-input mask and the spike words (steps_per_launch / 32 words per lane:
        bit i of word w is step base + 32 w + i; base is the first step, rounded down to a multiple
        of the steps that share a Philox call).

        Frozen (dr.freeze): traced once per input layout, then replayed without Python tracing,
        which otherwise costs more than a short launch computes (0.3-1.6 ms, measured). So every
        value that changes between calls is an opaque 1-wide array in `control`, and every size
        in the code is fixed per sensor."""
        m, Float, UInt32 = self.m, self.Float, self.m.UInt32
        SP = self.width_lanes
        row0, key_phase, k, n, offset, group_lo, group_hi = control
        span = offset + n                 # steps from base; the first `offset` are not ours
        num_words = (span + (WORD_STEPS - 1)) >> 5
        lane = dr.arange(UInt32, SP)
        words = dr.empty(UInt32, self.steps_per_launch // WORD_STEPS * SP)
        step, group_normals = self._step_rules(fixed)
        G = self.group                    # steps an iteration runs; one Philox call serves them
        per_step_draws = draws_per_step(self.camera)
        reset_loss = self.camera.reset_loss > 0

        def read_y(row, r, active):
            """y of this step: keyframe row (and the next, weighted r / k), bounded, and whether a
            value read was invalid. `active` (None: always) marks the steps that are ours: the
            others read the block's first row instead (a select of the index is much cheaper than a
            masked gather on the CPU) and their results are discarded by the caller."""
            y = Float(dr.gather(m.Float32, block, row + lane if active is None else dr.select(active, row + lane, lane)))
            invalid = self._invalid(y)
            if interpolate:
                later = r > 0 if active is None else active & (r > 0)
                yb = Float(dr.gather(m.Float32, block, row + SP + lane, later))
                w = Float(r) / Float(k)
                invalid = invalid | self._invalid(yb)
                y = dr.select(later, y * (1.0 - w) + yb * w, y)
            return dr.minimum(y, Y_MAX), invalid

        def next_row(row, r):
            if not interpolate:
                return row + SP, r
            r = r + 1
            wrap = r == k
            return dr.select(wrap, row + SP, row), dr.select(wrap, UInt32(0), r)

        def keep(active, new, old):
            return new if active is None else dr.select(active, new, old)

        def inner_body(i, bits, row, r, acc, comp, fired, counts, bad, w):
            local = w * WORD_STEPS + i    # step index from base
            if per_step_draws:  # the group's words: (shot, comparator) normals from their halves
                c = group_lo + (local >> (G.bit_length() - 1))
                zs = group_normals(c, group_hi + dr.select(c < group_lo, UInt32(1), UInt32(0)))
            else:  # no per-step draw (the renewal camera's charges have their own)
                zs = [(None, None)]
            for half, z in enumerate(zs):
                # Only a masked piece (a group cut by the call's ends) has steps that are not ours.
                active = (local + half >= offset) & (local + half < span) if masked else None
                y, invalid = read_y(row, r, active)
                f, acc2, comp2, counts2 = step(y, z, acc, comp, fired, counts)
                if active is not None:
                    f, invalid = f & active, invalid & active
                acc, comp = keep(active, acc2, acc), keep(active, comp2, comp)
                counts = tuple(keep(active, a, b) for a, b in zip(counts2, counts))
                if reset_loss:
                    fired = keep(active, f, fired)
                bad = bad | invalid
                bits = bits | dr.select(f, UInt32(1) << (i + half), UInt32(0))
                row2, r2 = next_row(row, r)
                row, r = keep(active, row2, row), keep(active, r2, r)
            return i + len(zs), bits, row, r, acc, comp, fired, counts, bad, w

        def word_body(w, row, r, acc, comp, fired, counts, bad):
            limit = dr.minimum(span - w * WORD_STEPS, UInt32(WORD_STEPS))
            _, bits, row, r, acc, comp, fired, counts, bad, _ = dr.while_loop(
                (UInt32(0), UInt32(0), row, r, acc, comp, fired, counts, bad, w),
                lambda i, *rest: i < limit, inner_body)
            dr.scatter(words, bits, w * SP + lane)
            return w + 1, row, r, acc, comp, fired, counts, bad

        acc, comp, fired, *counts = state
        _, _, _, acc, comp, fired, counts, bad = dr.while_loop(
            (UInt32(0), row0, key_phase, acc, comp, fired, tuple(counts), bad), lambda w, *rest: w < num_words,
            word_body)
        # Evaluate the loop's outputs with its side effect (the words): else the packing
        # forces the scatter alone and the loop runs a second time for the state.
        dr.eval(words, acc, comp, fired, counts, bad)
        return (acc, comp, fired, *counts), bad, words

    def _pack_traced(self, words, idx, out, control: tuple):
        """The .dat frame layout from the lanes' words: one lane per (word block b, stream s,
        32-pixel group g) transposes a 32 x 32 bit block in registers (the recursive block swap
        of Warren, Hacker's Delight, section 7-3). Sizes are literals (fixed per sensor), so the
        divisions compile to multiply-shifts. Frozen like the launch: `idx` (one per lane) and
        `out` are made by the caller, so no size inside depends on a width."""
        UInt32 = self.m.UInt32
        SP, S, P, G = self.width_lanes, self.num_streams, self.camera.num_pixels, self._words_per_frame()
        offset, span, total = control
        num_blocks = (span + (WORD_STEPS - 1)) >> 5
        g, s, b = idx % G, (idx // G) % S, idx // (G * S)
        rows = []
        for q in range(WORD_STEPS):
            pix = g * WORD_STEPS + q
            rows.append(dr.gather(UInt32, words, b * SP + s * P + pix, (pix < P) & (b < num_blocks)))
        j, mask = 16, 0x0000FFFF
        while j:
            for a in range(WORD_STEPS):
                if not a & j:
                    t = ((rows[a] >> j) ^ rows[a + j]) & mask
                    rows[a] = rows[a] ^ (t << j)
                    rows[a + j] = rows[a + j] ^ t
            j >>= 1
            mask ^= mask << j
        # rows[i] now holds step b * 32 + i (from base): bit q = pixel 32 g + q. The writes are
        # disjoint, which Permute mode lets Dr.Jit put in one kernel (else one kernel each).
        for i in range(WORD_STEPS):
            local = b * WORD_STEPS + i
            valid = (local >= offset) & (local < span)
            dr.scatter(out, rows[i], (s * total + local - offset) * G + g, valid, mode=dr.ReduceMode.Permute)
        return out

    # ------------------------------------------------------------------------------------------
    def get_state(self) -> dict[str, np.ndarray]:
        """Accumulators, their compensation terms and last-step spikes, (S, H W) arrays; with the
        renewal shot noise also each pixel's spike count (the threshold charges' counter)."""
        shape = (self.num_streams, self.camera.num_pixels)
        state = {"accumulator": np.asarray(self._acc.numpy(), dtype=self.dtype).reshape(shape),
                 "compensation": np.asarray(self._comp.numpy(), dtype=self.dtype).reshape(shape),
                 "fired": np.asarray(self._fired.numpy(), dtype=bool).reshape(shape)}
        if self.renewal:
            lo, hi = (np.asarray(c.numpy(), dtype=np.uint64).reshape(shape) for c in self._counts)
            state["spike_count"] = (hi << np.uint64(32)) | lo
        return state


__all__ = ["DrJitSensor", "DevicePacked", "InvalidFrames", "philox4x32", "philox_key", "WORD_STEPS"]
