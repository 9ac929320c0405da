"""The simulator front end: validates frames, streams them through a backend in chunks, keeps
state between calls.

Frames arrive as an iterable (a generator from the renderer, or an array): the whole sequence is
never held in memory, only `chunk_steps` frames at a time.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from .camera import SpikeCamera
from .fixed_pattern import draw_pixel_parameters
from .stream import DatWriter, SpikeStream, write_sidecar

log = logging.getLogger(__name__)

BACKENDS = ("auto", "numpy", "llvm", "cuda")
_STEP_WORD = 1 << 32  # the Dr.Jit kernels count steps in 32-bit halves


def available_backends() -> list[str]:
    from ._drjit import has_cuda, has_llvm
    out = ["numpy"]
    if has_llvm():
        out.append("llvm")
    if has_cuda():
        out.append("cuda")
    return out


def resolve_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {BACKENDS}")
    avail = available_backends()
    if backend == "auto":
        for b in ("cuda", "llvm", "numpy"):
            if b in avail:
                if b == "numpy":
                    log.warning("no Dr.Jit backend available (libLLVM >= 17 missing?); using the NumPy reference")
                return b
    if backend not in avail:
        from .errors import UnavailableError
        hint = " (no CUDA GPU or driver found)" if backend == "cuda" else " (libLLVM >= 17 missing?)"
        raise UnavailableError(f"backend {backend!r} is not available on this machine{hint}; available: {avail}")
    return backend


def check_frame(frame: Any, index: int, height: int, width: int) -> np.ndarray:
    """A (H, W) float32 array of y >= 0, or a ValueError naming the frame and the problem."""
    arr = np.asarray(frame)
    if arr.shape != (height, width):
        raise ValueError(f"frame {index}: shape {arr.shape}, expected ({height}, {width}) for this camera")
    if not np.issubdtype(arr.dtype, np.floating) and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"frame {index}: dtype {arr.dtype} is not numeric")
    arr = arr.astype(np.float32, copy=False)
    finite = np.isfinite(arr)
    if not finite.all():
        nan = int(np.isnan(arr).sum())
        inf = int((~finite).sum()) - nan
        raise ValueError(f"frame {index}: {nan} NaN and {inf} infinite pixel(s); irradiance must be finite")
    if arr.size and arr.min() < 0:
        raise ValueError(f"frame {index}: {int((arr < 0).sum())} negative pixel(s) (min {arr.min():.3g}); "
                         "irradiance y (spikes per step) must be >= 0")
    return arr


class Simulator:
    """Turn irradiance frames (y, expected spikes per step) into a spike stream.

    State (accumulators, last spikes, temporal-noise counters, the last keyframe) carries over
    between calls, so simulating a stream in chunks gives exactly what one call gives.
    """

    def __init__(self, camera: SpikeCamera, backend: str = "auto", seed: int = 0, chunk_steps: int = 256):
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        if chunk_steps <= 0:
            raise ValueError(f"chunk_steps must be positive, got {chunk_steps}")
        self.camera = camera
        self.seed = int(seed)
        self.chunk_steps = int(chunk_steps)
        self.backend_name = resolve_backend(backend)
        self.params = draw_pixel_parameters(camera, self.seed)
        if self.backend_name == "numpy":
            from .sensor_numpy import NumpySensor
            self._sensor = NumpySensor(camera, self.params, self.seed)
        else:
            from .sensor_drjit import DrJitSensor
            self._sensor = DrJitSensor(camera, self.params, self.seed, backend=self.backend_name)
        self.steps_done = 0
        self._pending: np.ndarray | None = None  # keyframe mode: the last keyframe, not yet passed
        self._keyframe_every: int | None = None
        self._frames_seen = 0
        self._buf: np.ndarray | None = None
        self._pending_keyframe: tuple[int, np.ndarray] | None = None

    # ---- public API -----------------------------------------------------------------------------
    def run(self, frames: Iterable[Any], keyframe_every: int = 1, final: bool = True,
            max_frames: int | None = None) -> SpikeStream:
        """Simulate and return the whole stream in memory (bit-packed)."""
        parts = list(self.stream(frames, keyframe_every=keyframe_every, final=final, max_frames=max_frames))
        if not parts:
            nb = (self.camera.num_pixels + 7) // 8
            return SpikeStream(np.zeros((0, nb), np.uint8), self.camera.height, self.camera.width)
        return SpikeStream.concatenate(parts)

    def run_to_dat(self, frames: Iterable[Any], path: str | Path, keyframe_every: int = 1, flip: bool = True,
                   max_frames: int | None = None, extra: dict[str, Any] | None = None,
                   max_steps: int | None = None) -> Path:
        """Simulate straight to a `.dat` file (plus its JSON sidecar); memory stays one chunk.
        `max_steps` cuts the stream (keyframes may reach past the last wanted step)."""
        cam = self.camera
        with DatWriter(path, cam.height, cam.width, flip=flip) as writer:
            for part in self.stream(frames, keyframe_every=keyframe_every, final=True, max_frames=max_frames):
                if max_steps is not None:
                    part = part.slice(0, max(0, max_steps - writer.num_steps))
                    if part.num_steps == 0:
                        break
                writer.write(part)
            n = writer.num_steps
        write_sidecar(path, self.describe(num_steps=n, flip=flip, keyframe_every=keyframe_every, **(extra or {})))
        return Path(path)

    def stream(self, frames: Iterable[Any], keyframe_every: int = 1, final: bool = True,
               max_frames: int | None = None) -> Iterator[SpikeStream]:
        """Yield the spike stream chunk by chunk as frames are consumed.

        With `keyframe_every=k`, frame j is the irradiance at step j*k and the sensor interpolates
        linearly in between; steps up to (not including) the last keyframe are emitted, and with
        `final=True` the last keyframe's own step too. Chunked calls pass `final=False` except for
        the last one, and then give the same stream as one call.
        """
        k = int(keyframe_every)
        if k < 1:
            raise ValueError(f"keyframe_every must be >= 1, got {keyframe_every}")
        if self._keyframe_every is not None and self._pending is not None and k != self._keyframe_every:
            raise ValueError(f"keyframe_every changed from {self._keyframe_every} to {k} in the middle of a stream")
        self._keyframe_every = k
        cam = self.camera
        per_chunk = max(1, self.chunk_steps // k) + (1 if k > 1 else 0)
        if (isinstance(frames, np.ndarray) and frames.ndim == 3 and frames.dtype == np.float32
                and frames.flags.c_contiguous and self._pending is None and frames.shape[1:] == (cam.height, cam.width)):
            yield from self._stream_array(frames[:max_frames], k, per_chunk, final)
            return
        # One reusable buffer: frames are copied in as they arrive (no per-chunk allocation and
        # page faults, which cost more than the kernel itself at 400x250, measured).
        if self._buf is None or self._buf.shape[0] < per_chunk:
            self._buf = np.empty((per_chunk, cam.num_pixels), dtype=np.float32)
        buf = self._buf
        n = 0
        if self._pending is not None:
            buf[0] = self._pending
            n = 1
        checked = n  # rows [0, checked) are validated
        count = 0
        if isinstance(frames, np.ndarray) and frames.ndim == 2:
            frames = [frames]
        for frame in frames:
            if max_frames is not None and count >= max_frames:
                break
            arr = np.asarray(frame)
            if arr.shape != (cam.height, cam.width):
                raise ValueError(f"frame {self._frames_seen}: shape {arr.shape}, expected "
                                 f"({cam.height}, {cam.width}) for this camera")
            if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
                raise ValueError(f"frame {self._frames_seen}: dtype {arr.dtype} is not numeric")
            buf[n] = arr.reshape(-1)
            n += 1
            self._frames_seen += 1
            count += 1
            if n >= per_chunk:
                self._validate(buf, checked, n)
                yield from self._flush(buf[:n], k, keep_last=True)
                if k > 1:
                    buf[0] = buf[n - 1]
                    n = checked = 1
                else:
                    n = checked = 0
        self._validate(buf, checked, n)
        if n:
            if k == 1:
                yield from self._flush(buf[:n], k, keep_last=False)
                self._pending = None
            else:
                yield from self._flush(buf[:n], k, keep_last=True)
                self._pending = buf[n - 1].copy()
                if final:
                    yield from self._flush(buf[n - 1:n], k, keep_last=False)
                    self._pending = None
        elif final:
            self._pending = None

    def _stream_array(self, frames: np.ndarray, k: int, per_chunk: int, final: bool) -> Iterator[SpikeStream]:
        """Zero-copy path for frames already in memory: the kernel reads views of the array."""
        flat = frames.reshape(frames.shape[0], -1)
        m = flat.shape[0]
        if m == 0:
            return
        step = per_chunk if k == 1 else per_chunk - 1
        base = self._frames_seen
        for a in range(0, m, step):
            b = min(m, a + per_chunk)
            last = b == m
            self._frames_seen = base + b
            self._validate(flat[a:b], 0, b - a) if a == 0 or k == 1 else self._validate(flat[a:b], 1, b - a)
            if k == 1:
                yield from self._flush(flat[a:b], k, keep_last=False)
            else:
                yield from self._flush(flat[a:b], k, keep_last=True)
            if last:
                break
        if k > 1:
            self._pending = flat[m - 1].copy()
            if final:
                yield from self._flush(flat[m - 1:m], k, keep_last=False)
                self._pending = None

    def _validate(self, buf: np.ndarray, a: int, b: int, force: bool = False) -> None:
        """Rows [a, b) must be finite and >= 0. The Dr.Jit kernels check this themselves as
        they read each value (free), so only the NumPy backend pays two reductions here; the
        per-frame search that names the culprit runs only on failure."""
        if b <= a or (self.backend_name != "numpy" and not force):
            return
        block = buf[a:b]
        lo, hi = block.min(), block.max()
        if np.isfinite(lo) and np.isfinite(hi) and lo >= 0:
            return
        first_frame = self._frames_seen - (b - a)
        for i in range(b - a):
            check_frame(block[i].reshape(self.camera.height, self.camera.width), first_frame + i,
                        self.camera.height, self.camera.width)

    def stream_keyframes(self, keyframes: Iterable[tuple[int, Any]], final: bool = True) -> Iterator[SpikeStream]:
        """Adaptive temporal sampling: keyframes at arbitrary, increasing steps.

        `keyframes` yields (step, frame); between two keyframes the sensor interpolates linearly,
        exactly as with a fixed `keyframe_every` equal to their distance (one compiled kernel
        serves every spacing). The first keyframe must be at the next step to simulate. Steps up
        to (not including) the last keyframe are emitted, and with `final=True` its own step too.
        """
        cam = self.camera
        pending = self._pending_keyframe
        for step, frame in keyframes:
            step = int(step)
            arr = check_frame(frame, self._frames_seen, cam.height, cam.width).reshape(1, -1)
            self._frames_seen += 1
            if pending is None:
                if step != self.steps_done:
                    raise ValueError(f"first keyframe at step {step}, but the stream is at step {self.steps_done}")
            else:
                p_step, p_frame = pending
                if step <= p_step:
                    raise ValueError(f"keyframe steps must increase: {step} after {p_step}")
                if step - p_step == 1:  # adjacent keyframes: the first is its step's own frame
                    yield from self._flush(p_frame, 1, keep_last=False)
                else:
                    yield from self._flush(np.concatenate([p_frame, arr]), step - p_step, keep_last=True)
            pending = (step, arr)
            self._pending_keyframe = pending
        if final and pending is not None:
            yield from self._flush(pending[1], 1, keep_last=False)
            self._pending_keyframe = None

    def describe(self, **extra: Any) -> dict[str, Any]:
        """Everything needed to reproduce a stream bit for bit."""
        import spikesim
        return {"camera": self.camera.to_dict(), "seed": self.seed, "backend": self.backend_name,
                "height": self.camera.height, "width": self.camera.width,
                "spikesim_version": spikesim.__version__, **extra}

    def get_state(self) -> dict[str, Any]:
        return {**self._sensor.get_state(), "steps_done": self.steps_done}

    # ---- internals ------------------------------------------------------------------------------
    def _flush(self, keyframes: np.ndarray, k: int, keep_last: bool) -> Iterator[SpikeStream]:
        """Run the steps covered by `buf`: (len-1)*k steps if keep_last (the last keyframe is
        still needed for the next segment), else every step up to and including the last frame."""
        m = keyframes.shape[0]
        num = m if k == 1 else ((m - 1) * k if keep_last else (m - 1) * k + 1)
        if num == 0:
            return
        done = 0
        while done < num:
            step = self.steps_done
            # bounded memory per kernel call, and never straddle a 2^32-step boundary
            n = min(num - done, self.chunk_steps, _STEP_WORD - step % _STEP_WORD)
            # the keyframes this piece reads: from its first keyframe to the one after its last step
            j0 = done // k
            j1 = min(m - 1, (done + n - 1) // k + 1)
            try:
                packed = self._sensor.run(keyframes[j0:j1 + 1], phase=done - j0 * k, keyframe_every=k,
                                          num_steps=n, first_step=step)
            except ValueError as exc:
                if type(exc).__name__ != "InvalidFrames":
                    raise
                self._validate(keyframes, 0, m, force=True)
                raise
            self.steps_done += n
            done += n
            yield SpikeStream(packed, self.camera.height, self.camera.width)


def simulate(frames: Iterable[Any], camera: SpikeCamera | None = None, backend: str = "auto", seed: int = 0,
             keyframe_every: int = 1) -> SpikeStream:
    """One-call convenience: frames -> spike stream."""
    return Simulator(camera or SpikeCamera(), backend=backend, seed=seed).run(frames, keyframe_every=keyframe_every)


__all__ = ["Simulator", "simulate", "available_backends", "resolve_backend", "check_frame", "BACKENDS"]
