"""The simulator front end: validates frames, streams them through a backend in chunks, keeps
state between calls.

Frames arrive as an iterable (a generator from the renderer, or an array): the whole sequence is
never held in memory, only `chunk_steps` steps' worth of frames at a time. A frame is a NumPy
array, or a Dr.Jit array on the simulator's device (the renderer's output): those stay on the
device, and with `stream_packed` only the packed spike words leave it.

`Simulator` runs one stream; `BatchSimulator` runs several (scenes, seeds, RLLR samples) of one
camera model in the same kernel launches, so a small frame still fills a GPU. Each stream of a
batch is bit for bit the stream it would be alone.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

from .camera import SpikeCamera
from .errors import InvalidFrames
from .fixed_pattern import draw_pixel_parameters
from .keyframes import steps_covered
from .stream import DatWriter, SpikeStream, write_sidecar

log = logging.getLogger(__name__)

BACKENDS = ("auto", "numpy", "llvm", "cuda")


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
        raise ValueError(f"frame {index}: shape {arr.shape}, expected ({height}, {width}) for this camera; "
                         "a camera of another size is SpikeCamera.realistic(height=..., width=...)")
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


def _is_device_array(frame: Any) -> bool:
    """A Dr.Jit array (a flat Float or a TensorXf from the renderer), not a NumPy array."""
    return type(frame).__module__.startswith("drjit")


#: Bytes a frame buffer's rows are aligned to: a CPU vector load of a row then never straddles
#: two cache lines (the frame-per-step kernel ran 0.79-0.84x real time on NumPy's 16-byte
#: aligned frames, 1.00-1.03x on 64-byte aligned ones: docs/performance.md section 3c).
FRAME_ALIGNMENT = 64


def aligned_empty(shape: tuple[int, ...], dtype: Any = np.float32, alignment: int = FRAME_ALIGNMENT) -> np.ndarray:
    """An uninitialised C-ordered array whose first element sits on an `alignment`-byte boundary
    (NumPy only promises 16). Rows stay aligned where a row's bytes are a multiple of it (frames
    of a multiple of 16 pixels, in float32)."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    raw = np.empty(nbytes + alignment, dtype=np.uint8)
    start = (-raw.ctypes.data) % alignment
    return raw[start:start + nbytes].view(dtype).reshape(shape)


class _Frames:
    """Buffers up to `capacity` frames of S P values: NumPy rows in one reusable host buffer (no
    per-chunk allocation and page faults, which cost more than the kernel at 400 x 250,
    measured), or Dr.Jit arrays kept on their device as a list."""

    def __init__(self, capacity: int, width: int):
        self.capacity, self.width = capacity, width
        self._host = aligned_empty((capacity, width))
        self._device: list | None = None
        self.n = 0

    def append(self, row: Any) -> None:
        if _is_device_array(row):
            if self._device is None:
                if self.n:
                    raise ValueError("NumPy and Dr.Jit frames cannot be mixed in one stream")
                self._device = []
            self._device.append(row)
        else:
            if self._device is not None:
                raise ValueError("NumPy and Dr.Jit frames cannot be mixed in one stream")
            self._host[self.n] = row
        self.n += 1

    def block(self) -> Any:
        """The buffered frames: a NumPy (n, S P) view, or a list of n device arrays."""
        return self._host[: self.n] if self._device is None else list(self._device)

    def keep_last(self) -> None:
        """Drop all but the last frame (a keyframe both chunks need)."""
        if self._device is None:
            self._host[0] = self._host[self.n - 1]
        else:
            self._device = self._device[-1:]
        self.n = 1

    def clear(self) -> None:
        self.n = 0
        self._device = None


#: The fields a stream's sidecar records itself (`BatchSimulator._describe` and `run_to_dat`):
#: `extra` may not set them.
SIDECAR_FIELDS = frozenset({"camera", "seed", "backend", "height", "width", "spikesim_version", "num_steps", "flip",
                            "keyframe_every"})


def check_stream_outputs(paths: Sequence[str | Path], extra: dict[str, Any] | None,
                         reserved: frozenset[str] = SIDECAR_FIELDS) -> tuple[list[Path], dict[str, Any]]:
    """What a run_to_dat checks before it simulates, returning the paths and `extra`: `extra` sets none
    of the record's own fields (`reserved`: they overwrote the geometry, or failed after the .dat was
    replaced) and is plain JSON; each record's name holds nothing but an earlier stream's record
    (check_sidecar_slot); and no two outputs are one file: two streams at one path, or a stream at
    another's record name, lost a stream with no error (round twenty-two)."""
    from spikesim.config_io import standard_json
    from spikesim.stream import check_sidecar_slot, sidecar_path
    paths = [Path(p) for p in paths]
    extra = dict(extra or {})
    taken = sorted(set(extra) & reserved)
    if taken:
        raise ValueError(f"extra: {', '.join(taken)} {'is' if len(taken) == 1 else 'are'} the stream's own record "
                         f"({', '.join(sorted(reserved))}), not extra fields")
    try:
        standard_json(extra)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"extra: not plain JSON ({exc})") from None
    seen: dict[str, str] = {}
    for p in paths:
        check_sidecar_slot(p)
        for what, q in ((f"stream {p}", p), (f"record of {p}", sidecar_path(p))):
            where = os.path.realpath(q)  # one file by two spellings ("a/../b.dat", a linked folder) is one file
            if where in seen:
                raise ValueError(f"output paths collide: {q} would be both the {seen[where]} and the {what}; give "
                                 "each stream a path of its own")
            seen[where] = what
    return paths, extra


class BatchSimulator:
    """Turn irradiance frames (y, expected spikes per step) of S streams into S spike streams.

    Each stream has its own seed: its own fixed patterns, initial state and temporal noise, so
    every stream equals `Simulator(camera, seed=seeds[i])` on the same frames, bit for bit. A
    frame is (S, H, W) for NumPy input, or a Dr.Jit array of S H W values.

    State (accumulators, last spikes, temporal-noise counters, the last keyframe) carries over
    between calls, so simulating a stream in chunks gives exactly what one call gives.
    """

    def __init__(self, camera: SpikeCamera, seeds: Sequence[int], backend: str = "auto", chunk_steps: int = 256):
        if not isinstance(camera, SpikeCamera):  # Simulator("realistic") was an AttributeError from deep inside
            raise TypeError(f"camera: expected a SpikeCamera (e.g. SpikeCamera.preset({camera!r}) or "
                            f"SpikeCamera.realistic(height=..., width=...)), got {type(camera).__name__}")
        seeds = list(seeds)
        if not seeds:
            raise ValueError("a batch needs at least one seed")
        for s in seeds:
            if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
                raise ValueError(f"seed must be a non-negative integer, got {s!r}")
        if isinstance(chunk_steps, bool) or not isinstance(chunk_steps, (int, np.integer)) or chunk_steps <= 0:
            raise ValueError(f"chunk_steps must be a positive integer, got {chunk_steps!r}")
        self.camera = camera
        self.seeds = [int(s) for s in seeds]
        self.chunk_steps = int(chunk_steps)
        self.backend_name = resolve_backend(backend)
        params = [draw_pixel_parameters(camera, s) for s in self.seeds]
        self.pixel_parameters = params
        if self.backend_name == "numpy":
            from .sensor_numpy import NumpySensor
            self._numpy = [NumpySensor(camera, p, s) for p, s in zip(params, self.seeds)]
            self._sensor = None
        else:
            from .sensor_drjit import DrJitSensor
            self._numpy = None
            self._sensor = DrJitSensor(camera, params, self.seeds, backend=self.backend_name)
        self.steps_done = 0
        self._pending: Any = None            # keyframe mode: the last keyframe, not yet passed
        self._keyframe_every: int | None = None
        self._frames_seen = 0
        self._buf: _Frames | None = None
        self._pending_keyframe: tuple[int, Any] | None = None

    @property
    def num_streams(self) -> int:
        return len(self.seeds)

    @property
    def frame_values(self) -> int:
        """Values per frame: S streams of H W pixels."""
        return self.num_streams * self.camera.num_pixels

    # ---- public API -----------------------------------------------------------------------------
    def run(self, frames: Iterable[Any], keyframe_every: int = 1, final: bool = True,
            max_frames: int | None = None) -> list[SpikeStream]:
        """Simulate and return every stream whole, in host memory (bit-packed)."""
        parts = [p.to_numpy() for p in self.stream_packed(frames, keyframe_every, final, max_frames)]
        return [self._host_stream(np.concatenate([p[s] for p in parts]) if parts else None)
                for s in range(self.num_streams)]

    def stream_packed(self, frames: Iterable[Any], keyframe_every: int = 1, final: bool = True,
                      max_frames: int | None = None) -> Iterator[Any]:
        """Yield the packed spikes chunk by chunk as frames are consumed: objects with
        `.to_numpy()` (uint8 (S, n, bytes)) and, on Dr.Jit backends, `.to_torch()` (the words on
        the device, through DLPack). See `Simulator.stream` for the keyframe rules."""
        # run(0.3): "'float' object is not iterable" (np.ndim of a list would convert it whole)
        if isinstance(frames, (int, float, complex, np.generic)) or (isinstance(frames, np.ndarray)
                                                                     and frames.ndim == 0):
            raise TypeError(f"frames must be an (N, H, W) array or an iterable of (H, W) frames of luminance y, "
                            f"got {type(frames).__name__} {frames!r:.40}")
        # an integer, not a float that equals one (2.0 ran: round twenty) nor a bool
        if isinstance(keyframe_every, bool) or not isinstance(keyframe_every, (int, np.integer)) or keyframe_every < 1:
            raise ValueError(f"keyframe_every must be a positive integer, got {keyframe_every!r}")
        k = int(keyframe_every)
        if max_frames is not None and (isinstance(max_frames, bool) or not isinstance(max_frames, (int, np.integer))
                                       or max_frames < 0):
            raise ValueError(f"max_frames must be an integer >= 0 or None, got {max_frames!r}")
        if self._keyframe_every is not None and self._pending is not None and k != self._keyframe_every:
            raise ValueError(f"keyframe_every changed from {self._keyframe_every} to {k} in the middle of a stream")
        self._keyframe_every = k
        per_chunk = max(1, self.chunk_steps // k) + (1 if k > 1 else 0)
        if (isinstance(frames, np.ndarray) and frames.dtype == np.float32 and frames.flags.c_contiguous
                and self._pending is None and frames.ndim >= 3 and frames.shape[1:] == self._frame_shape()):
            yield from self._stream_array(frames[:max_frames], k, per_chunk, final)
            return
        if self._buf is None or self._buf.capacity < per_chunk:
            self._buf = _Frames(per_chunk, self.frame_values)
        buf = self._buf
        buf.clear()
        if self._pending is not None:
            buf.append(self._pending)
        checked = buf.n  # frames [0, checked) are validated
        count = 0
        if (isinstance(frames, np.ndarray) and frames.shape == self._frame_shape()) or _is_device_array(frames):
            frames = [frames]
        for frame in frames:
            if max_frames is not None and count >= max_frames:
                break
            buf.append(self._as_row(frame))
            self._frames_seen += 1
            count += 1
            if buf.n >= per_chunk:
                self._validate(buf, checked)
                yield from self._flush(buf.block(), k, keep_last=True)
                if k > 1:
                    buf.keep_last()
                    checked = 1
                else:
                    buf.clear()
                    checked = 0
        self._validate(buf, checked)
        if buf.n:
            block = buf.block()
            if k == 1:
                yield from self._flush(block, k, keep_last=False)
                self._pending = None
            else:
                yield from self._flush(block, k, keep_last=True)
                last = block[-1]
                self._pending = last.copy() if isinstance(last, np.ndarray) else last
                if final:
                    yield from self._flush(block[-1:], k, keep_last=False)
                    self._pending = None
        elif final:
            self._pending = None
        buf.clear()

    def stream_keyframes(self, keyframes: Iterable[tuple[int, Any]], final: bool = True) -> Iterator[Any]:
        """Adaptive temporal sampling: keyframes at arbitrary, increasing steps, as packed chunks.

        `keyframes` yields (step, frame); between two keyframes the sensor interpolates linearly,
        exactly as with a fixed `keyframe_every` equal to their distance (one compiled kernel
        serves every spacing). The first keyframe must be at the next step to simulate. Steps up
        to (not including) the last keyframe are emitted, and with `final=True` its own step too.
        """
        pending = self._pending_keyframe
        for step, frame in keyframes:
            step = int(step)
            row = self._as_row(frame)
            self._check_rows([row], self._frames_seen)
            self._frames_seen += 1
            if pending is None:
                if step != self.steps_done:
                    raise ValueError(f"first keyframe at step {step}, but the stream is at step {self.steps_done}")
            else:
                p_step, p_row = pending
                if step <= p_step:
                    raise ValueError(f"keyframe steps must increase: {step} after {p_step}")
                if step - p_step == 1:  # adjacent keyframes: the first is its step's own frame
                    yield from self._flush(self._block_of([p_row]), 1, keep_last=False)
                else:
                    yield from self._flush(self._block_of([p_row, row]), step - p_step, keep_last=True)
            pending = (step, row)
            self._pending_keyframe = pending
        if final and pending is not None:
            yield from self._flush(self._block_of([pending[1]]), 1, keep_last=False)
            self._pending_keyframe = None

    def run_to_dat(self, frames: Iterable[Any], paths: Sequence[str | Path], keyframe_every: int = 1,
                   flip: bool = True, max_frames: int | None = None, extra: dict[str, Any] | None = None,
                   max_steps: int | None = None) -> list[Path]:
        """Simulate straight to one `.dat` file (plus its JSON sidecar) per stream; memory stays
        one chunk. `max_steps` cuts the streams (keyframes may reach past the last wanted step)."""
        if len(paths) != self.num_streams:
            raise ValueError(f"{len(paths)} output paths for {self.num_streams} streams")
        paths, extra = check_stream_outputs(paths, extra)
        from spikesim.stream import sidecar_path
        cam = self.camera
        writers = [DatWriter(p, cam.height, cam.width, flip=flip) for p in paths]
        try:
            for part in self.stream_packed(frames, keyframe_every=keyframe_every, max_frames=max_frames):
                packed = part.to_numpy()
                n = packed.shape[1]
                if max_steps is not None:
                    n = min(n, max_steps - writers[0].num_steps)
                    if n <= 0:
                        break
                for s, writer in enumerate(writers):
                    writer.write(SpikeStream(packed[s, :n], cam.height, cam.width))
            for p in paths:  # an old record never stands beside a new stream: without one, readers ask for the size
                sidecar_path(p).unlink(missing_ok=True)
            written = [w.close() for w in writers]
        except BaseException:
            for w in writers:
                w.abort()
            raise
        for s, p in enumerate(written):
            write_sidecar(p, self._describe(s, num_steps=writers[s].num_steps, flip=flip,
                                            keyframe_every=keyframe_every, **extra))
        return written

    def describe(self, stream: int = 0, **extra: Any) -> dict[str, Any]:
        """Everything needed to reproduce stream `stream` bit for bit."""
        return self._describe(stream, **extra)

    def _describe(self, stream: int, **extra: Any) -> dict[str, Any]:
        import spikesim
        return {"camera": self.camera.to_dict(), "seed": self.seeds[stream], "backend": self.backend_name,
                "height": self.camera.height, "width": self.camera.width,
                "spikesim_version": spikesim.__version__, **extra}

    def get_state(self) -> dict[str, Any]:
        """Accumulators (and their compensation terms) and last-step spikes, (S, H W) arrays."""
        if self._numpy is not None:
            states = [s.get_state() for s in self._numpy]
            state = {k: np.stack([st[k] for st in states]) for k in states[0]}
        else:
            state = self._sensor.get_state()
        return {**state, "steps_done": self.steps_done}

    # ---- internals ------------------------------------------------------------------------------
    def _frame_shape(self) -> tuple[int, ...]:
        return (self.num_streams, self.camera.height, self.camera.width)

    def _host_stream(self, packed: np.ndarray | None) -> SpikeStream:
        cam = self.camera
        if packed is None:
            packed = np.zeros((0, (cam.num_pixels + 7) // 8), np.uint8)
        return SpikeStream(packed, cam.height, cam.width)

    def _as_row(self, frame: Any) -> Any:
        """A frame as one row of S P values: a NumPy view, or a flat device array."""
        if _is_device_array(frame):
            from ._drjit import dr
            flat = frame.array if dr.is_tensor_v(frame) else frame
            if dr.width(flat) != self.frame_values:
                raise ValueError(f"frame {self._frames_seen}: {dr.width(flat)} values, expected "
                                 f"{self.frame_values} ({self._frame_shape()})")
            if self._sensor is None:  # the NumPy reference reads device frames on the host
                return np.asarray(flat.numpy(), dtype=np.float32)
            return flat
        arr = np.asarray(frame)
        want = self._frame_shape()
        if arr.shape != want and len(want) == 3 and arr.ndim == 3 and arr.shape[1:] == want[1:]:
            # blamed the camera's size when the count of streams was what differed (round eight)
            raise ValueError(f"frame {self._frames_seen}: {arr.shape[0]} streams' frames of {want[1]} x {want[2]}, but "
                             f"this simulator makes {want[0]} streams (one per seed)")
        if arr.shape != want:
            raise ValueError(f"frame {self._frames_seen}: shape {arr.shape}, expected {self._frame_shape()} "
                             "for this camera; a camera of another size is --height/--width on the command line, "
                             "SpikeCamera.realistic(height=..., width=...) in Python")
        if np.issubdtype(arr.dtype, np.integer):
            # an 8-bit image (0..255) was taken as y = 200 spikes/step: a saturated stream, silently, while
            # `spikesim simulate` refuses such frames (round eleven; the library, round twelve)
            raise ValueError(f"frame {self._frames_seen}: dtype {arr.dtype}, but frames are float luminance, linear y "
                             "(expected spikes per step); an 8-bit or other integer image must be scaled to y (and "
                             "linearised, undoing its gamma) first, e.g. y = (img / 255.0) ** 2.2 * peak_y, or for "
                             "values that already are y, frames.astype(np.float32)")
        if not np.issubdtype(arr.dtype, np.floating):
            raise ValueError(f"frame {self._frames_seen}: dtype {arr.dtype} is not numeric; frames are float "
                             "luminance, linear y (expected spikes per step)")
        return arr.reshape(-1)

    def _block_of(self, rows: list) -> Any:
        if _is_device_array(rows[0]):
            return rows
        return np.stack([np.asarray(r, dtype=np.float32) for r in rows])

    def _validate(self, buf: _Frames, checked: int) -> None:
        """Frames past `checked` must be finite and >= 0. The Dr.Jit kernels check this
        themselves as they read each value (free), so only the NumPy backend pays here."""
        if self._sensor is None and buf.n > checked:
            self._check_rows(buf.block()[checked:], self._frames_seen - (buf.n - checked))

    def _check_rows(self, rows: Any, first_frame: int, force: bool = False) -> None:
        """Name the first bad frame (NaN, infinite, negative), for the NumPy backend or, with
        `force`, after a Dr.Jit kernel flagged one."""
        if self._sensor is not None and not force:
            return
        if not isinstance(rows, np.ndarray):
            rows = np.stack([np.asarray(r.numpy() if _is_device_array(r) else r, np.float32) for r in rows])
        lo, hi = (rows.min(), rows.max()) if rows.size else (0.0, 0.0)
        if np.isfinite(lo) and np.isfinite(hi) and lo >= 0:
            return
        h, w = self.camera.height, self.camera.width
        for i, row in enumerate(rows):
            for s, frame in enumerate(row.reshape(self.num_streams, h, w)):
                label = first_frame + i if self.num_streams == 1 else f"{first_frame + i} (stream {s})"
                check_frame(frame, label, h, w)

    def _stream_array(self, frames: np.ndarray, k: int, per_chunk: int, final: bool) -> Iterator[Any]:
        """Zero-copy path for frames already in memory: the kernel reads views of the array."""
        if frames.shape[0] == 0:  # no frames, no steps (reshape(0, -1) raised NumPy's own error, round eight)
            return
        flat = frames.reshape(frames.shape[0], -1)
        m = flat.shape[0]
        step = per_chunk if k == 1 else per_chunk - 1
        base = self._frames_seen
        for a in range(0, m, step):
            b = min(m, a + per_chunk)
            self._frames_seen = base + b
            if self._sensor is None:
                first = 0 if a == 0 or k == 1 else 1
                self._check_rows(flat[a + first:b], base + a + first)
            yield from self._flush(flat[a:b], k, keep_last=k > 1)
            if b == m:
                break
        if k > 1:
            self._pending = flat[m - 1].copy()
            if final:
                yield from self._flush(flat[m - 1:m], k, keep_last=False)
                self._pending = None

    def _flush(self, block: Any, k: int, keep_last: bool) -> Iterator[Any]:
        """Run the steps covered by `block` (m keyframes): (m - 1) k steps if keep_last (the last
        keyframe is still needed for the next segment), else every step up to and including the
        last frame."""
        m = block.shape[0] if isinstance(block, np.ndarray) else len(block)
        num = steps_covered(m, k, keep_last)
        if num == 0:
            return
        device_block = self._sensor.keyframe_block(block) if self._sensor is not None else None
        done = 0
        while done < num:
            n = min(num - done, self.chunk_steps)  # bounded memory per call
            # the keyframes this piece reads: from its first keyframe to the one after its last step
            j0 = done // k
            j1 = min(m - 1, (done + n - 1) // k + 1)
            try:
                if self._sensor is not None:
                    packed = self._sensor.run_device(device_block, j0, done - j0 * k, k, n, self.steps_done)
                else:
                    packed = _HostPacked(np.stack([
                        sensor.run(block[j0:j1 + 1, s * self.camera.num_pixels:(s + 1) * self.camera.num_pixels],
                                   phase=done - j0 * k, keyframe_every=k, num_steps=n, first_step=self.steps_done)
                        for s, sensor in enumerate(self._numpy)]))
            except InvalidFrames:
                self._check_rows(block, self._frames_seen - m, force=True)
                raise
            self.steps_done += n
            done += n
            yield packed


class _HostPacked:
    """The NumPy reference's output in the shape of the device's: uint8 (S, n, bytes)."""

    def __init__(self, packed: np.ndarray):
        self.packed = packed

    def to_numpy(self) -> np.ndarray:
        return self.packed

    def to_torch(self):
        import torch
        return torch.from_numpy(self.packed)


class Simulator(BatchSimulator):
    """Turn irradiance frames (y, expected spikes per step) into a spike stream.

    State (accumulators, last spikes, temporal-noise counters, the last keyframe) carries over
    between calls, so simulating a stream in chunks gives exactly what one call gives. Frames are
    (H, W) NumPy arrays, or Dr.Jit arrays of H W values on the simulator's device.
    """

    def __init__(self, camera: SpikeCamera, backend: str = "auto", seed: int = 0, chunk_steps: int = 256):
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        super().__init__(camera, [seed], backend=backend, chunk_steps=chunk_steps)

    @property
    def seed(self) -> int:
        return self.seeds[0]

    @property
    def params(self):
        """The pixel parameters (fixed patterns) drawn from the seed."""
        return self.pixel_parameters[0]

    def _frame_shape(self) -> tuple[int, ...]:
        return (self.camera.height, self.camera.width)

    def run(self, frames: Iterable[Any], keyframe_every: int = 1, final: bool = True,
            max_frames: int | None = None) -> SpikeStream:
        """Simulate and return the whole stream in memory (bit-packed)."""
        return super().run(frames, keyframe_every, final, max_frames)[0]

    def stream(self, frames: Iterable[Any], keyframe_every: int = 1, final: bool = True,
               max_frames: int | None = None) -> Iterator[SpikeStream]:
        """Yield the spike stream chunk by chunk as frames are consumed (host memory).

        With `keyframe_every=k`, frame j is the irradiance at step j*k and the sensor interpolates
        linearly in between; steps up to (not including) the last keyframe are emitted, and with
        `final=True` the last keyframe's own step too. Chunked calls pass `final=False` except for
        the last one, and then give the same stream as one call.
        """
        for part in self.stream_packed(frames, keyframe_every, final, max_frames):
            yield self._host_stream(part.to_numpy()[0])

    def stream_keyframes(self, keyframes: Iterable[tuple[int, Any]], final: bool = True) -> Iterator[SpikeStream]:
        for part in super().stream_keyframes(keyframes, final):
            yield self._host_stream(part.to_numpy()[0])

    def run_to_dat(self, frames: Iterable[Any], path: str | Path, keyframe_every: int = 1, flip: bool = True,
                   max_frames: int | None = None, extra: dict[str, Any] | None = None,
                   max_steps: int | None = None) -> Path:
        """Simulate straight to a `.dat` file (plus its JSON sidecar); memory stays one chunk.
        `max_steps` cuts the stream (keyframes may reach past the last wanted step)."""
        return super().run_to_dat(frames, [path], keyframe_every, flip, max_frames, extra, max_steps)[0]

    def describe(self, **extra: Any) -> dict[str, Any]:
        """Everything needed to reproduce the stream bit for bit."""
        return self._describe(0, **extra)

    def get_state(self) -> dict[str, Any]:
        state = super().get_state()
        return {k: (v[0] if isinstance(v, np.ndarray) else v) for k, v in state.items()}


def twin_camera(camera: SpikeCamera) -> SpikeCamera:
    """The noise-free twin of `camera`: every noise term off but the initial state. Its initial
    charge comes from the same seed's draws, as the same fraction of its (ideal) threshold as the
    camera's is of its own (fixed_pattern.draw_pixel_parameters), so the two streams start in the
    same phase and differ by the noise alone. SCSim writes such a pair for every stream."""
    from .camera import NOISE_TERMS
    return camera.without(*(t for t in NOISE_TERMS if t != "random_initial_state"))


class TwinSimulator:
    """A simulator and its noise-free twin (twin_camera) on the same frames: each frame is rendered
    once and simulated twice. Iterates the camera's stream parts; each twin part of the same steps
    goes to `on_twin` just before it. Quacks like the Simulator it wraps for the calls a scene job
    makes (stream, stream_keyframes, steps_done, backend_name, describe)."""

    def __init__(self, sim: Simulator, on_twin: Any) -> None:
        self.sim, self.on_twin = sim, on_twin
        self.twin = Simulator(twin_camera(sim.camera), backend=sim.backend_name, seed=sim.seed,
                              chunk_steps=sim.chunk_steps)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.sim, name)

    def _pair(self, ours: Iterator[Any], theirs: Iterator[Any]) -> Iterator[Any]:
        from itertools import zip_longest
        for part, twin_part in zip_longest(ours, theirs):
            if twin_part is not None:
                self.on_twin(twin_part)
            if part is not None:
                yield part

    def stream(self, frames: Iterable[Any], keyframe_every: int = 1, final: bool = True,
               max_frames: int | None = None) -> Iterator[SpikeStream]:
        from itertools import tee
        a, b = tee(frames)  # holds at most the frames one simulator is ahead by: one chunk
        return self._pair(self.sim.stream(a, keyframe_every, final, max_frames),
                          self.twin.stream(b, keyframe_every, final, max_frames))

    def stream_keyframes(self, keyframes: Iterable[tuple[int, Any]], final: bool = True) -> Iterator[SpikeStream]:
        from itertools import tee
        a, b = tee(keyframes)
        return self._pair(self.sim.stream_keyframes(a, final), self.twin.stream_keyframes(b, final))

    def run_to_dat(self, frames: Iterable[Any], path: str | Path, twin_path: str | Path, keyframe_every: int = 1,
                   flip: bool = True, extra: dict[str, Any] | None = None,
                   max_steps: int | None = None) -> tuple[Path, Path]:
        """Both streams straight to `.dat` files with their sidecars (each sidecar names its camera,
        the twin's also the stream it is the twin of); memory stays one chunk."""
        # as BatchSimulator.run_to_dat, before simulating; the twin's record has two fields of its own
        # (the geometry from `extra`, and errors after both streams were replaced: round twenty-two)
        (path, twin_path), extra = check_stream_outputs([path, twin_path], extra, SIDECAR_FIELDS | {"twin", "twin_of"})
        from spikesim.stream import sidecar_path
        cam = self.sim.camera
        ours, theirs = (DatWriter(p, cam.height, cam.width, flip=flip) for p in (path, twin_path))

        def cut(writer: DatWriter, part: SpikeStream) -> None:
            n = part.num_steps if max_steps is None else min(part.num_steps, max_steps - writer.num_steps)
            if n > 0:
                writer.write(part.slice(0, n))
        try:
            self.on_twin = lambda part: cut(theirs, part)
            for part in self.stream(frames, keyframe_every=keyframe_every):
                cut(ours, part)
                if max_steps is not None and ours.num_steps >= max_steps and theirs.num_steps >= max_steps:
                    break
            for p in (path, twin_path):  # an old record never stands beside a new stream
                sidecar_path(p).unlink(missing_ok=True)
            written = ours.close(), theirs.close()
        except BaseException:
            ours.abort()
            theirs.abort()
            raise
        common = {"flip": flip, "keyframe_every": keyframe_every, **(extra or {})}
        write_sidecar(written[0], self.sim.describe(num_steps=ours.num_steps, twin=written[1].name, **common))
        write_sidecar(written[1], self.twin.describe(num_steps=theirs.num_steps, twin_of=written[0].name, **common))
        return written


def simulate(frames: Iterable[Any], camera: SpikeCamera | None = None, backend: str = "auto", seed: int = 0,
             keyframe_every: int = 1) -> SpikeStream:
    """One-call convenience: frames -> spike stream."""
    return Simulator(camera or SpikeCamera(), backend=backend, seed=seed).run(frames, keyframe_every=keyframe_every)


__all__ = ["Simulator", "BatchSimulator", "TwinSimulator", "twin_camera", "simulate", "available_backends", "resolve_backend", "check_frame",
           "BACKENDS"]
