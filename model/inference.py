"""Reconstruct a spike stream from Python, as `spikesim reconstruct` does from the command line.

    import model
    frames = model.reconstruct(spikes)                      # the shipped network, every whole window
    frames = model.reconstruct(spikes, method="tfp")        # or any method evaluate takes
    frames = model.reconstruct("recording.dat", method="runs/mine/best.pt")

The torch thread count is chosen as the commands choose it (model.threads.set_cpu_threads: the
free cores, from the load average), unless `threads` says otherwise: torch's own default of one
thread per core stalls on a shared machine (7.5 s instead of 0.5 s for a frame, measured).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from .methods import method_from_spec
from .streaming import StepWindows, TensorWindows
from .threads import set_cpu_threads


def check_spike_array(spikes: Any) -> torch.Tensor:
    """A spike stream as a bool tensor (steps, H, W): a spike array is bool or holds only 0 and 1.
    Anything else (NaN, 0.3, 255, -1, complex numbers, an empty frame) is a ValueError that says
    what it holds, never a plausible-looking reconstruction of it. A `spikesim.stream.SpikeStream`
    is unpacked (it was refused as "dtype object", round twelve)."""
    from spikesim.stream import SpikeStream
    if isinstance(spikes, SpikeStream):
        spikes = spikes.unpack()
    if isinstance(spikes, torch.Tensor):
        s = spikes.detach().cpu()
    else:
        try:
            arr = np.asarray(spikes)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"spikes: not an array ({exc})") from None
        if arr.dtype == object or arr.dtype.kind in "USV":
            raise ValueError(f"spikes: expected a 0/1 or bool array, got dtype {arr.dtype}")
        arr = np.ascontiguousarray(arr)  # a flipped view (np.flip, [:, ::-1]) has negative strides torch refuses
        s = torch.as_tensor(arr.view(np.uint8) if arr.dtype == np.bool_ else arr)
        if arr.dtype == np.bool_:
            s = s.bool()
    if s.dim() != 3:
        raise ValueError(f"spikes: expected (steps, H, W), got shape {tuple(s.shape)}")
    if min(s.shape) == 0:
        raise ValueError(f"spikes: every side must hold at least one step or pixel, got shape {tuple(s.shape)}")
    if s.dtype == torch.bool:
        return s
    if s.is_complex():
        raise ValueError(f"spikes: expected a 0/1 or bool array, got complex values ({s.dtype})")
    bad = ~((s == 0) | (s == 1))
    if bool(bad.any()):
        first = s[bad][0].item()
        raise ValueError(f"spikes: a spike array holds only 0 and 1 (or is bool); this one holds {first!r} "
                         f"({int(bad.sum())} value(s) that are neither, dtype {s.dtype})")
    return s != 0


def _check_reader_args(**given: Any) -> None:
    """The keyword arguments' types, each named: `flip="false"` was taken as True (a non-empty
    string), `height=0` as "not given", `chunk="x"` as a TypeError from deep inside (issue 40,
    round 5)."""
    for name in ("flip", "drop_partial"):
        v = given[name]
        if v is not None and not isinstance(v, (bool, np.bool_)):
            raise ValueError(f"{name}: expected True, False or None, got {v!r}")
    for name in ("height", "width"):
        v = given[name]
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1):
            raise ValueError(f"{name}: expected a positive number of pixels or None, got {v!r}")
    for name, low in (("threads", 0), ("chunk", 1)):
        v = given[name]
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
            raise ValueError(f"{name}: expected an integer >= {low}, got {v!r}")


def reconstruct(spikes: Any, method: str = "lrrep", window: int = 41, threads: int = 0, chunk: int = 8,
                device: str = "cpu", height: int | None = None, width: int | None = None,
                header_columns: int | str | None = "auto", flip: bool | None = None,
                drop_partial: bool = False, horizon: int | str = "trained",
                horizon_stride: int | None = None) -> np.ndarray:
    """Frames (M, H, W), float32 on the y scale (expected spikes per step), one per whole `window`-step
    window of `spikes`: a (steps, H, W) 0/1 array (NumPy or torch, row 0 at the top), a
    `spikesim.stream.SpikeStream` (what `DatReader.read` returns), a `DatReader`, or the path
    of a `.dat` stream, read as `spikesim reconstruct` reads one, a few windows at a time (memory
    bounded by `chunk`, or a network's by its horizon's piece, not by the file):
    `height`/`width`/`flip` as recorded beside it unless given (else 250 x 400, rows bottom-up), `header_columns` detected unless given,
    `drop_partial` for a file cut off mid-frame. `method` is any spec
    `evaluate` takes (lrrep, tfp, tfi, tfp:N, a checkpoint path, label=spec). `device` (cpu, cuda,
    cuda:N, mps, auto) is checked for every method, a device this machine lacks refused naming it;
    the window averages (tfp, tfi, tfp:N) compute on the CPU whatever it is. A network runs over a
    long stream in pieces of its training horizon (`horizon` "trained"), of `horizon` windows, or
    over the whole stream at once ("all"); `horizon_stride` frames are taken from each piece
    (model.methods.ModelMethod)."""
    _check_reader_args(height=height, width=width, flip=flip, drop_partial=drop_partial, threads=threads, chunk=chunk)
    if isinstance(method, Path):  # the README says "a checkpoint path": a pathlib.Path is one (round eight)
        method = str(method)
    if not isinstance(method, str) or not method.strip():
        raise ValueError(f"method: expected a method spec (lrrep, tfp, tfi, tfp:N, a checkpoint path), got {method!r}")
    if isinstance(window, np.integer) and not isinstance(window, np.bool_):
        window = int(window)  # as height=np.int64(16) is taken (round twelve)
    from spikesim.stream import DatReader, SpikeStream
    if isinstance(spikes, (str, Path)):
        from spikesim.stream import open_stream  # what `reconstruct FILE.dat` takes, with the same defaults
        spikes, _ = open_stream(Path(spikes), height, width, flip, header_columns, drop_partial)
    else:  # an array (or a SpikeStream, a DatReader) carries its own size and orientation: what only a
        # file needs is refused, not ignored
        for name, value, default in (("flip", flip, None), ("header_columns", header_columns, "auto"),
                                     ("drop_partial", drop_partial, False)):
            if value != default:
                raise ValueError(f"{name}: applies to a .dat path; an array is read as it is (row 0 at the top)")
    if isinstance(spikes, (DatReader, SpikeStream)):
        # read window by window, as `spikesim reconstruct` reads a file (model.streaming.StepWindows): the
        # whole stream unpacked, then copied, held 3.6 GB for a 40 MB file (round twelve); a SpikeStream
        # (DatReader.read) was refused as "dtype object"
        stream = spikes
        steps, h, w = len(stream), stream.height, stream.width
        if isinstance(stream, DatReader):
            read_steps = lambda a, b: stream.read(a, b).unpack()  # noqa: E731  (pipelines/reconstruct.py's reader)
        else:
            read_steps = stream.unpack
    else:
        s = check_spike_array(spikes)
        steps, h, w = s.shape
    if min(steps, h, w) == 0:
        raise ValueError(f"spikes: every side must hold at least one step or pixel, got shape {(steps, h, w)}")
    for name, value, got in (("height", height, h), ("width", width, w)):
        if value is not None and value != got:
            raise ValueError(f"{name}={value}, but the array's frames are {h} x {w}")
    if not (isinstance(window, int) and not isinstance(window, bool) and window >= 1 and window % 2 == 1):
        raise ValueError(f"window: expected an odd number of steps >= 1 (41 for the shipped networks), got {window!r}")
    m = steps // window
    if m < 1:
        raise ValueError(f"spikes: {steps} steps hold no whole {window}-step window")
    from .training import resolve_device
    device = str(resolve_device(device, "device"))  # "mps" blamed the weights and "gpu" raised torch's own error
    set_cpu_threads(threads)
    chosen = method_from_spec(method, window, chunk, device, horizon, horizon_stride)
    if isinstance(spikes, (DatReader, SpikeStream)):
        source: Any = StepWindows(read_steps, 0, window, m)
    else:
        source = TensorWindows((s[: m * window] != 0).reshape(m, window, *s.shape[1:]))
    out: np.ndarray | None = None
    made = 0
    for i, f in chosen.frames(source):
        frame = torch.as_tensor(f).float().numpy()
        if out is None:  # filled in place: a list of frames, then a stacked copy, held the frames twice
            out = np.empty((m, *frame.shape), np.float32)
        out[i] = frame
        made = max(made, i + 1)
    assert out is not None
    return out[:made] if made < m else out

__all__ = ["reconstruct", "check_spike_array"]
