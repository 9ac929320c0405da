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
from .streaming import TensorWindows
from .threads import set_cpu_threads


def reconstruct(spikes: Any, method: str = "lrrep", window: int = 41, threads: int = 0, chunk: int = 8,
                device: str = "cpu", height: int | None = None, width: int | None = None) -> np.ndarray:
    """Frames (M, H, W), float32 on the y scale (expected spikes per step), one per whole `window`-step
    window of `spikes`: a (steps, H, W) 0/1 array (NumPy or torch, row 0 at the top) or the path
    of a `.dat` stream (geometry from `height`/`width` or recorded beside it). `method` is any spec
    `evaluate` takes (lrrep, tfp, tfi, tfp:N, a checkpoint path, label=spec)."""
    if isinstance(spikes, (str, Path)):
        from spikesim.stream import DatReader, stream_geometry
        h, w, flip = stream_geometry(spikes, height, width, None)
        spikes = DatReader(spikes, h, w, flip=flip).read().unpack()
    s = torch.as_tensor(np.asarray(spikes) if not isinstance(spikes, torch.Tensor) else spikes)
    if s.dim() != 3:
        raise ValueError(f"spikes: expected (steps, H, W), got shape {tuple(s.shape)}")
    m = s.shape[0] // window
    if m < 1:
        raise ValueError(f"spikes: {s.shape[0]} steps hold no whole {window}-step window")
    set_cpu_threads(threads)
    chosen = method_from_spec(method, window, chunk, device)
    source = TensorWindows((s[: m * window] != 0).reshape(m, window, *s.shape[1:]))
    frames = [f for _, f in chosen.frames(source)]
    return torch.stack([torch.as_tensor(f) for f in frames]).float().numpy()


__all__ = ["reconstruct"]
