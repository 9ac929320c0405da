"""The per-window representation in front of the feature extractor (paper, Light-robust
Representation; docs/design.md section 5), and its ablation stand-ins (spike branch alone, TFP, TFI;
the published methods' representations are in model/published_reps.py)."""
from __future__ import annotations

import torch
from torch import nn

from .blocks import LEAKY_SLOPE, conv3x3, conv_lrelu
from .config import ModelConfig
from .published_reps import PUBLISHED_REPS


class LRRep(nn.Module):
    """Rep = a * F_S + (1 - a) * F_G (paper eq. Rep = beta*F_G + alpha*F_S with beta = 1 - alpha,
    as the authors compute it): F_S from the spike window (T -> C conv, leaky 0.1), F_G from the
    interval map (1 -> C conv, leaky 0.1), a from an attention block of three bias-free 3x3 convs
    (2C -> C -> C -> 1; leaky, leaky, sigmoid)."""

    def __init__(self, window: int, channels: int) -> None:
        super().__init__()
        self.spike_branch = conv_lrelu(window, channels)
        self.interval_branch = conv_lrelu(1, channels)
        self.attention = nn.Sequential(
            conv3x3(2 * channels, channels, bias=False), nn.LeakyReLU(LEAKY_SLOPE),
            conv3x3(channels, channels, bias=False), nn.LeakyReLU(LEAKY_SLOPE),
            conv3x3(channels, 1, bias=False), nn.Sigmoid())

    def forward(self, spikes: torch.Tensor, interval: torch.Tensor | None) -> torch.Tensor:
        if interval is None:
            raise ValueError("LR-Rep needs the interval map (GISI or LISI) of each window")
        f_s = self.spike_branch(spikes)
        f_g = self.interval_branch(interval)
        alpha = self.attention(torch.cat([f_s, f_g], 1))
        return alpha * f_s + (1 - alpha) * f_g


class SpikeRep(nn.Module):
    """Ablation "without LR-Rep": the spike-window branch alone (T -> C conv, leaky)."""

    def __init__(self, window: int, channels: int) -> None:
        super().__init__()
        self.spike_branch = conv_lrelu(window, channels)

    def forward(self, spikes: torch.Tensor, interval: torch.Tensor | None) -> torch.Tensor:
        return self.spike_branch(spikes)


class MapRep(nn.Module):
    """Paper Table 3: a one-channel representation (TFP or TFI) through a conv in LR-Rep's place."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.map_branch = conv_lrelu(1, channels)

    def forward(self, spikes: torch.Tensor, interval: torch.Tensor | None) -> torch.Tensor:
        if interval is None:
            raise ValueError("this representation needs its map (TFP or TFI) of each window")
        return self.map_branch(interval)


def build_representation(cfg: ModelConfig) -> nn.Module:
    if cfg.representation == "lr_rep":
        return LRRep(cfg.window, cfg.num_features)
    if cfg.representation == "spike":
        return SpikeRep(cfg.window, cfg.num_features)
    if cfg.representation in PUBLISHED_REPS:  # AST, AMIM, SALI, WGSE-1d (model/published_reps.py)
        return PUBLISHED_REPS[cfg.representation](cfg.window, cfg.num_features)
    return MapRep(cfg.num_features)
