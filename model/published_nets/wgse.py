"""WGSE (`arch: "wgse"`): Zhang et al., "Learning Temporal-Ordered
Representation for Spike Streams Based on Discrete Wavelet Transforms" (Wavelet-Guided
Spike Enhancing), AAAI 2023; "WGSE" in the LR-Rep paper's Table 1. One frame per window, from that
window alone.

The network, as the paper describes it:
  1. WGSE-1d front end (model/published_reps.py): each pixel's spike train over the window is
     decomposed by a multi-level 1-D discrete wavelet transform along time; each band is filtered
     by a small learned temporal conv net (a residual TCN layer, then a conv back to one channel),
     the bands are recombined by the inverse transform, and a 3 x 3 conv maps the T enhanced
     steps to C features: the temporal-ordered representation.
  2. Wavelet-guided enhancement in the image domain: num_blocks residual blocks of C features
     (conv-ReLU-conv, skip, ReLU).
  3. Head: conv C -> C/4, ReLU, conv C/4 -> 1.
Published size: C = 256, 3 residual blocks (about 3.8 M parameters; about 0.85 TFLOP per
256 x 400 frame): config `wgse`.

Where this re-implementation departs from the paper:
  * The head's last ReLU is dropped: a network whose output starts below zero everywhere gets no
    gradient through it; the evaluation clips negative values anyway.
  * The wavelet front end is model/published_reps.py's WGSE1dRep (db8, 5 levels, as the
    authors' best model; its departures are listed there), with the published 32-wide band
    branches, narrowed to C / 4 in networks of fewer than 128 features.
  * Trained with this project's loss and recipe, on its data.
  * Written from the paper; the authors' released code was read for the layer sizes only.
"""
from __future__ import annotations

import torch
from torch import nn

from ..config import ModelConfig
from ..registry import ARCH_REGISTRY
from ..published_reps import WGSE1dRep
from .common import PublishedNet, res_stack

#: Width of WGSE-1d's temporal conv branches in the published network (capped at C / 4 for small C).
WGSE_BAND_WIDTH = 32


class WGSE(PublishedNet):
    representation = "wgse1d"

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        c = cfg.num_features
        self.rep = WGSE1dRep(cfg.window, c, hidden=min(WGSE_BAND_WIDTH, max(1, c // 4)))
        self.enhance = res_stack(c, cfg.num_blocks)
        mid = max(1, c // 4)
        self.head = nn.Sequential(nn.Conv2d(c, mid, 3, padding=1), nn.ReLU(), nn.Conv2d(mid, 1, 3, padding=1))

    def frames(self, spikes: torch.Tensor) -> torch.Tensor:
        f = self.rep(spikes, self.rep_maps(spikes))
        return self.head(self.enhance(f)).squeeze(1)


@ARCH_REGISTRY.register("wgse")
def _build(cfg: ModelConfig) -> WGSE:
    return WGSE(cfg)
