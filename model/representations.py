"""Spike-stream representations: TFP, TFI, LISI and GISI as exact, vectorised tensor functions.

Conventions (docs/model.md, "Representations"):
- A window is a tensor of T steps, shape (T, H, W) or batched (B, T, H, W); its centre is step T // 2
  (the paper's windows have T = 2*dt + 1 = 41 steps, centre 20).
- A sequence of K windows is (K, T, H, W) or (B, K, T, H, W); window i covers the absolute steps
  [first_step + i*T, first_step + (i+1)*T).
- Spike times are absolute integer step indices (int64), so carried maps never drift.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch

IntervalTransform = Literal["raw", "inverse"]
INTERVAL_TRANSFORMS: tuple[str, ...] = ("raw", "inverse")


def _check_spikes(spikes: torch.Tensor, min_dim: int, max_dim: int, what: str) -> torch.Tensor:
    """Validate a spike tensor and return it as bool; says exactly what is wrong otherwise."""
    if not isinstance(spikes, torch.Tensor):
        raise TypeError(f"{what}: expected a torch.Tensor, got {type(spikes).__name__}")
    if not min_dim <= spikes.dim() <= max_dim:
        raise ValueError(f"{what}: expected {min_dim} to {max_dim} dimensions, got shape {tuple(spikes.shape)}")
    if spikes.dtype == torch.bool:
        return spikes
    if spikes.dtype == torch.uint8 or spikes.dtype.is_floating_point:
        # values are unknown on the meta device (model/flops.py counts FLOP there): shapes only
        if spikes.numel() and spikes.device.type != "meta" and (spikes.min() < 0 or spikes.max() > 1):
            raise ValueError(f"{what}: spike values must be 0 or 1, got range "
                             f"[{spikes.min().item()}, {spikes.max().item()}]")
        return spikes != 0
    raise TypeError(f"{what}: spikes must be bool, uint8 or floating 0/1, got {spikes.dtype}")


def _first_spike(s: torch.Tensor, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Index of the first spike along `dim` and whether there is one (argmax returns the first
    maximum; uint8 keeps the temporaries at one byte per element, so full frames stay cheap)."""
    u = s.to(torch.uint8)
    return u.argmax(dim=dim), u.amax(dim=dim) > 0


def _last_spike(s: torch.Tensor, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Index of the last spike along `dim` and whether there is one."""
    idx, has = _first_spike(s.flip(dim), dim)
    return s.shape[dim] - 1 - idx, has


# ---------------------------------------------------------------------------------------------
# Baselines on one window (Zhu et al., ICME 2019: texture from playback / from interval)
# ---------------------------------------------------------------------------------------------

def tfp(spikes: torch.Tensor) -> torch.Tensor:
    """Texture from playback: spikes in the window / window length (docs/model.md, "Representations").

    spikes: (T, H, W) or (B, T, H, W). Returns float32 (H, W) or (B, H, W) on the y scale
    (expected spikes per step), the same scale as the ground truth.
    """
    s = _check_spikes(spikes, 3, 4, "tfp")
    return s.sum(dim=-3, dtype=torch.int64).to(torch.float32) / s.shape[-3]


def tfi(spikes: torch.Tensor) -> torch.Tensor:
    """Texture from interval: 1 / inter-spike interval around the window centre (Zhu et al. 2019).

    The interval runs from the last spike at or before the centre step c = T // 2 to the first
    spike strictly after it. A side with no spike inside the window takes the step just outside
    it (-1 before, T after), so a pixel with no spike at all gets 1 / (T + 1) and one with a
    single spike gets 1 / (distance across to the far window edge). These stand-ins make the
    interval a lower bound of the true one, so the value is an upper bound of the true rate:
    the estimate stays finite and dark pixels stay dark.

    spikes: (T, H, W) or (B, T, H, W). Returns float32 (H, W) or (B, H, W).
    """
    s = _check_spikes(spikes, 3, 4, "tfi")
    t = s.shape[-3]
    c = t // 2
    prev, has_prev = _last_spike(s[..., : c + 1, :, :], -3)
    prev = torch.where(has_prev, prev, -1)
    if c + 1 < t:
        nxt, has_next = _first_spike(s[..., c + 1:, :, :], -3)
        nxt = torch.where(has_next, nxt + c + 1, t)
    else:
        nxt = torch.full_like(prev, t)
    return 1.0 / (nxt - prev).to(torch.float32)


# ---------------------------------------------------------------------------------------------
# LISI / GISI (paper, "GISI transform"; docs/design.md section 5, facts from the authors' released code)
# ---------------------------------------------------------------------------------------------

@dataclass
class LastSpike:
    """Forward carry: per pixel, the absolute step of the latest spike seen so far.

    `steps` holds stream_start - 1 for a pixel that has not fired yet (the authors' -1 when the
    stream starts at step 0).
    """

    steps: torch.Tensor  # int64 (..., H, W)

    @classmethod
    def never(cls, shape: tuple[int, ...], stream_start: int = 0, device: torch.device | str = "cpu") -> "LastSpike":
        """The state before any window: no pixel has fired."""
        return cls(torch.full(shape, stream_start - 1, dtype=torch.int64, device=device))


@dataclass
class NextSpike:
    """Backward carry: per pixel, the absolute step of the earliest spike seen so far going back.

    `steps` holds stream_end (one past the last step of the sequence; the authors' K*41) for a
    pixel that does not fire again before the end.
    """

    steps: torch.Tensor  # int64 (..., H, W)

    @classmethod
    def never(cls, shape: tuple[int, ...], stream_end: int, device: torch.device | str = "cpu") -> "NextSpike":
        """The state after the last window: no later spike."""
        return cls(torch.full(shape, stream_end, dtype=torch.int64, device=device))


def _window_times(s: torch.Tensor, first_step: int) -> tuple[torch.Tensor, ...]:
    """Absolute spike times per window of a sequence s (..., K, T, H, W).

    Returns (last_before_centre, last_any, first_from_centre, first_any), each int64
    (..., K, H, W); a window without such a spike gets the int64 minimum (for "last") or maximum
    (for "first"), so it never wins a running max / min against a real time or a carry.
    """
    k, t = s.shape[-4], s.shape[-3]
    c = t // 2
    lo, hi = torch.iinfo(torch.int64).min, torch.iinfo(torch.int64).max
    shape = [1] * (s.dim() - 1)
    shape[-3] = k
    offset = first_step + t * torch.arange(k, device=s.device, dtype=torch.int64).view(shape)
    if c > 0:
        idx, has = _last_spike(s[..., :c, :, :], -3)
        last_before = torch.where(has, idx + offset, lo)
    else:
        last_before = torch.full(s.shape[:-3] + s.shape[-2:], lo, dtype=torch.int64, device=s.device)
    idx, has = _last_spike(s, -3)
    last_any = torch.where(has, idx + offset, lo)
    idx, has = _first_spike(s[..., c:, :, :], -3)
    first_from = torch.where(has, idx + c + offset, hi)
    idx, has = _first_spike(s, -3)
    first_any = torch.where(has, idx + offset, hi)
    return last_before, last_any, first_from, first_any


def _check_sequence(spikes: torch.Tensor, what: str) -> torch.Tensor:
    s = _check_spikes(spikes, 4, 5, what)
    if s.shape[-3] < 1:
        raise ValueError(f"{what}: window length must be >= 1, got shape {tuple(s.shape)}")
    return s


def _check_carry(carry: torch.Tensor, expected: tuple[int, ...], name: str) -> None:
    if carry.dtype != torch.int64:
        raise TypeError(f"{name}.steps must be int64, got {carry.dtype}")
    if tuple(carry.shape) != expected:
        raise ValueError(f"{name}.steps has shape {tuple(carry.shape)}, expected {expected}")


def forward_spike_times(spikes: torch.Tensor, first_step: int = 0,
                        carry: LastSpike | None = None) -> tuple[torch.Tensor, LastSpike]:
    """Forward half of the GISI transform: last spike strictly before each window's centre.

    Per pixel and window i: the latest spike at an absolute step < centre_i, looking through this
    window and all earlier ones (carried in by `carry`); `carry` defaults to "never fired"
    (first_step - 1). spikes: (K, T, H, W) or (B, K, T, H, W). Returns the int64 map
    (..., K, H, W) and the carry to hand to the next call.
    """
    s = _check_sequence(spikes, "forward_spike_times")
    batch_hw = s.shape[:-4] + s.shape[-2:]
    if carry is None:
        carry = LastSpike.never(batch_hw, first_step, s.device)
    _check_carry(carry.steps, batch_hw, "LastSpike")
    last_before, last_any, _, _ = _window_times(s, first_step)
    # Latest spike in all windows before i: exclusive running max of last_any, seeded by the carry.
    seen = torch.cat([carry.steps.unsqueeze(-3), last_any], dim=-3).cummax(dim=-3).values
    result = torch.maximum(seen[..., :-1, :, :], last_before)
    return result, LastSpike(seen[..., -1, :, :].clone())


def backward_spike_times(spikes: torch.Tensor, first_step: int = 0,
                         carry: NextSpike | None = None) -> tuple[torch.Tensor, NextSpike]:
    """Backward half of the GISI transform: first spike at or after each window's centre.

    Per pixel and window i: the earliest spike at an absolute step >= centre_i, looking through
    this window and all later ones (carried in by `carry`); `carry` defaults to "never fires
    again" (the end of these windows, first_step + K*T, the authors' K*41). Returns the int64 map
    (..., K, H, W) and the carry to hand to the call for the preceding windows.
    """
    s = _check_sequence(spikes, "backward_spike_times")
    k, t = s.shape[-4], s.shape[-3]
    batch_hw = s.shape[:-4] + s.shape[-2:]
    if carry is None:
        carry = NextSpike.never(batch_hw, first_step + k * t, s.device)
    _check_carry(carry.steps, batch_hw, "NextSpike")
    _, _, first_from, first_any = _window_times(s, first_step)
    # Earliest spike in all windows after i: reversed exclusive running min, seeded by the carry.
    rev = torch.cat([carry.steps.unsqueeze(-3), first_any.flip(-3)], dim=-3).cummin(dim=-3).values
    seen = rev.flip(-3)  # seen[i] = min(carry, first_any[i:]) ; seen[K] = carry
    result = torch.minimum(seen[..., 1:, :, :], first_from)
    return result, NextSpike(seen[..., 0, :, :].clone())


def gisi(spikes: torch.Tensor, first_step: int = 0, last: LastSpike | None = None,
         nxt: NextSpike | None = None) -> tuple[torch.Tensor, LastSpike, NextSpike]:
    """Global inter-spike interval per window (paper eq. of Fig. "GISI transform";
    docs/design.md section 5).

    GISI_i = (first spike at or after centre_i, carried backward from later windows)
           - (last spike strictly before centre_i, carried forward from earlier windows),
    in absolute steps, raw (not inverted, not normalised), as the authors compute it. With the
    default carries a pixel that never fires in the sequence gets K*T + 1 (K*41 - (-1)).
    Returns float32 (..., K, H, W) and the forward and backward carries after these windows.
    """
    before, last_out = forward_spike_times(spikes, first_step, last)
    after, next_out = backward_spike_times(spikes, first_step, nxt)
    return (after - before).to(torch.float32), last_out, next_out


def lisi(spikes: torch.Tensor) -> torch.Tensor:
    """Local inter-spike interval: GISI restricted to each window on its own (paper, LISI).

    Same rule as GISI (last spike strictly before the centre, first at or after it) but nothing is
    carried between windows: a side without a spike inside the window takes the step just outside
    it, so a pixel silent in the window gets T + 1 (42 for 41-step windows).
    spikes: (T, H, W) or (B, T, H, W), one window each; lisi_windows takes sequences of windows.
    """
    s = _check_spikes(spikes, 3, 4, "lisi")
    return lisi_windows(s.unsqueeze(-4)).squeeze(-3)


def lisi_windows(spikes: torch.Tensor) -> torch.Tensor:
    """LISI for every window of a sequence (K, T, H, W) or (B, K, T, H, W) -> float32 (..., K, H, W)."""
    s = _check_sequence(spikes, "lisi_windows")
    t = s.shape[-3]
    c = t // 2
    if c > 0:
        before, has = _last_spike(s[..., :c, :, :], -3)
        before = torch.where(has, before, -1)
    else:
        before = torch.full(s.shape[:-3] + s.shape[-2:], -1, dtype=torch.int64, device=s.device)
    after, has = _first_spike(s[..., c:, :, :], -3)
    after = torch.where(has, after + c, t)
    return (after - before).to(torch.float32)


def tfp_windows(spikes: torch.Tensor) -> torch.Tensor:
    """TFP for every window of a sequence (..., K, T, H, W) -> (..., K, H, W)."""
    s = _check_sequence(spikes, "tfp_windows")
    return s.sum(dim=-3, dtype=torch.int64).to(torch.float32) / s.shape[-3]


def tfi_windows(spikes: torch.Tensor) -> torch.Tensor:
    """TFI for every window of a sequence (..., K, T, H, W) -> (..., K, H, W)."""
    s = _check_sequence(spikes, "tfi_windows")
    lead = s.shape[:-3]
    flat = s.reshape((-1,) + s.shape[-3:])
    return tfi(flat).reshape(lead + s.shape[-2:])


def transform_interval(interval: torch.Tensor, mode: IntervalTransform) -> torch.Tensor:
    """How an interval map (GISI or LISI, in steps, >= 1) is fed to the network.

    "raw": as the authors feed it (docs/design.md section 5). "inverse": 1 / interval, a rate on
    the y scale (the TFI of the carried interval), bounded in (0, 1], so the conv sees inputs of
    order one.
    """
    if mode == "raw":
        return interval
    if mode == "inverse":
        return 1.0 / interval.clamp_min(1.0)
    raise ValueError(f"interval transform must be one of {INTERVAL_TRANSFORMS}, got {mode!r}")
