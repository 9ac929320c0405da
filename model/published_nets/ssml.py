"""SSML (`arch: "ssml"`): Chen et al., "Self-Supervised Mutual Learning for
Dynamic Scene Reconstruction of Spiking Camera", IJCAI 2022; "SSML" in the LR-Rep paper's
Table 1. Trained from spikes alone, with no ground truth: train.loss "self_supervised".

The network, as the paper describes it, two branches learning from each other:
  * a representation branch, the reconstruction used at inference: the AMIM front end
    (model/published_reps.py) to C features, num_blocks residual blocks, head conv C -> C, ReLU,
    conv C -> 1; one frame per window, from that window alone;
  * a blind-spot branch (BSN): sees the window's spikes around each pixel but never the pixel
    itself, so it can be trained to predict the pixel's own noisy light estimate without learning
    to copy it (Noise2Void / Laine et al. 2019 construction: one stack of num_blocks + 1
    "upward" convolutions, whose receptive field at a pixel covers only the rows above it, run
    on the input rotated four ways with shared weights, each result shifted one row so its own
    row is excluded, then combined by 1 x 1 convs).
The loss (`self_supervised_loss`), per window, every term divided by the sample's light level
(as l1_sum_relative), summed over windows:
    |BSN - TFP|^2                 the blind spot against the window's firing rate, an unbiased,
                                   pixel-independent noisy estimate of the light (squared error:
                                   its minimiser is the mean, not the median of a few spikes)
  + |R - stop_grad(BSN)|          the representation branch learns from the blind spot's
                                   denoised estimate ...
  + MUTUAL_WEIGHT * |BSN - stop_grad(R)|   ... and the blind spot from the representation branch.
Config `ssml`: 96 features, 8 blocks, 2.2 M parameters (published: 2.4 M).

Where this re-implementation departs from the paper:
  * Written from the paper's description alone (the authors' code was not available to read):
    the BSN's depth and width, the loss weights and the squared/absolute split are this
    project's choices; the paper's motion-aligned refinement inside the interval branch is not
    reproduced beyond what the AMIM front end does.
  * The blind-spot target is the window's TFP on the y scale rather than the paper's
    interval-based estimate.
  * Inference runs the representation branch only (the BSN is a training device here), so the
    inference FLOP count excludes the BSN.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..blocks import LEAKY_SLOPE
from ..config import ModelConfig
from ..registry import ARCH_REGISTRY
from .common import PublishedNet, front_end, res_stack

#: Weight of the blind spot's term towards the representation branch.
MUTUAL_WEIGHT = 0.1
#: The light level below which the loss stops dividing (as model/losses.py's relative loss).
LEVEL_FLOOR = 1e-3


class BlindSpotNet(nn.Module):
    """(N, C_in, H, W) -> (N, H, W); output pixel (i, j) never depends on input pixel (i, j)."""

    def __init__(self, in_ch: int, c: int, layers: int) -> None:
        super().__init__()
        self.convs = nn.ModuleList(nn.Conv2d(in_ch if i == 0 else c, c, 3) for i in range(layers))
        self.combine = nn.Sequential(nn.Conv2d(4 * c, c, 1), nn.LeakyReLU(LEAKY_SLOPE),
                                     nn.Conv2d(c, c, 1), nn.LeakyReLU(LEAKY_SLOPE), nn.Conv2d(c, 1, 1))

    def upper(self, x: torch.Tensor) -> torch.Tensor:
        """Features whose receptive field at row i covers rows < i only."""
        for conv in self.convs:  # padded 2 rows on top, none below: row i sees rows i-2..i
            x = F.leaky_relu(conv(F.pad(x, (1, 1, 2, 0))), LEAKY_SLOPE)
        return F.pad(x, (0, 0, 1, 0))[..., :-1, :]  # shift down one row: rows < i

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        parts = [torch.rot90(self.upper(torch.rot90(x, k, (2, 3))), -k, (2, 3)) for k in range(4)]
        return self.combine(torch.cat(parts, 1)).squeeze(1)


class SSML(PublishedNet):
    representation = "amim"

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        c = cfg.num_features
        self.rep = front_end("amim", cfg.window, c)
        self.body = res_stack(c, cfg.num_blocks)
        self.head = nn.Sequential(nn.Conv2d(c, c, 3, padding=1), nn.ReLU(), nn.Conv2d(c, 1, 3, padding=1))
        self.bsn = BlindSpotNet(cfg.window, c, cfg.num_blocks + 1)

    def frames(self, spikes: torch.Tensor) -> torch.Tensor:
        f = self.rep(spikes, self.rep_maps(spikes))
        return self.head(self.body(f)).squeeze(1)

    def self_supervised_loss(self, spikes: torch.Tensor) -> torch.Tensor:
        """The training loss from spikes (B, K, T, H, W) alone (see the module docstring)."""
        self.check_input(spikes)
        b, k, t, h, w = spikes.shape
        x = spikes.to(torch.float32).reshape(b * k, t, h, w)
        rep = self.frames(self.pad(x))[..., :h, :w].float()
        blind = self.bsn(x).float()  # unpadded: a replicated border would show a pixel to itself
        target = x.mean(1)
        level = target.flatten(1).mean(1).clamp_min(LEVEL_FLOOR)[:, None, None]
        loss = ((blind - target) / level).square().mean()
        loss = loss + ((rep - blind.detach()).abs() / level).mean()
        loss = loss + MUTUAL_WEIGHT * ((blind - rep.detach()).abs() / level).mean()
        return k * loss  # summed over the K windows, as l1_sum


@ARCH_REGISTRY.register("ssml")
def _build(cfg: ModelConfig) -> SSML:
    return SSML(cfg)
