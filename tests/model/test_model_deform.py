"""The pure-torch deformable conv against (1) a loop implementation of torchvision's documented
sampling rule, (2) plain conv2d at zero offsets, (3) torchvision itself when it imports."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from model.deform import ModulatedDeformConvPack, deform_conv2d, deform_conv2d_torch, torchvision_deform_conv2d


def _bilinear(img: np.ndarray, y: float, x: float) -> float:
    """torchvision's rule: 0 when y <= -1, y >= H, x <= -1 or x >= W; otherwise bilinear with each
    out-of-image corner contributing 0."""
    h, w = img.shape
    if y <= -1 or y >= h or x <= -1 or x >= w:
        return 0.0
    y0, x0 = math.floor(y), math.floor(x)
    ly, lx = y - y0, x - x0
    v = 0.0
    for yy, wy in ((y0, 1 - ly), (y0 + 1, ly)):
        for xx, wx in ((x0, 1 - lx), (x0 + 1, lx)):
            if 0 <= yy < h and 0 <= xx < w:
                v += wy * wx * img[yy, xx]
    return v


def _naive(inp, off, wt, bias, stride, pad, dil, mask):
    b, cin, h, w = inp.shape
    cout, cing, kh, kw = wt.shape
    groups = cin // cing
    ho = (h + 2 * pad - dil * (kh - 1) - 1) // stride + 1
    wo = (w + 2 * pad - dil * (kw - 1) - 1) // stride + 1
    og = off.shape[1] // (2 * kh * kw)
    out = np.zeros((b, cout, ho, wo))
    for n in range(b):
        for co in range(cout):
            g = co // (cout // groups)
            for y in range(ho):
                for x in range(wo):
                    acc = bias[co]
                    for ci in range(cing):
                        c = g * cing + ci
                        o = c // (cin // og)
                        for i in range(kh):
                            for j in range(kw):
                                k = i * kw + j
                                dy, dx = off[n, 2 * (o * kh * kw + k), y, x], off[n, 2 * (o * kh * kw + k) + 1, y, x]
                                val = _bilinear(inp[n, c], y * stride - pad + i * dil + dy,
                                                x * stride - pad + j * dil + dx)
                                acc += wt[co, ci, i, j] * mask[n, o * kh * kw + k, y, x] * val
                    out[n, co, y, x] = acc
    return out


CASES = [  # stride, pad, dil, groups, offset groups
    (1, 1, 1, 1, 2),
    (2, 1, 1, 2, 4),
    (1, 2, 2, 2, 1),
]


def _random_case(stride, pad, dil, groups, og, seed=0, b=2, cin=4, h=5, w=6, cout=6):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(b, cin, h, w, generator=g, dtype=torch.float64)
    wt = torch.randn(cout, cin // groups, 3, 3, generator=g, dtype=torch.float64)
    bias = torch.randn(cout, generator=g, dtype=torch.float64)
    ho = (h + 2 * pad - dil * 2 - 1) // stride + 1
    wo = (w + 2 * pad - dil * 2 - 1) // stride + 1
    off = torch.randn(b, 2 * og * 9, ho, wo, generator=g, dtype=torch.float64) * 2  # reaches outside
    mask = torch.rand(b, og * 9, ho, wo, generator=g, dtype=torch.float64)
    return x, off, wt, bias, mask


@pytest.mark.parametrize("stride,pad,dil,groups,og", CASES)
def test_matches_loop_reference(stride, pad, dil, groups, og):
    x, off, wt, bias, mask = _random_case(stride, pad, dil, groups, og)
    out = deform_conv2d_torch(x, off, wt, bias, stride, pad, dil, mask)
    ref = _naive(x.numpy(), off.numpy(), wt.numpy(), bias.numpy(), stride, pad, dil, mask.numpy())
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-10)


@pytest.mark.parametrize("groups", [1, 2])
def test_zero_offset_unit_mask_is_conv2d(groups):
    g = torch.Generator().manual_seed(1)
    x = torch.randn(2, 8, 9, 7, generator=g)
    wt = torch.randn(6, 8 // groups, 3, 3, generator=g)
    bias = torch.randn(6, generator=g)
    off = torch.zeros(2, 2 * 4 * 9, 9, 7)
    out = deform_conv2d_torch(x, off, wt, bias, 1, 1, 1, torch.ones(2, 4 * 9, 9, 7))
    ref = F.conv2d(x, wt, bias, padding=1, groups=groups)
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-5)
    # mask=None means unit mask
    torch.testing.assert_close(deform_conv2d_torch(x, off, wt, bias, 1, 1, 1), ref, atol=1e-5, rtol=1e-5)


def test_integer_offset_is_a_shifted_conv():
    g = torch.Generator().manual_seed(2)
    x = torch.randn(1, 2, 8, 8, generator=g, dtype=torch.float64)
    wt = torch.randn(3, 2, 3, 3, generator=g, dtype=torch.float64)
    off = torch.zeros(1, 18, 8, 8, dtype=torch.float64)
    off[:, 1::2] = 1.0  # every tap one column to the right
    out = deform_conv2d_torch(x, off, wt, None, 1, 1, 1)
    # Tap (i, j) of output (y, x) now reads input (y - 1 + i, x + j): zero padding of one row above
    # and below, none on the left, two columns on the right, then a valid conv.
    ref = F.conv2d(F.pad(x, (0, 2, 1, 1)), wt)
    torch.testing.assert_close(out, ref)


def test_gradients_flow_to_all_inputs():
    x, off, wt, bias, mask = _random_case(1, 1, 1, 1, 2, seed=3, b=1, cin=2, h=4, w=3, cout=2)
    for t in (x, off, wt, bias, mask):
        t.requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda a, o, w_, b_, m: deform_conv2d_torch(a, o, w_, b_, 1, 1, 1, m), (x, off, wt, bias, mask),
        eps=1e-6, atol=1e-5)


def test_shape_errors_are_named():
    x = torch.zeros(1, 4, 5, 5)
    w = torch.zeros(4, 4, 3, 3)
    with pytest.raises(ValueError, match="offset must be"):
        deform_conv2d_torch(x, torch.zeros(1, 17, 5, 5), w, None, 1, 1, 1)
    with pytest.raises(ValueError, match="mask must be"):
        deform_conv2d_torch(x, torch.zeros(1, 18, 5, 5), w, None, 1, 1, 1, torch.ones(1, 8, 5, 5))
    with pytest.raises(ValueError, match="backend"):
        deform_conv2d(x, torch.zeros(1, 18, 5, 5), w, backend="cuda")


def test_pack_starts_as_plain_conv_with_half_mask():
    """Zero-initialised offset conv: zero offsets and sigmoid(0) = 0.5 masks."""
    pack = ModulatedDeformConvPack(8, 6, deform_groups=4, backend="torch")
    nn_bias = torch.randn(6)
    pack.bias.data.copy_(nn_bias)
    x, feat = torch.randn(2, 8, 6, 6), torch.randn(2, 8, 6, 6)
    ref = 0.5 * F.conv2d(x, pack.weight, None, padding=1) + nn_bias.view(1, -1, 1, 1)
    torch.testing.assert_close(pack(x, feat), ref, atol=1e-5, rtol=1e-5)
    with pytest.raises(ValueError, match="deform_groups"):
        ModulatedDeformConvPack(6, 6, deform_groups=4)


@pytest.mark.skipif(torchvision_deform_conv2d() is None,
                    reason="torchvision.ops does not import beside this torch (no matching CPU build); "
                           "the pure-torch path is checked against a loop reference instead")
@pytest.mark.parametrize("stride,pad,dil,groups,og", CASES)
def test_matches_torchvision(stride, pad, dil, groups, og):
    x, off, wt, bias, mask = _random_case(stride, pad, dil, groups, og, seed=7)
    for t in (x, off, wt, bias, mask):
        t.requires_grad_(True)
    tv = torchvision_deform_conv2d()
    a = tv(x, off, wt, bias, stride=(stride, stride), padding=(pad, pad), dilation=(dil, dil), mask=mask)
    b = deform_conv2d_torch(x, off, wt, bias, stride, pad, dil, mask)
    torch.testing.assert_close(a, b)
    ga = torch.autograd.grad(a.sum(), (x, off, wt, mask))
    gb = torch.autograd.grad(b.sum(), (x, off, wt, mask))
    for u, v in zip(ga, gb):
        torch.testing.assert_close(u, v)
