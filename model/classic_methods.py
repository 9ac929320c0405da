"""The paper's two traditional (non-learned) Table-1 methods, STP and SNM, re-implemented as
streaming reconstruction methods (model/methods.py's `Method`: one float32 (H, W) image on the y
scale, expected spikes per step in [0, 1], at the centre step of every window).

Both are recurrences over the spike stream: every pixel carries a small state that is updated step
by step, in order, and carried from one window to the next, so a stream is read once, one chunk of
windows at a time (memory: one chunk; time: linear in the stream; the output does not depend on the
chunk size). The image of window i is read from the state after its centre step i*T + T//2, so
both methods are causal: they see the spikes up to the centre, none after it (TFP and TFI see the
whole window).

STP: Zheng et al., "High-speed image reconstruction through short-term plasticity for spiking
cameras", CVPR 2021 (and "Capture the moment", TPAMI 2023). Every pixel drives a synapse with
Tsodyks-Markram short-term plasticity: a facilitation variable u (release probability, rest u0)
and a depression variable R (available resources, rest 1). At a spike that ends an inter-spike
interval d (in steps):

    R' = 1 - (1 - R (1 - u)) exp(-d / D)          (R used u R and recovers towards 1)
    u' = u0 + (u + f (1 - u) - u0) exp(-d / F)    (u jumped by f (1 - u) and decays towards u0)

Under a constant interval d both settle to fixed points; inverting those relations analytically
gives two estimates of the interval from the current state alone:

    d_u = F ln((v (1 - f) + f (1 - u0)) / v),   v = u - u0
    d_R = D ln((Q + u (1 - Q)) / Q),            Q = 1 - R

and the image is the mean of the two rates, (1/d_u + 1/d_R) / 2 (the authors' code adds them and
normalises min-max; the mean keeps the y scale). A pixel that never fired keeps the resting state,
which decodes to rate 0. The default parameters are those of the authors' released reconstruction
code (u0 = f = 0.15, D = 1 and F = 10 steps). Departures: the state is kept as log(u - u0) and
log(1 - R) in float64, so long low-light intervals (d >> D) neither round R to 1 nor underflow (the
plain form loses every interval over ~35 steps to rounding); a pixel's first spike is measured
from the step before the stream starts, as the authors' code does. The paper's motion handling
(a per-spike change filter on R and an LIF motion-detection layer that selects moving regions) is
not built: this is the plain STP reconstruction, the same image everywhere in the frame.

SNM: Zhu et al., "Retina-like visual image reconstruction via spiking neural model", CVPR 2020.
Three stages per step, vectorised over pixels:
  1. motion local excitation: a pixel is excited when the interval that just ended differs from
     its previous interval by more than `rel_change` of the shorter (and at least `abs_change`
     steps); an LIF neuron per pixel integrates the excitations of its k x k neighbourhood
     (leak `lif_decay` per step) and fires at `lif_threshold`, then resets to 0;
  2. dynamic / static separation: a neuron that fired marks its pixel dynamic for `hold` steps
     and restarts that pixel's static integration (the scene there changed);
  3. reconstruction: a static pixel reports its integrated rate since the last restart, a
     leaky weighted harmonic mean of its intervals (sum of weights / sum of weighted intervals;
     weight exp(-age / static_tau)); a dynamic pixel (or one with fewer than `min_intervals`
     intervals since the restart) reports the latest interval, 1 / max(last interval, steps since
     the last spike + 1), which also lets a pixel that stops firing fade.
Simplified: the paper's spike refining layer, whose synapses adapt by STDP, is not built (its role,
keeping the integration to one stable stretch of the scene, is taken by the restart in step 2); the
neuron constants are ours (chosen for 41-step windows of a 20 kHz-like stream; the paper's
values were not reproduced); the latest-interval fall-back in step 3 is TFI's causal half.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Iterator

import torch
import torch.nn.functional as F

from .streaming import WindowSource

_F64 = torch.float64


def _check_fields(obj: object, rules: dict[str, tuple[str, object]]) -> None:
    """Refuse a parameter that breaks its rule, naming the field: ("open01", None) 0 < x < 1,
    ("pos", None) x > 0, ("min", m) x >= m, ("int_odd", None) a positive odd int."""
    cls = type(obj).__name__
    for f in fields(obj):  # type: ignore[arg-type]
        x = getattr(obj, f.name)
        rule, arg = rules[f.name]
        if rule == "int_odd":
            if isinstance(x, bool) or not isinstance(x, int) or x < 1 or x % 2 == 0:
                raise ValueError(f"{cls}.{f.name} must be a positive odd integer, got {x!r}")
            continue
        if rule == "int_min":
            if isinstance(x, bool) or not isinstance(x, int) or x < arg:  # type: ignore[operator]
                raise ValueError(f"{cls}.{f.name} must be an integer >= {arg}, got {x!r}")
            continue
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise ValueError(f"{cls}.{f.name} must be a finite number, got {x!r}")
        if rule == "open01" and not 0 < x < 1:
            raise ValueError(f"{cls}.{f.name} must lie strictly between 0 and 1, got {x!r}")
        if rule == "pos" and not x > 0:
            raise ValueError(f"{cls}.{f.name} must be > 0, got {x!r}")
        if rule == "min" and not x >= arg:  # type: ignore[operator]
            raise ValueError(f"{cls}.{f.name} must be >= {arg}, got {x!r}")
        if rule == "unit" and not 0 <= x < 1:
            raise ValueError(f"{cls}.{f.name} must lie in [0, 1), got {x!r}")


# ---------------------------------------------------------------------------------------------
# STP
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class STPParams:
    """Tsodyks-Markram synapse constants; times in camera steps."""

    u0: float = 0.15  # resting release probability: Zheng et al.'s released TFSTP code (u0 = 0.15)
    f: float = 0.15   # facilitation increment: same code (f = 0.15)
    D: float = 1.0    # depression recovery time: same code (D = 0.05 x 20 steps)
    F: float = 10.0   # facilitation decay time: same code (F = 0.5 x 20 steps)

    def __post_init__(self) -> None:
        _check_fields(self, {"u0": ("open01", None), "f": ("open01", None), "D": ("pos", None), "F": ("pos", None)})


@dataclass(frozen=True)
class STPState:
    """Per pixel: log(u - u0), log(1 - R) (float64; -inf at rest) and the last spike's step."""

    log_v: torch.Tensor
    log_q: torch.Tensor
    last: torch.Tensor  # int64 absolute step of the latest spike (stream start - 1 before any)

    @classmethod
    def rest(cls, shape: tuple[int, ...], first_step: int = 0, device: torch.device | str = "cpu") -> "STPState":
        ninf = torch.full(shape, -math.inf, dtype=_F64, device=device)
        return cls(ninf, ninf.clone(), torch.full(shape, first_step - 1, dtype=torch.int64, device=device))


def stp_update(state: STPState, spikes: torch.Tensor, step: int, p: STPParams) -> STPState:
    """The state after step `step` (absolute) with spikes bool (H, W) at that step (a new state;
    only the pixels that fire are computed)."""
    i = spikes.reshape(-1).nonzero().squeeze(1)
    if i.numel() == 0:
        return state
    flat = [x.reshape(-1) for x in (state.log_v, state.log_q, state.last)]
    log_v, log_q, last = (x[i] for x in flat)
    d = (step - last).to(_F64)
    v, q = log_v.exp(), log_q.exp()
    u = p.u0 + v  # the pre-spike u drives the depression (R's update uses u before it facilitates)
    new_q = torch.log(q + u * (1 - q)) - d / p.D
    new_v = torch.log(v * (1 - p.f) + p.f * (1 - p.u0)) - d / p.F
    shape = state.last.shape
    return STPState(flat[0].index_put((i,), new_v).reshape(shape), flat[1].index_put((i,), new_q).reshape(shape),
                    flat[2].index_put((i,), torch.full_like(last, step)).reshape(shape))


def stp_rate(state: STPState, p: STPParams) -> torch.Tensor:
    """float32 (H, W) in [0, 1]: the mean of the two steady-state rates the state implies."""
    v = state.log_v.exp()
    q = state.log_q.exp()
    u = p.u0 + v
    d_u = p.F * (torch.log(v * (1 - p.f) + p.f * (1 - p.u0)) - state.log_v)  # +inf at rest
    d_r = p.D * (torch.log(q + u * (1 - q)) - state.log_q)
    return (0.5 * (1 / d_u + 1 / d_r)).clamp(0, 1).to(torch.float32)


# ---------------------------------------------------------------------------------------------
# SNM
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SNMParams:
    """Spiking-neural-model constants; times in camera steps. The paper's values were not
    reproduced: these are ours, each with its reason."""

    neighbourhood: int = 3       # k x k receptive field of a motion neuron (a local 3 x 3, as Zheng et al.'s LIF layer)
    rel_change: float = 0.5      # an interval change of half the shorter one excites (above the +-1 step quantisation)
    abs_change: float = 2.0      # ... and at least 2 steps, so a bright pixel's 1 <-> 2 step jitter does not
    lif_decay: float = 0.9       # membrane leak per step (time constant ~10 steps)
    lif_threshold: float = 3.0   # three excited neighbours in quick succession fire the neuron
    hold: int = 41               # steps a fired pixel stays dynamic: one window
    static_tau: float = 2000.0   # static integration forgets with this time constant (~50 windows)
    min_intervals: int = 2       # intervals since a restart before the static rate is trusted

    def __post_init__(self) -> None:
        _check_fields(self, {"neighbourhood": ("int_odd", None), "rel_change": ("min", 0.0),
                             "abs_change": ("min", 0.0), "lif_decay": ("unit", None),
                             "lif_threshold": ("pos", None), "hold": ("int_min", 0), "static_tau": ("pos", None),
                             "min_intervals": ("int_min", 1)})


@dataclass(frozen=True)
class SNMState:
    last: torch.Tensor        # int64: latest spike's step (stream start - 1 before any)
    seen: torch.Tensor        # bool: fired at least once
    interval: torch.Tensor    # int64: latest interval (the first spike's: from the stream start)
    known: torch.Tensor       # bool: `interval` is a real one (between two spikes)
    potential: torch.Tensor   # float64: LIF membrane of the motion neuron
    dynamic_until: torch.Tensor  # int64: the pixel is dynamic while step < this
    weight: torch.Tensor      # float64: leaky count of intervals since the last restart
    span: torch.Tensor        # float64: leaky sum of those intervals (steps)

    @classmethod
    def rest(cls, shape: tuple[int, ...], first_step: int = 0, device: torch.device | str = "cpu") -> "SNMState":
        i64 = dict(dtype=torch.int64, device=device)
        zero = torch.zeros(shape, dtype=_F64, device=device)
        no = torch.zeros(shape, dtype=torch.bool, device=device)
        before = torch.full(shape, first_step - 1, **i64)
        return cls(before, no, torch.zeros(shape, **i64), no.clone(), zero,
                   torch.full(shape, first_step, **i64), zero.clone(), zero.clone())


def snm_update(state: SNMState, spikes: torch.Tensor, step: int, p: SNMParams) -> SNMState:
    """The state after step `step` (absolute) with spikes bool (H, W) at that step (a new state;
    the interval bookkeeping is computed only where pixels fire)."""
    i = spikes.reshape(-1).nonzero().squeeze(1)
    shape = state.last.shape
    flat = {k: getattr(state, k).reshape(-1) for k in state.__dataclass_fields__}
    last, real, interval, known = (flat[k][i] for k in ("last", "seen", "interval", "known"))
    d = step - last  # `real`: an interval between two spikes ends now
    shorter = torch.minimum(d, interval).to(_F64)
    changed = (d - interval).abs().to(_F64) > torch.clamp(p.rel_change * shorter, min=p.abs_change)
    excited = i[real & known & changed]
    decay = torch.exp(-d.to(_F64) / p.static_tau)
    w, s = flat["weight"][i], flat["span"][i]
    out = dict(flat)
    out["weight"] = flat["weight"].index_put((i,), torch.where(real, w * decay + 1, w))
    out["span"] = flat["span"].index_put((i,), torch.where(real, s * decay + d.to(_F64), s))
    out["last"] = flat["last"].index_put((i,), torch.full_like(d, step))
    out["seen"] = flat["seen"].index_put((i,), torch.ones_like(real))
    out["interval"] = flat["interval"].index_put((i,), d)
    out["known"] = flat["known"].index_put((i,), known | real)
    out["potential"] = flat["potential"] * p.lif_decay
    if excited.numel():
        k = p.neighbourhood
        ones = torch.ones((1, 1, k, k), dtype=_F64, device=spikes.device)
        ex = torch.zeros(flat["last"].numel(), dtype=_F64, device=spikes.device).index_fill(0, excited, 1.0)
        pot = out["potential"] + F.conv2d(ex.reshape((1, 1) + tuple(shape)), ones, padding=k // 2).reshape(-1)
        jf = (pot >= p.lif_threshold).nonzero().squeeze(1)  # fired: dynamic for `hold` steps, integration restarts
        out["potential"] = pot.index_fill(0, jf, 0.0)
        out["dynamic_until"] = flat["dynamic_until"].index_put((jf,), torch.full_like(jf, step + 1 + p.hold))
        out["weight"] = out["weight"].index_fill(0, jf, 0.0)
        out["span"] = out["span"].index_fill(0, jf, 0.0)
    return SNMState(**{k: v.reshape(shape) for k, v in out.items()})


def snm_rate(state: SNMState, step: int, p: SNMParams) -> torch.Tensor:
    """float32 (H, W) in [0, 1] at step `step` (the step last passed to snm_update)."""
    latest = torch.maximum(state.interval, step - state.last + 1).to(_F64)
    dynamic = (step < state.dynamic_until) | (state.weight < p.min_intervals - 1e-9) | (state.span <= 0)
    static = state.weight / state.span.clamp(min=1e-300)
    rate = torch.where(dynamic, 1 / latest.clamp(min=1), static)
    return torch.where(state.seen, rate, torch.zeros_like(rate)).clamp(0, 1).to(torch.float32)


# ---------------------------------------------------------------------------------------------
# Methods
# ---------------------------------------------------------------------------------------------

@dataclass
class _RecurrentMethod:
    """Steps a per-pixel state through a source in order, chunk windows at a time, and reads
    the image at each window's centre step."""

    name: str
    window: int = 41
    chunk: int = 8
    device: str = "cpu"

    def __post_init__(self) -> None:
        if self.chunk < 1:
            raise ValueError(f"{self.name}: chunk must be >= 1, got {self.chunk}")

    def _rest(self, shape: tuple[int, ...], first_step: int, device: torch.device):  # pragma: no cover
        raise NotImplementedError

    def _update(self, state, spikes: torch.Tensor, step: int):  # pragma: no cover
        raise NotImplementedError

    def _rate(self, state, step: int) -> torch.Tensor:  # pragma: no cover
        raise NotImplementedError

    @torch.no_grad()
    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        device = torch.device(self.device)
        t, first = source.window, source.first_step
        centre = t // 2
        state = None
        for a in range(0, source.num_windows, self.chunk):
            b = min(a + self.chunk, source.num_windows)
            spk = source.windows(a, b).to(device)
            if state is None:
                state = self._rest(tuple(spk.shape[-2:]), first, device)
            for k in range(b - a):
                base = first + (a + k) * t
                for j in range(t):
                    state = self._update(state, spk[k, j], base + j)
                    if j == centre:
                        yield a + k, self._rate(state, base + j).cpu()
            del spk


@dataclass
class STPMethod(_RecurrentMethod):
    """Short-term plasticity reconstruction (Zheng et al., CVPR 2021), causal, without its motion layer."""

    params: STPParams = STPParams()

    def _rest(self, shape, first_step, device):
        return STPState.rest(shape, first_step, device)

    def _update(self, state, spikes, step):
        return stp_update(state, spikes, step, self.params)

    def _rate(self, state, step):
        return stp_rate(state, self.params)


@dataclass
class SNMMethod(_RecurrentMethod):
    """Spiking neural model reconstruction (Zhu et al., CVPR 2020), core without STDP refining."""

    params: SNMParams = SNMParams()

    def _rest(self, shape, first_step, device):
        return SNMState.rest(shape, first_step, device)

    def _update(self, state, spikes, step):
        return snm_update(state, spikes, step, self.params)

    def _rate(self, state, step):
        return snm_rate(state, step, self.params)


#: Spec name -> (method class, table label).
CLASSIC_METHODS = {"stp": (STPMethod, "STP"), "snm": (SNMMethod, "SNM")}


def classic_method(kind: str, label: str = "", window: int = 41, chunk: int = 8, device: str = "cpu"):
    """The method of a spec name in CLASSIC_METHODS."""
    cls, default = CLASSIC_METHODS[kind]
    return cls(label or default, window, chunk, device)


__all__ = ["STPParams", "STPState", "stp_update", "stp_rate", "SNMParams", "SNMState", "snm_update", "snm_rate",
           "STPMethod", "SNMMethod", "CLASSIC_METHODS", "classic_method"]
