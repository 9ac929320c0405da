"""The bidirectional recurrent reconstruction network (paper, section Method; docs/design.md section 5).

For windows i = 0..K-1 of a sequence:
    F_i   = f(Rep_i)                                    16 residual blocks on the representation
    Ff_i  = g_f([F_i + a(Ff_{i-1}, F_i), Ff_{i-1}])     forward fusion, Ff_{-1} = 0, no a() at i=0
    Fb_i  = g_b([F_i + a(Fb_{i+1}, F_i), Fb_{i+1}])     backward fusion, Fb_K = 0, no a() at K-1
    Y_i   = c([Ff_i, Fb_i])                              head: conv 2C->2C, leaky, 2C->C, leaky, C->1
with a() the PCD alignment shared by both directions and g = conv 2C->C + leaky + residual blocks
(separate weights per direction). The per-window pieces are public so streaming inference
(model/streaming.py) runs exactly the same arithmetic chunk by chunk.
"""
from __future__ import annotations

from typing import Callable, Iterator, NamedTuple

import torch
from torch import nn

from .blocks import conv3x3, conv_lrelu, double_conv, pad_to_multiple, padded_size, residual_stack
from .config import TRAINABLE, ModelConfig
from .lrrep import build_representation
from .pcd import PCDAlign
from .published_reps import PUBLISHED_REPS, published_input_map
from .registry import ARCH_REGISTRY
from .representations import (LastSpike, NextSpike, gisi, lisi_windows, tfi, tfi_windows, tfp_windows,
                              transform_interval)


class ReconNet(nn.Module):
    """LR-Rep + ResNet + bidirectional PCD-aligned recurrent fusion + head."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        # Inference setting, not part of the config: the largest GISI (in steps) fed to the net.
        # Training sequences of K windows never exceed K*T + 1; on a longer stream the "never
        # fired" distance grows with its length, so inference clips to what training saw.
        self.max_interval: float | None = None
        # Inference hook, not part of the config: called with each decoded batch's RefineParts
        # (padded maps) when the head refines, so a reader sees the gates (`spikesim gates`).
        self.refine_observer: Callable[[RefineParts], None] | None = None
        c, nb = cfg.num_features, cfg.num_blocks
        self.representation = build_representation(cfg)
        self.extract = residual_stack(c, nb)
        self.align = PCDAlign(c, cfg.deform_groups, cfg.deform_backend) if cfg.aif else None
        self.fuse_forward = nn.Sequential(conv_lrelu(2 * c, c), residual_stack(c, nb))
        self.fuse_backward = nn.Sequential(conv_lrelu(2 * c, c), residual_stack(c, nb))
        self.head = nn.Sequential(double_conv(2 * c, c, mid_ch=2 * c), conv3x3(c, head_channels(cfg)))
        if cfg.output == "refine":
            init_refine_gates(self.head[-1])

    # ---- inputs ---------------------------------------------------------------------------
    def input_maps(self, spikes: torch.Tensor, first_step: int = 0, last: LastSpike | None = None,
                   nxt: NextSpike | None = None) -> tuple[torch.Tensor | None, LastSpike | None, NextSpike | None]:
        """The one-channel map each window's representation needs, (B, K, H, W) float32, or None.

        GISI uses (and returns) the carried spike times; with no carries given, the sequence is
        taken on its own (last = first_step - 1, next = end of the windows), as in training.
        """
        cfg = self.cfg
        if cfg.representation == "spike":
            return None, last, nxt
        if cfg.representation == "tfp":
            return tfp_windows(spikes), last, nxt
        if cfg.representation == "tfi":
            return tfi_windows(spikes), last, nxt
        if cfg.representation in PUBLISHED_REPS:  # window-local: None, or AMIM's windowed TFI
            return published_input_map(cfg.representation, spikes), last, nxt
        if cfg.interval == "lisi":
            return transform_interval(lisi_windows(spikes), cfg.interval_transform), last, nxt
        interval, last_out, next_out = gisi(spikes, first_step, last, nxt)
        if self.max_interval is not None:
            interval = interval.clamp_max(self.max_interval)
        return transform_interval(interval, cfg.interval_transform), last_out, next_out

    def padded_size(self, h: int, w: int) -> tuple[int, int]:
        return padded_size(h, w, self.cfg.pad_multiple)

    def pad(self, x: torch.Tensor) -> torch.Tensor:
        """Replicate-pad the last two dims up to multiples of pad_multiple."""
        return pad_to_multiple(x, self.cfg.pad_multiple)

    # ---- per-window pieces ----------------------------------------------------------------
    def encode(self, spikes: torch.Tensor, maps: torch.Tensor | None) -> torch.Tensor:
        """F = f(Rep) for a batch of padded windows: spikes (N, T, H, W), maps (N, H, W) or None.
        With input_norm, both are divided by the window's rate first (window_rate_scale)."""
        if self.cfg.input_norm != "none":
            scale = window_rate_scale(spikes, self.cfg.input_norm_floor_rate)
            spikes = spikes / scale[:, None, None, None]
            maps = None if maps is None else maps / scale[:, None, None]
        rep = self.representation(spikes, None if maps is None else maps.unsqueeze(1))
        return self.extract(rep)

    def step(self, feat: torch.Tensor, state: torch.Tensor | None, backward: bool) -> torch.Tensor:
        """One recurrent step; state None = the first window of this direction (zero state, no
        alignment). Without ADF every window gets the zero state."""
        fuse = self.fuse_backward if backward else self.fuse_forward
        if state is None or not self.cfg.adf:
            return fuse(torch.cat([feat, torch.zeros_like(feat)], 1))
        x = feat + self.align(state, feat) if self.align is not None else feat
        return fuse(torch.cat([x, state], 1))

    def decode(self, fwd: torch.Tensor, bwd: torch.Tensor, window: torch.Tensor | None = None,
               span: torch.Tensor | None = None) -> torch.Tensor:
        """Y = c([Ff, Fb]) -> (N, H, W); with output "refine", the head's gates blend its frame with
        the classic estimates of `window` (N, T, H, W), the window's own (padded) spikes, and with
        refine_span > 1 the mean rate `span` (N, H, W) of the span centred on it (span_rates). With
        input_norm the frame is scaled back by the window's rate (window_rate_scale)."""
        out = self.head(torch.cat([fwd, bwd], 1))
        if window is None and self.cfg.decode_needs_window:
            raise ValueError(f"model.output {self.cfg.output!r} with input_norm {self.cfg.input_norm!r} decodes a "
                             "window with its spikes: pass window=")
        if self.cfg.input_norm != "none":
            scale = window_rate_scale(window, self.cfg.input_norm_floor_rate)
            out = torch.cat([out[:, :1] * scale[:, None, None, None].to(out.dtype), out[:, 1:]], 1)
        if self.cfg.output == "direct":
            return out.squeeze(1)
        if (span is None) != (self.cfg.refine_span == 1):
            raise ValueError(f"model.refine_span={self.cfg.refine_span}: decode takes span= exactly when it is > 1")
        parts = refine_parts(out, window, span)
        if self.refine_observer is not None:
            self.refine_observer(parts)
        return parts.frame

    # ---- whole sequence ---------------------------------------------------------------------
    def forward(self, spikes: torch.Tensor, maps: torch.Tensor | None = None) -> torch.Tensor:
        """spikes (B, K, T, H, W) bool/uint8/float 0-1 -> reconstructions (B, K, H, W) on the y scale.

        maps: the representation's maps (B, K, H, W); computed from these K windows alone when
        omitted (GISI with the "never fired" sentinels -1 and K*T).

        The graph is built in the order every run of this project was trained with: the forward
        recurrence, then the backward one with each window decoded as it is reached. Autograd
        accumulates a parameter's gradient in reverse creation order, so decoding in another order
        (as `frames` does) gives the same frames but other last bits in the gradients: a run
        rerun or resumed from an earlier checkpoint would then differ from the one it continues
        (measured: from step 4 of the shipped network's run; tested against a reference loop).
        """
        x, feats, (k, h, w) = self._features(spikes, maps)
        fwd: list[torch.Tensor] = []
        state = None
        for i in range(k):
            state = self.step(feats[:, i], state, backward=False)
            fwd.append(state)
        out: list[torch.Tensor] = [torch.empty(0)] * k
        spans = span_rates(x, self.cfg.refine_span) if self.cfg.refine_span > 1 else None
        state = None
        for i in range(k - 1, -1, -1):
            state = self.step(feats[:, i], state, backward=True)
            out[i] = self.decode(fwd[i], state, x[:, i] if self.cfg.decode_needs_window else None,
                                 None if spans is None else spans[:, i])
        return torch.stack(out, 1)[..., :h, :w]

    def frames(self, spikes: torch.Tensor, maps: torch.Tensor | None = None,
               take: range | None = None) -> Iterator[tuple[int, torch.Tensor]]:
        """(i, frame (B, H, W)) for each window i of `take` (default all K), in order: the frames
        forward gives, made for inference. The forward recurrence runs up to take's last window
        and the backward one down to its first, nothing further; each frame is decoded just before
        it is yielded (so a refine_observer sees one decode per frame). Horizon inference
        (model/streaming.py) takes the middle windows of a K-window piece this way."""
        x, feats, (k, h, w) = self._features(spikes, maps)
        take = range(k) if take is None else take
        if not (len(take) and take.step == 1 and 0 <= take.start and take.stop <= k):
            raise ValueError(f"take={take}: expected consecutive windows within the sequence's {k}")
        fwd: dict[int, torch.Tensor] = {}
        state = None
        for i in range(take.stop):
            state = self.step(feats[:, i], state, backward=False)
            if i in take:
                fwd[i] = state
        bwd: dict[int, torch.Tensor] = {}
        state = None
        for i in range(k - 1, take.start - 1, -1):
            state = self.step(feats[:, i], state, backward=True)
            if i in take:
                bwd[i] = state
        spans = span_rates(x, self.cfg.refine_span) if self.cfg.refine_span > 1 else None
        for i in take:
            y = self.decode(fwd.pop(i), bwd.pop(i), x[:, i] if self.cfg.decode_needs_window else None,
                            None if spans is None else spans[:, i])
            yield i, y[..., :h, :w]

    def _features(self, spikes: torch.Tensor, maps: torch.Tensor | None
                  ) -> tuple[torch.Tensor, torch.Tensor, tuple[int, int, int]]:
        """The checked, padded windows x (B, K, T, H', W'), their features (B, K, C, H', W') and
        (K, H, W): what forward and frames share before the recurrences."""
        if spikes.dim() != 5:
            raise ValueError(f"spikes must be (B, K, T, H, W), got shape {tuple(spikes.shape)}")
        b, k, t, h, w = spikes.shape
        if t != self.cfg.window:
            raise ValueError(f"windows have {t} steps but the model was built for window={self.cfg.window}")
        if maps is None:
            maps, _, _ = self.input_maps(spikes)
        elif tuple(maps.shape) != (b, k, h, w):
            raise ValueError(f"maps must be (B, K, H, W) = {(b, k, h, w)}, got {tuple(maps.shape)}")
        x = self.pad(spikes.to(torch.float32))
        m = None if maps is None else self.pad(maps.to(torch.float32))
        ph, pw = x.shape[-2:]
        feats = self.encode(x.reshape(b * k, t, ph, pw), None if m is None else m.reshape(b * k, ph, pw))
        return x, feats.reshape(b, k, -1, ph, pw), (k, h, w)


# ---- input normalisation by the window's firing rate ----------------------------------------------
def window_rate_scale(window: torch.Tensor, floor_rate: float) -> torch.Tensor:
    """Each window's mean firing rate (spikes per step over its steps and pixels), at least
    `floor_rate`: window (N, T, H, W) 0/1 -> (N,). Why: the y a network must give is proportional to
    the rate (a noise-free integrate-and-fire pixel fires at a rate proportional to its light), so
    inputs divided by it, and the frame multiplied by it, make the features the same at every light
    level (model.input_norm, issue 39's lever "input normalisation by the window's firing rate")."""
    return window.float().mean(dim=(1, 2, 3)).clamp_min(floor_rate)


# ---- the refining output ------------------------------------------------------------------------
#: The refining head's gate towards the classic estimate starts at sigmoid(-4) = 1.8 %: a network
#: widened from "direct" weights (widen_head_state) starts close to that network. Its logit is
#: REFINE_GATE_GAIN times the head's channel, so the gate learns at a useful rate: at sigmoid(-6)
#: and gain 1 its gradients were near Adam's epsilon, and 400 fine-tuning steps moved the bias from
#: -6.0000 to -6.0001 (docs/model.md, "The fourth stage").
REFINE_GATE_LOGIT = -4.0
REFINE_GATE_GAIN = 16.0


#: The span gate (refine_span > 1) starts even between the span's rate and the window's TFP: the
#: classic gate, nearly closed, keeps the start close to the network it was widened from.
REFINE_SPAN_LOGIT = 0.0


def head_channels(cfg: ModelConfig) -> int:
    """The head's output channels: the frame, and for "refine" the two gates (classic vs network,
    TFP vs TFI), and a third (span vs window TFP) with refine_span > 1."""
    if cfg.output == "direct":
        return 1
    return 3 if cfg.refine_span == 1 else 4


def init_refine_gates(last: nn.Conv2d) -> None:
    """Gates start nearly closed towards the classic estimate (sigmoid(REFINE_GATE_LOGIT)) and even
    between TFP and TFI, with zero weights: the frame channel decides the first output."""
    init_gate_channels(last, 1)


def init_gate_channels(last: nn.Conv2d, first: int) -> None:
    """Gate channels `first`.. of the head's last conv at their starting logits, zero weights."""
    start = (REFINE_GATE_LOGIT, 0.0, REFINE_SPAN_LOGIT)
    with torch.no_grad():
        for ch in range(max(first, 1), last.out_channels):
            last.weight[ch].zero_()
            last.bias[ch] = start[ch - 1] / REFINE_GATE_GAIN


def trainable_parameters(model: "ReconNet", trainable: str) -> list[nn.Parameter]:
    """The parameters a run trains (train.trainable), every other one frozen: "all"; "head" (the
    head's convs, on the frozen body's features); "gates" (the gate rows of the refining head's
    last conv: its weight and bias train with the frame row's gradient held at 0, so Adam, with no
    weight decay, leaves that row, and so the network's own frame, exactly as it was)."""
    if trainable == "all":
        return list(model.parameters())
    if trainable not in TRAINABLE:
        raise ValueError(f"trainable must be one of {TRAINABLE}, got {trainable!r}")
    if trainable == "gates" and model.cfg.output != "refine":
        raise ValueError(f"training the gates alone needs a refining head (model.output 'refine'), got {model.cfg.output!r}")
    for p in model.parameters():
        p.requires_grad_(False)
    last = model.head[-1]
    params = list(model.head.parameters()) if trainable == "head" else [last.weight, last.bias]
    for p in params:
        p.requires_grad_(True)
    if trainable == "gates":
        for p in params:
            mask = torch.ones_like(p)
            mask[0] = 0.0  # channel 0 is the network's own frame (refine_parts)
            p.register_hook(lambda grad, mask=mask: grad * mask)
    return params


def classic_estimates(window: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(TFP, TFI) of each window, (N, H, W), from its spikes (N, T, H, W) 0/1."""
    return window.mean(dim=1), tfi(window != 0)


def span_rates(windows: torch.Tensor, span: int) -> torch.Tensor:
    """The mean spike rate over the `span` windows centred on each window, clipped at the
    sequence's ends: windows (B, K, T, H, W) -> (B, K, H, W). With K*T steps in all, span 5 at
    T = 41 is TFP over 205 steps, the best classic estimate where the scene is still."""
    rates = windows.float().mean(dim=2)
    return torch.stack([window_span_rate(rates, i, span) for i in range(rates.shape[1])], 1)


def window_span_rate(rates: torch.Tensor, i: int, span: int) -> torch.Tensor:
    """Mean of per-window rates (B, K, H, W) over windows [i - span//2, i + span//2] within 0..K-1;
    every window has T steps, so this is the rate over the steps they cover."""
    r = span // 2
    return rates[:, max(0, i - r): i + r + 1].mean(dim=1)


class RefineParts(NamedTuple):
    """The refining head's pieces for a batch of windows, each (N, H, W) float32: what `refine`
    blends, kept apart so a reader can see where the network trusts the window average
    (`spikesim gates`). `span_gate` is None for a head without one (refine_span == 1)."""

    frame: torch.Tensor         # Y, the output
    net: torch.Tensor           # N, the network's own frame
    classic: torch.Tensor       # C = m * TFP' + (1 - m) * TFI, TFP' the span-blended TFP
    classic_gate: torch.Tensor  # g: 1 = the frame is C, 0 = it is N
    tfp_share: torch.Tensor     # m: TFP's share of C
    span_gate: torch.Tensor | None  # s: the span's rate's share of TFP'


def refine_parts(head_out: torch.Tensor, window: torch.Tensor, span: torch.Tensor | None = None) -> RefineParts:
    """Y = g * (m * TFP + (1 - m) * TFI) + (1 - g) * N, with (N, g, m) the head's three channels
    (gates: sigmoid of REFINE_GATE_GAIN times the channel). Why: a small network that must rebuild
    a window average from its features loses to that average wherever it is already right (bright
    light, slow motion); with the average as an input to its output, matching it costs one gate,
    and the network's capacity goes to what the average gets wrong. With a fourth channel s and the
    span's rate S, TFP becomes s * S + (1 - s) * TFP: where the scene is still, the longer average."""
    net = head_out[:, 0].float()
    gate = torch.sigmoid(REFINE_GATE_GAIN * head_out[:, 1].float())
    mix = torch.sigmoid(REFINE_GATE_GAIN * head_out[:, 2].float())
    tfp_map, tfi_map = classic_estimates(window)
    still = None
    if head_out.shape[1] > 3:
        if span is None:
            raise ValueError("the head has a span gate: refine needs the span's rate (span=)")
        still = torch.sigmoid(REFINE_GATE_GAIN * head_out[:, 3].float())
        tfp_map = still * span.float() + (1 - still) * tfp_map
    classic = mix * tfp_map + (1 - mix) * tfi_map
    return RefineParts(gate * classic + (1 - gate) * net, net, classic, gate, mix, still)


def refine(head_out: torch.Tensor, window: torch.Tensor, span: torch.Tensor | None = None) -> torch.Tensor:
    """The refining head's frame Y (refine_parts says how it is made)."""
    return refine_parts(head_out, window, span).frame


def widen_head_state(state: dict[str, torch.Tensor], cfg: ModelConfig) -> dict[str, torch.Tensor]:
    """The weights of a network with a narrower head ("direct": 1 channel, "refine": 3) as one of
    `cfg` (head_channels): the head's last conv gains the missing gate channels at their starting
    logits (init_gate_channels), everything else is kept. Fine-tuning from shipped weights so starts
    at that network: a direct one blended 1.8 % (REFINE_GATE_LOGIT) with the classic estimate."""
    if cfg.output != "refine":
        raise ValueError(f"widen_head_state makes a 'refine' network's weights; the config's output is {cfg.output!r}")
    keys = [k for k in state if k.startswith("head.") and k.endswith(".weight")]
    last = max(keys, key=lambda k: int(k.split(".")[1]))
    prefix = last[: -len("weight")]
    w, b = state[prefix + "weight"], state[prefix + "bias"]
    have, want = w.shape[0], head_channels(cfg)
    if have not in (1, 3) or have >= want:
        raise ValueError(f"the weights' head gives {have} channels; widening to the config's {want} needs 1 "
                         "(a 'direct' network) or 3 (a 'refine' one without a span)")
    conv = nn.Conv2d(w.shape[1], want, 3, padding=1)
    with torch.no_grad():
        conv.weight[:have] = w
        conv.bias[:have] = b
    init_gate_channels(conv, have)
    return {**state, prefix + "weight": conv.weight.detach().clone(), prefix + "bias": conv.bias.detach().clone()}


@ARCH_REGISTRY.register("lrrep_bidirectional")
def _build_recon_net(cfg: ModelConfig) -> ReconNet:
    return ReconNet(cfg)


def build_model(cfg: ModelConfig) -> nn.Module:
    """The network a config names (ARCH_REGISTRY); refused, naming the fields, when its weights
    alone would not fit in this machine's memory (check_model_size)."""
    builder = ARCH_REGISTRY.get(cfg.arch)
    check_model_size(cfg)
    return builder(cfg)


def parameter_count(cfg: ModelConfig) -> int:
    """The network's parameters, from its config alone: built on the `meta` device (no memory)
    with 0 and 1 residual blocks; every block stack grows linearly with num_blocks."""
    import dataclasses

    builder = ARCH_REGISTRY.get(cfg.arch)

    def count(blocks: int) -> int:
        with torch.device("meta"):
            return sum(p.numel() for p in builder(dataclasses.replace(cfg, num_blocks=blocks)).parameters())
    base = count(0)
    return base + cfg.num_blocks * (count(1) - base) if cfg.num_blocks else base


def available_memory_bytes() -> int | None:
    """Memory this machine can still give (Linux MemAvailable), else its physical memory, else None."""
    import os

    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_model_size(cfg: ModelConfig, memory: int | None = None) -> int:
    """The parameter count of `cfg`; a ValueError naming the size fields when its float32 weights
    alone exceed `memory` (default: what is available now), before anything is allocated."""
    n = parameter_count(cfg)
    memory = available_memory_bytes() if memory is None else memory
    need = 4 * n
    if memory is not None and need > memory:
        raise ValueError(f"the model config asks for {n:,} parameters ({need / 2**30:,.1f} GiB of float32 weights "
                         f"alone), more than the {memory / 2**30:,.1f} GiB of memory available: model.num_features="
                         f"{cfg.num_features}, model.num_blocks={cfg.num_blocks}, model.window={cfg.window}")
    return n


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
