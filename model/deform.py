"""Modulated deformable convolution (DCNv2) in pure torch, with torchvision's operator when present.

Semantics follow torchvision.ops.deform_conv2d exactly (Zhu et al., DCNv2, 2019):
- input (B, C_in, H, W); weight (C_out, C_in / groups, kh, kw);
- offset (B, 2 * offset_groups * kh * kw, H_out, W_out): for offset group g and kernel tap
  k = i * kw + j, channel 2 * (g * kh * kw + k) is the row shift dy and the next one the column
  shift dx;
- mask (B, offset_groups * kh * kw, H_out, W_out), channel g * kh * kw + k, multiplies the sample;
- tap (i, j) of output (y, x) samples the input bilinearly at
  (y * stride_h - pad_h + i * dil_h + dy, x * stride_w - pad_w + j * dil_w + dx), with zeros
  outside the image (each of the four bilinear corners that falls outside contributes zero).
The pure-torch path samples with grid_sample (zeros padding, align_corners=False, whose
un-normalisation maps the normalised coordinate back to exactly that pixel position), which
implements the same bilinear rule, so it also gives the same gradients.
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.modules.utils import _pair

Backend = Literal["auto", "torch", "torchvision"]


@lru_cache(maxsize=1)
def torchvision_deform_conv2d():
    """torchvision.ops.deform_conv2d if torchvision imports beside this torch, else None."""
    try:
        from torchvision.ops import deform_conv2d  # type: ignore[import-not-found]
    except Exception:  # a torchvision built for another torch fails with assorted errors
        return None
    return deform_conv2d


def _out_size(size: int, k: int, stride: int, pad: int, dil: int) -> int:
    return (size + 2 * pad - dil * (k - 1) - 1) // stride + 1


def deform_conv2d_torch(input: torch.Tensor, offset: torch.Tensor, weight: torch.Tensor,
                        bias: torch.Tensor | None = None, stride: int | tuple[int, int] = 1,
                        padding: int | tuple[int, int] = 0, dilation: int | tuple[int, int] = 1,
                        mask: torch.Tensor | None = None) -> torch.Tensor:
    """Pure-torch twin of torchvision.ops.deform_conv2d (same arguments, same layout)."""
    sh, sw = _pair(stride)
    ph, pw = _pair(padding)
    dh, dw = _pair(dilation)
    b, c_in, h, w = input.shape
    c_out, c_in_g, kh, kw = weight.shape
    if c_in % c_in_g:
        raise ValueError(f"weight has {c_in_g} input channels per group, which does not divide "
                         f"the input's {c_in} channels")
    groups = c_in // c_in_g
    if c_out % groups:
        raise ValueError(f"{c_out} output channels are not divisible by {groups} groups")
    taps = kh * kw
    ho, wo = _out_size(h, kh, sh, ph, dh), _out_size(w, kw, sw, pw, dw)
    if offset.shape[0] != b or offset.shape[1] % (2 * taps) or tuple(offset.shape[2:]) != (ho, wo):
        raise ValueError(f"offset must be (B={b}, 2*offset_groups*{taps}, {ho}, {wo}), "
                         f"got {tuple(offset.shape)}")
    og = offset.shape[1] // (2 * taps)
    if c_in % og:
        raise ValueError(f"{og} offset groups do not divide the input's {c_in} channels")
    if mask is None:
        mask = input.new_ones(b, og * taps, ho, wo)
    elif tuple(mask.shape) != (b, og * taps, ho, wo):
        raise ValueError(f"mask must be (B={b}, {og * taps}, {ho}, {wo}), got {tuple(mask.shape)}")

    # Positions and sampling in float32 at least: under fp16 autocast a 400-pixel coordinate would
    # only resolve quarter pixels. The result is cast back to the input's dtype.
    out_dtype = input.dtype
    dt = torch.promote_types(input.dtype, torch.float32)
    input, offset, mask, weight = input.to(dt), offset.to(dt), mask.to(dt), weight.to(dt)
    bias = None if bias is None else bias.to(dt)
    # Sampling positions in pixels, per (offset group, tap): base grid + learned offset.
    dev = input.device
    ys = (torch.arange(ho, device=dev, dtype=dt) * sh - ph).view(1, 1, ho, 1)
    xs = (torch.arange(wo, device=dev, dtype=dt) * sw - pw).view(1, 1, 1, wo)
    ki = (torch.arange(kh, device=dev, dtype=dt) * dh).repeat_interleave(kw).view(1, taps, 1, 1)
    kj = (torch.arange(kw, device=dev, dtype=dt) * dw).repeat(kh).view(1, taps, 1, 1)
    off = offset.view(b, og, taps, 2, ho, wo)
    py = ys + ki + off[:, :, :, 0]  # (B, og, taps, Ho, Wo)
    px = xs + kj + off[:, :, :, 1]
    # grid_sample with align_corners=False maps normalised u to pixel ((u + 1) * size - 1) / 2.
    grid = torch.stack(((2 * px + 1) / w - 1, (2 * py + 1) / h - 1), dim=-1)
    grid = grid.view(b * og, taps * ho, wo, 2)
    sampled = F.grid_sample(input.reshape(b * og, c_in // og, h, w), grid, mode="bilinear",
                            padding_mode="zeros", align_corners=False)  # (B*og, C/og, taps*Ho, Wo)
    sampled = sampled.view(b, og, c_in // og, taps, ho, wo) * mask.view(b, og, 1, taps, ho, wo)
    # Columns ordered (C_in, taps) to match weight.view(C_out, C_in/groups * taps).
    cols = sampled.reshape(b, groups, c_in_g * taps, ho * wo)
    wmat = weight.reshape(groups, c_out // groups, c_in_g * taps)
    out = torch.einsum("goc,bgcl->bgol", wmat, cols).reshape(b, c_out, ho, wo)
    if bias is not None:
        out = out + bias.view(1, -1, 1, 1)
    return out.to(out_dtype)


def deform_conv2d(input: torch.Tensor, offset: torch.Tensor, weight: torch.Tensor,
                  bias: torch.Tensor | None = None, stride: int | tuple[int, int] = 1,
                  padding: int | tuple[int, int] = 0, dilation: int | tuple[int, int] = 1,
                  mask: torch.Tensor | None = None, backend: Backend = "auto") -> torch.Tensor:
    """Modulated deformable conv2d: torchvision's kernel when it imports ("auto"), else pure torch."""
    if backend not in ("auto", "torch", "torchvision"):
        raise ValueError(f"backend must be 'auto', 'torch' or 'torchvision', got {backend!r}")
    tv = torchvision_deform_conv2d() if backend != "torch" else None
    if backend == "torchvision" and tv is None:
        raise RuntimeError("backend='torchvision' asked for, but torchvision.ops does not import here")
    fn = tv if tv is not None else deform_conv2d_torch
    return fn(input, offset, weight, bias, stride=_pair(stride), padding=_pair(padding),
              dilation=_pair(dilation), mask=mask)


class ModulatedDeformConvPack(nn.Module):
    """DCNv2 whose offsets and masks are predicted from separate features (EDVR's DCNv2Pack;
    the authors' DCN_sep).

    A conv on `feat` gives 3 * deform_groups * kh * kw channels: two halves of offsets and one of
    mask logits (sigmoid). That conv starts at zero, so training starts from a plain conv (zero
    offsets, mask 0.5), as in EDVR and the authors' code.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 3, padding: int = 1,
                 deform_groups: int = 8, offset_in_channels: int | None = None,
                 backend: Backend = "auto") -> None:
        super().__init__()
        if in_channels % deform_groups:
            raise ValueError(f"deform_groups={deform_groups} must divide in_channels={in_channels}")
        self.kernel_size = _pair(kernel_size)
        self.padding = _pair(padding)
        self.deform_groups = deform_groups
        self.backend: Backend = backend
        self.weight = nn.Parameter(torch.empty(out_channels, in_channels, *self.kernel_size))
        self.bias = nn.Parameter(torch.empty(out_channels))
        taps = self.kernel_size[0] * self.kernel_size[1]
        self.conv_offset_mask = nn.Conv2d(offset_in_channels or in_channels, 3 * deform_groups * taps,
                                          self.kernel_size, padding=self.padding)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Uniform(+-1/sqrt(fan_in)) weights, zero bias, zero offset conv (DCNv2 reference init)."""
        fan_in = self.weight.shape[1] * self.kernel_size[0] * self.kernel_size[1]
        bound = 1.0 / math.sqrt(fan_in)
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.zeros_(self.bias)
        nn.init.zeros_(self.conv_offset_mask.weight)
        nn.init.zeros_(self.conv_offset_mask.bias)

    def forward(self, x: torch.Tensor, feat: torch.Tensor) -> torch.Tensor:
        o1, o2, mask = torch.chunk(self.conv_offset_mask(feat), 3, dim=1)
        offset = torch.cat((o1, o2), dim=1)
        return deform_conv2d(x, offset, self.weight, self.bias, padding=self.padding,
                             mask=torch.sigmoid(mask), backend=self.backend)
