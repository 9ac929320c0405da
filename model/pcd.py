"""PCD alignment: Pyramid, Cascading and Deformable convolution (EDVR, Wang et al. 2019), in the
three-level form of the authors' released code (docs/design.md section 5): the recurrent state
(neighbour) is aligned to the current window's features (reference)."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .blocks import LEAKY_SLOPE, conv3x3, double_conv
from .deform import Backend, ModulatedDeformConvPack


def _up2(x: torch.Tensor) -> torch.Tensor:
    return F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)


class PCDAlign(nn.Module):
    """align(neighbour, reference) -> neighbour features aligned to the reference, same shape.

    Levels L1 (full), L2 (1/2), L3 (1/4) come from two stride-2 convs shared by both inputs, so H
    and W must be divisible by 4. At each level offsets come from [neighbour, reference]; the
    coarser level's offset features are upsampled x2 and doubled (pixel units double with the
    resolution); a final cascading deformable conv refines L1.
    """

    def __init__(self, channels: int, deform_groups: int = 8, backend: Backend = "auto") -> None:
        super().__init__()
        c = channels
        self.lrelu = nn.LeakyReLU(LEAKY_SLOPE)
        # Pyramid features (shared by neighbour and reference).
        self.l2_down, self.l2_conv = conv3x3(c, c, stride=2), conv3x3(c, c)
        self.l3_down, self.l3_conv = conv3x3(c, c, stride=2), conv3x3(c, c)

        def dcn() -> ModulatedDeformConvPack:
            return ModulatedDeformConvPack(c, c, 3, padding=1, deform_groups=deform_groups, backend=backend)

        self.l3_offset = double_conv(2 * c, c)
        self.l3_dcn = dcn()
        self.l2_offset_in = conv3x3(2 * c, c)
        self.l2_offset = double_conv(2 * c, c)
        self.l2_dcn = dcn()
        self.l2_fea = conv3x3(2 * c, c)
        self.l1_offset_in = conv3x3(2 * c, c)
        self.l1_offset = double_conv(2 * c, c)
        self.l1_dcn = dcn()
        self.l1_fea = conv3x3(2 * c, c)
        self.cas_offset = double_conv(2 * c, c)
        self.cas_dcn = dcn()

    def _pyramid(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        l2 = self.lrelu(self.l2_conv(self.lrelu(self.l2_down(x))))
        l3 = self.lrelu(self.l3_conv(self.lrelu(self.l3_down(l2))))
        return x, l2, l3

    def forward(self, neighbour: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        if neighbour.shape != reference.shape:
            raise ValueError(f"PCD inputs differ in shape: {tuple(neighbour.shape)} vs {tuple(reference.shape)}")
        h, w = neighbour.shape[-2:]
        if h % 4 or w % 4:
            raise ValueError(f"PCD needs H and W divisible by 4 (two stride-2 levels), got {h}x{w}")
        # Both inputs through the shared pyramid in one batch.
        n1, n2, n3 = self._pyramid(torch.cat([neighbour, reference], 0))
        b = neighbour.shape[0]
        (nb1, rf1), (nb2, rf2), (nb3, rf3) = (t.split(b, 0) for t in (n1, n2, n3))
        # L3
        off3 = self.l3_offset(torch.cat([nb3, rf3], 1))
        fea3 = self.lrelu(self.l3_dcn(nb3, off3))
        # L2: offsets refined from the upsampled, doubled L3 offsets.
        off2 = self.lrelu(self.l2_offset_in(torch.cat([nb2, rf2], 1)))
        off2 = self.l2_offset(torch.cat([off2, _up2(off3) * 2], 1))
        fea2 = self.l2_dcn(nb2, off2)
        fea2 = self.lrelu(self.l2_fea(torch.cat([fea2, _up2(fea3)], 1)))
        # L1
        off1 = self.lrelu(self.l1_offset_in(torch.cat([nb1, rf1], 1)))
        off1 = self.l1_offset(torch.cat([off1, _up2(off2) * 2], 1))
        fea1 = self.l1_dcn(nb1, off1)
        fea1 = self.l1_fea(torch.cat([fea1, _up2(fea2)], 1))
        # Cascading: one more deformable conv with offsets from [aligned L1, reference].
        off = self.cas_offset(torch.cat([fea1, rf1], 1))
        return self.lrelu(self.cas_dcn(fea1, off))
