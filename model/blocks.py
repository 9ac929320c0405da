"""Small building blocks shared by the representation, fusion and head (docs/design.md section 5)."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

LEAKY_SLOPE = 0.1  # every leaky ReLU in the authors' network


def conv3x3(in_ch: int, out_ch: int, bias: bool = True, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_ch, out_ch, 3, stride=stride, padding=1, bias=bias)


def conv_lrelu(in_ch: int, out_ch: int, stride: int = 1) -> nn.Sequential:
    """3x3 conv + leaky ReLU(0.1): the spike / interval branches and the fusion entry."""
    return nn.Sequential(conv3x3(in_ch, out_ch, stride=stride), nn.LeakyReLU(LEAKY_SLOPE))


def double_conv(in_ch: int, out_ch: int, mid_ch: int | None = None) -> nn.Sequential:
    """conv-lrelu-conv-lrelu, used for PCD offsets and as the head's first two layers."""
    mid = mid_ch or out_ch
    return nn.Sequential(conv_lrelu(in_ch, mid), conv_lrelu(mid, out_ch))


class ResidualBlock(nn.Module):
    """x + conv(relu(conv(x))), no batch norm; weights Kaiming-normal scaled by 0.1 so a deep
    stack starts close to the identity (docs/design.md section 5; EDVR / BasicSR ResidualBlockNoBN)."""

    def __init__(self, channels: int, init_scale: float = 0.1) -> None:
        super().__init__()
        self.conv1 = conv3x3(channels, channels)
        self.conv2 = conv3x3(channels, channels)
        self.relu = nn.ReLU()
        for conv in (self.conv1, self.conv2):
            nn.init.kaiming_normal_(conv.weight)
            conv.weight.data.mul_(init_scale)
            nn.init.zeros_(conv.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(self.relu(self.conv1(x)))


def residual_stack(channels: int, num_blocks: int) -> nn.Sequential:
    """The "16-layer ResNet" f (paper, Fusion and Reconstruction): num_blocks residual blocks."""
    return nn.Sequential(*(ResidualBlock(channels) for _ in range(num_blocks)))


def padded_size(h: int, w: int, multiple: int) -> tuple[int, int]:
    """(h, w) rounded up to multiples of `multiple` (the stride-2 levels of PCD or a U-Net need it)."""
    return -(-h // multiple) * multiple, -(-w // multiple) * multiple


def pad_to_multiple(x: torch.Tensor, multiple: int) -> torch.Tensor:
    """Replicate-pad the last two dims up to multiples of `multiple` (250 -> 252 rows for 4); the
    networks crop their output back, so padding never reaches a frame."""
    h, w = x.shape[-2:]
    ph, pw = padded_size(h, w, multiple)
    if (ph, pw) == (h, w):
        return x
    lead = x.shape[:-2]
    y = F.pad(x.reshape((-1, 1, h, w)), (0, pw - w, 0, ph - h), mode="replicate")
    return y.reshape(lead + (ph, pw))
