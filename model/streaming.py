"""Inference over long streams with memory bounded: horizon inference (the default) and exact
one-shot streaming.

Horizon inference (horizon_reconstruct). The network was trained on sequences of K windows; run
over a whole stream of M > K windows its recurrence goes on for M windows, which it never saw, and
in the dark that drifts (docs/model.md, "Horizon inference": one run lost 5.3 dB on a 0.38-lx scene
over 9 windows that it kept over 5). So by default each frame comes from the network run on a piece
of K windows on its own, as in training, pieces overlapping by K - stride windows.

One-shot streaming (stream_reconstruct, horizon "all"). Definition. For a stream cut into M
consecutive windows, the output for window i is exactly the one-shot output of the network on
all M windows (model(spikes of the M windows)): forward state and last-spike times from window
0, backward state and next-spike times from window M-1, GISI sentinels -1 (before the first
window's first step) and M*T (after the last window's last step).
The bidirectional recurrence makes the backward half depend on everything later, so it is
computed in two passes over the stream, each holding one chunk of C windows:

  pass 0 (only with GISI, cheap): forward scan of spike times; keeps the last-spike map at every
          chunk start.
  pass 1 (backward, chunks M/C-1 .. 1): computes the backward recurrent state and the
          next-spike map entering each chunk from the right, and keeps only those.
  pass 2 (forward, chunks 0 .. M/C-1): per chunk, re-runs the backward recurrence from the kept
          state (C windows of features in memory), runs the forward recurrence carried from the
          previous chunk, decodes and yields the C frames.

Kept boundary states (one feature map and two int64 maps per chunk) go to a temporary directory
on disk, so memory is O(C) and disk O(M / C). The price is one extra encode + backward pass
(about 1.6x the one-shot work). With M <= C it is the one-shot computation.

The re-implemented published networks (model/published_nets) need less: a per-window network
(Spk2ImgNet, WGSE, SSML) maps each chunk's windows on their own, and a forward-only recurrent
one (RSIR) carries its hidden state from chunk to chunk; one pass, memory O(C), nothing on disk.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Protocol

import numpy as np
import torch

from .arch import ReconNet
from .published_nets.common import PublishedNet
from .representations import LastSpike, NextSpike, forward_spike_times


class WindowSource(Protocol):
    """M consecutive windows of T steps of one stream, read on demand."""

    num_windows: int
    window: int
    first_step: int  # absolute step of window 0's first step

    def windows(self, start: int, stop: int) -> torch.Tensor:
        """bool (stop - start, T, H, W) for windows [start, stop)."""
        ...


@dataclass
class TensorWindows:
    """Windows held in memory: spikes (M, T, H, W)."""

    spikes: torch.Tensor
    first_step: int = 0

    def __post_init__(self) -> None:
        if self.spikes.dim() != 4:
            raise ValueError(f"TensorWindows needs (M, T, H, W), got {tuple(self.spikes.shape)}")
        self.num_windows, self.window = int(self.spikes.shape[0]), int(self.spikes.shape[1])

    def windows(self, start: int, stop: int) -> torch.Tensor:
        return self.spikes[start:stop] != 0


class StepWindows:
    """Windows cut from a step reader, e.g. SceneRecord.spikes or a DatReader.

    read_steps(start, stop) -> bool (stop - start, H, W). Window i covers steps
    [first_step + i*T, first_step + (i+1)*T).
    """

    def __init__(self, read_steps: Callable[[int, int], np.ndarray | torch.Tensor], first_step: int,
                 window: int, num_windows: int) -> None:
        if window < 1 or num_windows < 1 or first_step < 0:
            raise ValueError(f"StepWindows: need window >= 1, num_windows >= 1, first_step >= 0; got "
                             f"window={window}, num_windows={num_windows}, first_step={first_step}")
        self.read_steps, self.first_step = read_steps, first_step
        self.window, self.num_windows = window, num_windows

    def windows(self, start: int, stop: int) -> torch.Tensor:
        a = self.first_step + start * self.window
        b = self.first_step + stop * self.window
        steps = torch.as_tensor(np.asarray(self.read_steps(a, b)))
        if steps.shape[0] != b - a:
            raise ValueError(f"reader returned {steps.shape[0]} steps for [{a}, {b})")
        return (steps != 0).reshape((stop - start, self.window) + tuple(steps.shape[1:]))


class _DiskStore:
    """Boundary states kept on disk, one file per key."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def put(self, key: str, value: torch.Tensor | None) -> None:
        torch.save(None if value is None else value.cpu(), self.root / f"{key}.pt")

    def get(self, key: str, device: torch.device) -> torch.Tensor | None:
        v = torch.load(self.root / f"{key}.pt", weights_only=True)
        return None if v is None else v.to(device)


@torch.no_grad()
def stream_reconstruct(model: ReconNet | PublishedNet, source: WindowSource, chunk: int = 8,
                       device: torch.device | str = "cpu",
                       spill_dir: str | Path | None = None) -> Iterator[tuple[int, torch.Tensor]]:
    """Yield (window index, reconstruction float32 (H, W) on the CPU) for every window, in order.

    Equal to model(all M windows) up to float rounding; see the module docstring.
    """
    if chunk < 1:
        raise ValueError(f"chunk must be >= 1, got {chunk}")
    if source.window != model.cfg.window:
        raise ValueError(f"source windows have {source.window} steps, model expects {model.cfg.window}")
    device = torch.device(device)
    model.eval()
    if isinstance(model, PublishedNet):
        yield from _stream_published(model, source, chunk, device)
        return
    m, t = source.num_windows, source.window
    starts = list(range(0, m, chunk))
    gisi_carry = model.cfg.carries_spike_times
    adf = model.cfg.adf

    def load(c: int) -> tuple[torch.Tensor, int]:
        a = starts[c]
        b = min(a + chunk, m)
        return source.windows(a, b).to(device).unsqueeze(0), source.first_step + a * t

    def encode(spk: torch.Tensor, maps: torch.Tensor | None) -> torch.Tensor:
        n = spk.shape[1]
        x = model.pad(spk[0].to(torch.float32))
        mp = None if maps is None else model.pad(maps[0])
        return model.encode(x, mp).reshape(n, 1, -1, *x.shape[-2:])

    with tempfile.TemporaryDirectory(dir=spill_dir, prefix="stream-") as tmp:
        store = _DiskStore(Path(tmp))
        probe = source.windows(0, 1)
        h, w = probe.shape[-2:]
        end_step = source.first_step + m * t

        # pass 0: last-spike maps entering each chunk (GISI's forward carry).
        if gisi_carry:
            last = LastSpike.never((1, h, w), source.first_step, device)
            for c in range(len(starts)):
                store.put(f"last{c}", last.steps)
                spk, first = load(c)
                _, last = forward_spike_times(spk, first, last)

        # pass 1: backward state and next-spike map entering each chunk from its right.
        nxt = NextSpike.never((1, h, w), end_step, device)
        state_b: torch.Tensor | None = None
        for c in range(len(starts) - 1, -1, -1):
            store.put(f"next{c}", nxt.steps if gisi_carry else None)
            store.put(f"bstate{c}", state_b)
            if c == 0 or not (gisi_carry or adf):
                continue
            spk, first = load(c)
            last_c = LastSpike(store.get(f"last{c}", device)) if gisi_carry else None
            maps, _, nxt = model.input_maps(spk, first, last_c, nxt)
            if adf:
                feats = encode(spk, maps)
                for i in range(feats.shape[0] - 1, -1, -1):
                    state_b = model.step(feats[i], state_b, backward=True)

        # pass 2: forward, re-running the backward recurrence within each chunk.
        last = LastSpike.never((1, h, w), source.first_step, device) if gisi_carry else None
        state_f: torch.Tensor | None = None
        span = model.cfg.refine_span
        rates: dict[int, torch.Tensor] = {}  # padded per-window rates, for the span's mean (refine_span)

        def window_rates(a: int, b: int, spk: torch.Tensor | None = None) -> None:
            """Rates of windows [a, b) not yet kept; `spk` holds them when already read."""
            missing = [j for j in range(a, b) if j not in rates]
            if missing and spk is None:
                a, spk = missing[0], source.windows(missing[0], b).to(device).unsqueeze(0)
            for j in missing:
                rates[j] = model.pad(spk[:, j - a].to(torch.float32)).mean(dim=1)

        for c in range(len(starts)):
            spk, first = load(c)
            if span > 1:  # the span reaches span // 2 windows past the chunk on either side
                a, b, r = starts[c], starts[c] + spk.shape[1], span // 2
                window_rates(a, b, spk)
                window_rates(b, min(b + r, m))
                for j in [j for j in rates if j < a - r]:
                    del rates[j]
            next_c = store.get(f"next{c}", device)
            maps, last, _ = model.input_maps(spk, first, last, None if next_c is None else NextSpike(next_c))
            feats = encode(spk, maps)
            n = feats.shape[0]
            sb = store.get(f"bstate{c}", device)
            bwd: list[torch.Tensor] = [torch.empty(0)] * n
            for i in range(n - 1, -1, -1):
                sb = model.step(feats[i], sb, backward=True)
                bwd[i] = sb
            for i in range(n):
                state_f = model.step(feats[i], state_f, backward=False)
                window = model.pad(spk[:, i].to(torch.float32)) if model.cfg.decode_needs_window else None
                span_rate = None
                if span > 1:
                    j = starts[c] + i
                    span_rate = torch.stack([rates[q] for q in range(max(0, j - span // 2), min(m, j + span // 2 + 1))],
                                            1).mean(dim=1)
                y = model.decode(state_f, bwd[i], window, span_rate)[0, :h, :w]
                yield starts[c] + i, y.float().cpu()
            del feats, bwd


def default_horizon_stride(horizon: int) -> int:
    """Frames taken from each piece by default: all but one window at each end of the piece, so
    every frame but the stream's first and last has at least one window of context on each side
    (docs/model.md, "Horizon inference", measured with K = 5: stride 3 costs 0.87 of the one-shot
    streaming and scores within 0.06 dB of stride 1 on validation, which costs 1.62 of it)."""
    return max(1, horizon - 2)


def horizon_pieces(num_windows: int, horizon: int, stride: int) -> list[tuple[int, range]]:
    """The pieces of horizon inference: (first window of a piece of min(horizon, num_windows)
    windows, the windows whose frames it gives). Every window is given by exactly one piece, from
    the middle `stride` positions of the piece where the stream allows (the first piece also gives
    the windows before them, the last one those after)."""
    if horizon < 1 or not 1 <= stride <= horizon:
        raise ValueError(f"horizon {horizon}, stride {stride}: expected horizon >= 1 and 1 <= stride <= horizon")
    if num_windows <= horizon:
        return [(0, range(num_windows))]
    offset = (horizon - stride) // 2  # the first taken position within a piece
    pieces, nxt = [], 0
    while nxt < num_windows:
        start = min(max(0, nxt - offset), num_windows - horizon)
        stop = num_windows if start == num_windows - horizon else start + offset + stride
        pieces.append((start, range(nxt, stop)))
        nxt = stop
    return pieces


@torch.no_grad()
def horizon_reconstruct(model: ReconNet, source: WindowSource, horizon: int, stride: int,
                        device: torch.device | str = "cpu") -> Iterator[tuple[int, torch.Tensor]]:
    """Yield (window index, frame float32 (H, W) on the CPU) for every window, in order, each from
    the network run on a piece of `horizon` windows on its own (horizon_pieces), as it was trained
    on K-window sequences: the recurrence never runs longer, and GISI takes the piece's own
    "never fired" sentinels. On a stream of at most `horizon` windows it is model(all windows).
    Memory holds one piece; a window is read once per piece that holds it."""
    if source.window != model.cfg.window:
        raise ValueError(f"source windows have {source.window} steps, model expects {model.cfg.window}")
    device = torch.device(device)
    model.eval()
    m = source.num_windows
    for start, given in horizon_pieces(m, horizon, stride):
        spk = source.windows(start, start + min(horizon, m)).to(device).unsqueeze(0)
        for i, y in model.frames(spk, take=range(given.start - start, given.stop - start)):
            yield start + i, y[0].float().cpu()


#: Windows a published (per-window or forward-recurrent) network runs at once: bigger chunks only
#: cost memory for these, never time.
PUBLISHED_CHUNK = 2


def _stream_published(model: PublishedNet, source: WindowSource, chunk: int,
                      device: torch.device) -> Iterator[tuple[int, torch.Tensor]]:
    """One forward pass over chunks of C windows: per-window networks need no carry; a
    forward-recurrent one carries its state (one feature map) across chunks. Nothing is computed
    twice whatever the chunk, so a per-window network runs at most PUBLISHED_CHUNK windows at once:
    Spk2ImgNet at 400 x 250 holds about 0.7 GB per window (five aligned sub-windows), and 21 at once
    were killed for memory on a 24 GiB machine."""
    state: torch.Tensor | None = None
    chunk = min(chunk, PUBLISHED_CHUNK)
    for a in range(0, source.num_windows, chunk):
        b = min(a + chunk, source.num_windows)
        spk = source.windows(a, b).to(device)
        h, w = spk.shape[-2:]
        x = model.pad(spk.to(torch.float32))
        if model.recurrent:
            for i in range(b - a):
                y, state = model.step(x[i:i + 1], state)
                yield a + i, y[0, :h, :w].float().cpu()
        else:
            frames = model.frames(x)
            for i in range(b - a):
                yield a + i, frames[i, :h, :w].float().cpu()


def reconstruct_windows(model: ReconNet | PublishedNet, spikes: torch.Tensor, chunk: int | None = None,
                        device: torch.device | str = "cpu") -> torch.Tensor:
    """All frames (M, H, W) of M windows (M, T, H, W); chunked when chunk < M."""
    src = TensorWindows(spikes)
    out = [y for _, y in stream_reconstruct(model, src, chunk or src.num_windows, device)]
    return torch.stack(out, 0)
