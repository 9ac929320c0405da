"""Spk2ImgNet (`arch: "spk2imgnet"`): Zhao et al., "Spk2ImgNet: Learning to
Reconstruct Dynamic Scene from Continuous Spike Stream", CVPR 2021; "S2I" in the LR-Rep paper's
Table 1. One frame per window, from that window alone.

The network, as the paper describes it:
  1. The window of T steps (41) is cut into five overlapping sub-windows of 13 steps, 7 apart
     (model.published_reps.sali_subwindows).
  2. Each sub-window goes through the same SALI front end (spatially adaptive light inference:
     four light estimates from its centred 13, 11, 9 and 7 steps, weighed by a learned attention,
     then a conv to C features) and the same residual feature extractor (num_blocks three-conv
     residual blocks, with a skip over the stack).
  3. The four outer sub-windows' features are aligned to the centre one with PCD alignment
     (pyramid, cascading, deformable convolution; model/pcd.py), each gated by a mask predicted from
     [aligned, centre] (conv-PReLU-conv-PReLU-conv-sigmoid).
  4. The five feature maps are concatenated and reconstructed: conv 5C -> 3C, ReLU, 3C -> C, ReLU,
     C -> 1.
Published size: C = 64, 10 residual blocks, 8 deformable groups (about 3.9 M parameters; about
2 TFLOP per 256 x 400 frame): config `s2i`.

Where this re-implementation departs from the paper:
  * The PCD module is this project's (model/pcd.py: three levels, modulated deformable convs,
    leaky ReLUs), not the authors' exact one; the deformable groups are model.deform_groups.
  * SALI is model/published_reps.py's SALIRep (its branches are C / 4 wide: Spk2ImgNet's 16 at
    C = 64; a leaky ReLU after the conv to C), kept per sub-window: SALIRep itself fuses the five
    sub-windows into one map (how the LR-Rep paper's Table 3 uses it), which would leave nothing
    to align, so `SubWindowSALI` runs its light inference and attention on each sub-window and
    ends in its own conv from that sub-window's four estimates to C features.
  * The sub-window geometry for windows other than 41 steps is SALIRep's (sali_geometry).
  * Trained with this project's loss and recipe (the config's train section), on its data; the
    paper trains with L1 on its own synthetic set.
  * Written from the paper; the authors' released code was read for the layer sizes only.
"""
from __future__ import annotations

import torch
from torch import nn

from ..blocks import conv_lrelu
from ..config import ModelConfig
from ..pcd import PCDAlign
from ..published_reps import SALI_COUNT, SALI_SCALES, SALIRep, sali_subwindows
from ..registry import ARCH_REGISTRY
from .common import PublishedNet, res_stack


class SubWindowSALI(SALIRep):
    """SALI applied to each of the five sub-windows apart: spikes (N, T, H, W) ->
    features (5 N, C, H, W), sub-window-major (rows j N .. (j + 1) N - 1 are sub-window j)."""

    def __init__(self, window: int, channels: int) -> None:
        super().__init__(window, channels)
        self.fuse = conv_lrelu(SALI_SCALES, channels)  # per sub-window: its four estimates -> C

    def forward(self, spikes: torch.Tensor, maps: torch.Tensor | None = None) -> torch.Tensor:
        n, _, h, w = spikes.shape
        sub = sali_subwindows(spikes.to(self.fuse[0].weight.dtype)).transpose(0, 1)
        sub = sub.reshape((SALI_COUNT * n,) + sub.shape[2:])
        length = sub.shape[1]
        est = torch.cat([b(sub[:, k:length - k]) for b, k in zip(self.branches, self.trims)], 1)
        return self.fuse(est * self.attention(est))


class _Gate(nn.Module):
    """A mask in (0, 1) for aligned features, from [aligned, reference]."""

    def __init__(self, c: int) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(2 * c, c, 3, padding=1), nn.PReLU(),
                                 nn.Conv2d(c, c, 3, padding=1), nn.PReLU(),
                                 nn.Conv2d(c, c, 3, padding=1), nn.Sigmoid())

    def forward(self, aligned: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        return aligned * self.net(torch.cat([aligned, reference], 1))


class Spk2ImgNet(PublishedNet):
    representation = "sali"

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        c = cfg.num_features
        self.rep = SubWindowSALI(cfg.window, c)
        self.extract = res_stack(c, cfg.num_blocks, convs=3)
        self.align = PCDAlign(c, cfg.deform_groups, cfg.deform_backend)
        self.gates = nn.ModuleList(_Gate(c) for _ in range(4))
        self.head = nn.Sequential(nn.Conv2d(5 * c, 3 * c, 3, padding=1), nn.ReLU(),
                                  nn.Conv2d(3 * c, c, 3, padding=1), nn.ReLU(),
                                  nn.Conv2d(c, 1, 3, padding=1))

    def frames(self, spikes: torch.Tensor) -> torch.Tensor:
        n, _, h, w = spikes.shape
        f = self.rep(spikes)  # (5N, C, H, W); SALI takes no precomputed map
        f = (f + self.extract(f)).reshape(SALI_COUNT, n, -1, h, w)
        centre = f[2]
        others = torch.cat([f[0], f[1], f[3], f[4]], 0)
        aligned = self.align(others, centre.repeat(4, 1, 1, 1)).reshape(4, n, -1, h, w)
        parts = [self.gates[0](aligned[0], centre), self.gates[1](aligned[1], centre), centre,
                 self.gates[2](aligned[2], centre), self.gates[3](aligned[3], centre)]
        return self.head(torch.cat(parts, 1)).squeeze(1)


@ARCH_REGISTRY.register("spk2imgnet")
def _build(cfg: ModelConfig) -> Spk2ImgNet:
    return Spk2ImgNet(cfg)
