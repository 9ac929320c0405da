"""Four per-window representations from published spike-camera reconstruction methods, re-implemented
to be swapped into ReconNet in LR-Rep's place (paper, "Comparison with other representation",
Table 3: AST, AMIM, SALI, WGSE-1d), and imported by the Table-1 re-implementations of their networks.

Every representation sees one window of T steps (41 in the paper) and nothing else, so chunked
streaming inference (model/streaming.py) equals one-shot inference. Each module is
`Rep(window, channels)` with `forward(spikes (N, T, H, W) float 0/1, maps (N, 1, H, W) | None)
-> (N, channels, H, W)`; `published_input_map` gives the one-channel map a representation wants
precomputed per window (only AMIM's windowed TFI; None for the others, which compute everything
from the spike window inside forward). The non-learned parts are the pure functions below.

AST (Zhu et al., "Recurrent spike-based image restoration under general illumination", ACM MM
2023, RSIR, its adaptive spike transformation module). RSIR turns the spike stream into spike-number
maps, counting over a temporal span that adapts to the light: a short span where light is strong,
a long one where it is weak, so a dark pixel still collects enough spikes to be estimated.
Here (`ast_counts`, `ast_maps`): per pixel, the span is the shortest one centred on the window's
centre that holds at least n spikes (n in AST_TARGETS = 1, 2, 4, 8), capped at the whole window;
each n gives the count / span (a rate on the y scale) and the span / T. The 8 maps go through three
3x3 convs (8 -> C -> C -> C, leaky 0.1). Departures: RSIR chooses its window from the light level of
the stream (a longer one for darker streams) and counts over successive spans longer than our
window; we choose per pixel by a spike-count stopping rule, stay inside the 41-step window, give
several targets at once, and replace RSIR's noise-modelling (NIM) and wavelet recurrent network by
the convs above.

AMIM (Chen et al., "Self-supervised mutual learning for dynamic scene reconstruction of spiking
camera", IJCAI 2022, SSML, the motion-inference module in front of its denoisers; published code
`MotionInference`). It fuses two light estimates: "learned TFP" maps, bias-free 1x1 convs over
centred spans of 11, 19 and 27 steps (AMIM_TFP_SPANS), and a TFI map looked for within 12 steps of
the centre (AMIM_TFI_RADIUS, `amim_tfi`); each goes through a 3x3 conv to 16 channels, a shared
CBAM spatial gate (channel max and mean -> 7x7 conv -> sigmoid), the two are summed, and a CBAM
channel gate (global mean and max pooling -> shared MLP 16 -> 4 -> 16 -> sigmoid) reweighs them.
As in SSML, whose first denoiser layer sees the spike window beside these 16 features, the output
is a 3x3 conv (T + 16 -> C, leaky 0.1) of both. Departures: SSML's convs use replicate padding
and no bias, ours zero padding and bias (the spatial gate's conv excepted); the spatial gate has no batch norm;
the TFI's sides without a spike take the step just past the search range (SSML: the range's own
ends); SSML applies AMIM to three 27-step sub-windows, we apply it once to the 41-step window.

SALI (Zhao et al., "Spk2ImgNet: learning to reconstruct dynamic scene from continuous spike
stream", CVPR 2021, its spatially adaptive light inference subnet). The window is cut into 5
overlapping sub-windows of 13 steps, 7 apart (`sali_subwindows`, Spk2ImgNet's win_r = 6,
win_step = 7); on each, four branches see the centred 13, 11, 9 and 7 steps (multi-scale light
inference: conv 3x3 -> hidden, ReLU, conv 3x3 -> 1), and a learned attention (conv 4 -> 8, ReLU,
conv 8 -> 4, sigmoid) weighs the four estimates per pixel; weights are shared by the sub-windows.
The 5 x 4 weighted estimates go through a 3x3 conv to C channels (leaky 0.1). Departures: the
branches are hidden = C / 4 wide (Spk2ImgNet: 16; equal at C = 64); Spk2ImgNet turns each
sub-window into 64 deep features (12 residual blocks), aligns the sub-windows (PCD) and fuses
them with masks, where we fuse the 20 estimates by one conv and leave depth to ReconNet's ResNet.

WGSE-1d (Zhang et al., "Learning temporal-ordered representation for spike streams based on
discrete wavelet transforms", AAAI 2023, WGSE, the 1-D DWT module). Each pixel's spike train is
decomposed by a multi-level 1-D discrete wavelet transform along time (`wavelet_coefficients_1d`,
PyWavelets' filters, zero padding, db8 and 5 levels as in WGSE's released configuration); the
approximation and every level's details go through their own temporal conv branch (a residual TCN
layer 1 -> hidden -> hidden, ReLU, and a conv hidden -> 1, all kernels 3 along time, applied to
every pixel's coefficient sequence), the inverse transform (`wavelet_reconstruct_1d`) brings the
enhanced coefficients back to a train of T steps, and a 3x3 conv (T -> C, leaky 0.1) fuses it.
Departures: branches are hidden = C / 4 wide (WGSE: 32); a branch's output is linear (WGSE: ReLU,
which clips negative detail coefficients); the inverse transform's extra last step (42 for 41) is
dropped; WGSE's 256-channel conv and residual blocks after it are ReconNet's job here.

Cost (torch.utils.flop_counter.FlopCounterMode on one (1, 41, 64, 64) window; FLOP counts a
multiply-add as 2; LR-Rep with its interval map):

                        channels = 16 (lrrep_cpu)             channels = 64 (paper)
    representation   parameters  GFLOP/window  x LR-Rep   parameters  GFLOP/window  x LR-Rep
    LR-Rep (LRRep)       13,136      0.107        1.00       135,488      1.109        1.00
    AST                   5,808      0.047        0.44        78,528      0.642        0.58
    AMIM                  9,135      0.074        0.69        33,807      0.276        0.25
    SALI                  5,088      0.112        1.04        18,576      0.377        0.34
    WGSE-1d               6,406      0.166        1.55        29,062      1.045        0.94

(`representation_cost` measures them; tests/test_published_reps.py checks the channels = 16 column.)
"""
from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from .blocks import conv3x3, conv_lrelu
from .representations import _check_spikes, tfi

#: AST's spike-count targets: one span per target, n spikes or the whole window.
AST_TARGETS: tuple[int, ...] = (1, 2, 4, 8)
#: AMIM's learned-TFP spans (steps, centred) and TFI search radius (SSML's released code).
AMIM_TFP_SPANS: tuple[int, ...] = (11, 19, 27)
AMIM_TFI_RADIUS = 12
AMIM_WIDTH = 16
#: SALI's sub-windows (Spk2ImgNet: 2 * win_r + 1 = 13 steps, win_step = 7, five of them) and scales.
SALI_LENGTH, SALI_COUNT, SALI_SCALES = 13, 5, 4
#: WGSE-1d's wavelet and levels (WGSE's released "db8-5" configuration).
WGSE_WAVELET, WGSE_LEVELS = "db8", 5


def _window_spikes(spikes: torch.Tensor, what: str) -> torch.Tensor:
    """A module's float 0/1 window as bool for the pure functions; on the `meta` device (cost
    counting, model/flops.py) values cannot be checked, so only compared with zero."""
    return spikes != 0 if spikes.is_meta else _check_spikes(spikes, 4, 4, what)


def _check_window_tensor(spikes: torch.Tensor, window: int, what: str) -> None:
    if not isinstance(spikes, torch.Tensor):
        raise TypeError(f"{what}: spikes must be a torch.Tensor, got {type(spikes).__name__}")
    if spikes.dim() != 4 or spikes.shape[1] != window:
        raise ValueError(f"{what}: spikes must be (N, T={window}, H, W), got shape {tuple(spikes.shape)}")


# ---------------------------------------------------------------------------------------------
# AST (RSIR): light-adaptive spike counts
# ---------------------------------------------------------------------------------------------

def ast_counts(spikes: torch.Tensor, target: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per pixel, the spikes in the shortest span centred on the window's centre that holds at least
    `target` of them, and that span's length (RSIR's adaptive spike transformation: strong light
    fills a short span, weak light needs a long one, so the count's noise stays similar).

    With c = T // 2 the spans are [c - r, c + r] for r = 0 .. c (lengths 1, 3, ..., T); a pixel that
    never reaches `target` in the window gets the whole window (its count may be below target).
    spikes: (..., T, H, W) with T odd, bool / uint8 / float 0-1, 3 to 5 dims. Returns int64
    (count, span), each (..., H, W).
    """
    s = _check_spikes(spikes, 3, 5, "ast_counts")
    if isinstance(target, bool) or not isinstance(target, int) or target < 1:
        raise ValueError(f"ast_counts: target must be a positive integer number of spikes, got {target!r}")
    t = s.shape[-3]
    if t % 2 == 0:
        raise ValueError(f"ast_counts: the window must have an odd number of steps (2*dt + 1) so spans "
                         f"centre on it, got T = {t}")
    c = t // 2
    csum = torch.cumsum(s.to(torch.int32), dim=-3)
    csum = torch.cat([torch.zeros_like(csum.narrow(-3, 0, 1)), csum], dim=-3)  # csum[k] = spikes in [0, k)
    r = torch.arange(c + 1, device=s.device)
    count = csum.index_select(-3, c + r + 1) - csum.index_select(-3, c - r)  # (..., c + 1, H, W)
    reached = count >= target
    first = reached.to(torch.uint8).argmax(dim=-3)
    radius = torch.where(reached.any(dim=-3), first, torch.full_like(first, c))
    n = count.gather(-3, radius.unsqueeze(-3)).squeeze(-3)
    return n.to(torch.int64), (2 * radius + 1).to(torch.int64)


def ast_maps(spikes: torch.Tensor, targets: Sequence[int] = AST_TARGETS) -> torch.Tensor:
    """AST's spike-number maps for several targets: per target n, count / span (a rate on the y scale,
    expected spikes per step) then span / T (how far it had to look, in (0, 1]).

    spikes: (..., T, H, W) as for ast_counts. Returns float32 (..., 2 * len(targets), H, W): the
    rates of all targets first, then their spans.
    """
    if not targets:
        raise ValueError("ast_maps: give at least one target")
    t = spikes.shape[-3] if isinstance(spikes, torch.Tensor) and spikes.dim() >= 3 else 1
    rates, spans = [], []
    for n in targets:
        count, span = ast_counts(spikes, n)
        rates.append(count.to(torch.float32) / span.to(torch.float32))
        spans.append(span.to(torch.float32) / t)
    return torch.stack(rates + spans, dim=-3)


class ASTRep(nn.Module):
    """AST maps (8 channels) -> three 3x3 convs to C channels, leaky 0.1 (see the module docstring)."""

    def __init__(self, window: int, channels: int, targets: Sequence[int] = AST_TARGETS) -> None:
        super().__init__()
        self.window, self.targets = window, tuple(targets)
        self.body = nn.Sequential(conv_lrelu(2 * len(self.targets), channels),
                                  conv_lrelu(channels, channels), conv_lrelu(channels, channels))

    def forward(self, spikes: torch.Tensor, maps: torch.Tensor | None = None) -> torch.Tensor:
        _check_window_tensor(spikes, self.window, "ASTRep")
        x = ast_maps(_window_spikes(spikes, "ASTRep"), self.targets).to(self.body[0][0].weight.dtype)
        return self.body(x)


# ---------------------------------------------------------------------------------------------
# AMIM (SSML): learned multi-span TFP + windowed TFI, spatial and channel gates
# ---------------------------------------------------------------------------------------------

def amim_tfi(spikes: torch.Tensor, radius: int = AMIM_TFI_RADIUS) -> torch.Tensor:
    """SSML's TFI around the window centre, looked for within `radius` steps only (its AMIM uses 12):
    1 / (first spike after the centre - last spike at or before it). A side with no spike in
    [c - radius, c] or [c + 1, c + radius] (clipped to the window) takes the step just past that
    range, so a silent pixel gets 1 / (2 * radius + 2) and not a rate from far-away spikes.

    spikes: (..., T, H, W), 3 to 5 dims. Returns float32 (..., H, W) on the y scale.
    """
    s = _check_spikes(spikes, 3, 5, "amim_tfi")
    if isinstance(radius, bool) or not isinstance(radius, int) or radius < 1:
        raise ValueError(f"amim_tfi: radius must be a positive integer number of steps, got {radius!r}")
    t = s.shape[-3]
    c = t // 2
    lo, hi = max(0, c - radius), min(t - 1, c + radius)
    sub = s[..., lo:hi + 1, :, :]
    lead = sub.shape[:-3]
    return tfi(sub.reshape((-1,) + sub.shape[-3:])).reshape(lead + sub.shape[-2:])


def _centred(t: int, span: int) -> tuple[int, int]:
    """[start, stop) of the centred span of `span` steps (at most the window, kept odd)."""
    span = min(span, t if t % 2 else t - 1) if t > 1 else 1
    start = t // 2 - span // 2
    return start, start + span


class _SpatialGate(nn.Module):
    """CBAM spatial attention: channel max and mean -> 7x7 conv -> sigmoid, multiplies the input."""

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(2, 1, 7, padding=3, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pooled = torch.cat([x.amax(1, keepdim=True), x.mean(1, keepdim=True)], 1)
        return x * torch.sigmoid(self.conv(pooled))


class _ChannelGate(nn.Module):
    """CBAM channel attention: global mean and max pooling of each window -> shared MLP -> sigmoid."""

    def __init__(self, channels: int, reduction: int = 4) -> None:
        super().__init__()
        mid = max(1, channels // reduction)
        self.mlp = nn.Sequential(nn.Linear(channels, mid), nn.ReLU(), nn.Linear(mid, channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = self.mlp(x.mean((2, 3))) + self.mlp(x.amax((2, 3)))
        return x * torch.sigmoid(w)[:, :, None, None]


class AMIMRep(nn.Module):
    """AMIM features (16) beside the spike window -> 3x3 conv to C channels (module docstring).

    maps: the window's AMIM TFI (N, 1, H, W) from published_input_map("amim", ...); computed here
    from the spikes when None.
    """

    def __init__(self, window: int, channels: int, width: int = AMIM_WIDTH) -> None:
        super().__init__()
        self.window = window
        self.spans = [_centred(window, n) for n in AMIM_TFP_SPANS]
        self.tfp = nn.ModuleList(nn.Conv2d(b - a, 1, 1, bias=False) for a, b in self.spans)
        self.tfp_conv = conv_lrelu(len(self.spans), width)
        self.tfi_conv = conv_lrelu(1, width)
        self.spatial = _SpatialGate()
        self.channel = _ChannelGate(width)
        self.out = conv_lrelu(window + width, channels)

    def forward(self, spikes: torch.Tensor, maps: torch.Tensor | None = None) -> torch.Tensor:
        _check_window_tensor(spikes, self.window, "AMIMRep")
        n, _, h, w = spikes.shape
        if maps is None:
            maps = amim_tfi(_window_spikes(spikes, "AMIMRep")).unsqueeze(1)
        elif tuple(maps.shape) != (n, 1, h, w):
            raise ValueError(f"AMIMRep: maps must be (N, 1, H, W) = {(n, 1, h, w)}, got {tuple(maps.shape)}")
        x = spikes.to(self.out[0].weight.dtype)
        tfps = torch.cat([conv(x[:, a:b]) for conv, (a, b) in zip(self.tfp, self.spans)], 1)
        fused = self.spatial(self.tfp_conv(tfps)) + self.spatial(self.tfi_conv(maps.to(x.dtype)))
        return self.out(torch.cat([x, self.channel(fused)], 1))


# ---------------------------------------------------------------------------------------------
# SALI (Spk2ImgNet): overlapping sub-windows, multi-scale light inference, adaptive fusion
# ---------------------------------------------------------------------------------------------

def sali_geometry(window: int, length: int = SALI_LENGTH, count: int = SALI_COUNT) -> tuple[int, int, int]:
    """(first start, stride, length) of SALI's `count` equally spaced sub-windows of the window,
    centred in it: for 41 steps, starts 0, 7, 14, 21, 28 of 13 steps (Spk2ImgNet's blocks)."""
    if window < 1 or length < 1 or count < 1:
        raise ValueError(f"sali_geometry: window, length and count must be >= 1, got {window}, {length}, {count}")
    length = min(length, window)
    stride = (window - length) // (count - 1) if count > 1 else 0
    first = (window - length - stride * (count - 1)) // 2
    return first, stride, length


def sali_subwindows(spikes: torch.Tensor, length: int = SALI_LENGTH, count: int = SALI_COUNT) -> torch.Tensor:
    """SALI's overlapping sub-windows (Spk2ImgNet's SALI: blocks of 2 * win_r + 1 steps, win_step
    apart): (..., T, H, W) -> (..., count, length, H, W), same dtype; for T = 41 sub-window
    i covers steps 7 i .. 7 i + 12. Each sub-window is a view of the input's steps, no copy of data
    beyond the stacking."""
    if not isinstance(spikes, torch.Tensor) or spikes.dim() < 3:
        raise ValueError(f"sali_subwindows: spikes must be a tensor (..., T, H, W), got "
                         f"{tuple(spikes.shape) if isinstance(spikes, torch.Tensor) else type(spikes).__name__}")
    first, stride, length = sali_geometry(spikes.shape[-3], length, count)
    return torch.stack([spikes[..., first + i * stride: first + i * stride + length, :, :] for i in range(count)], -4)


class SALIRep(nn.Module):
    """Spk2ImgNet's SALI on 5 sub-windows (shared weights), 20 estimates -> conv to C (module docstring)."""

    def __init__(self, window: int, channels: int, hidden: int | None = None) -> None:
        super().__init__()
        self.window = window
        _, _, length = sali_geometry(window)
        hidden = hidden or max(1, channels // 4)
        self.trims = [min(j, (length - 1) // 2) for j in range(SALI_SCALES)]
        self.branches = nn.ModuleList(
            nn.Sequential(conv3x3(length - 2 * k, hidden), nn.ReLU(), conv3x3(hidden, 1)) for k in self.trims)
        self.attention = nn.Sequential(conv3x3(SALI_SCALES, 2 * SALI_SCALES), nn.ReLU(),
                                       conv3x3(2 * SALI_SCALES, SALI_SCALES), nn.Sigmoid())
        self.fuse = conv_lrelu(SALI_COUNT * SALI_SCALES, channels)

    def forward(self, spikes: torch.Tensor, maps: torch.Tensor | None = None) -> torch.Tensor:
        _check_window_tensor(spikes, self.window, "SALIRep")
        n, _, h, w = spikes.shape
        sub = sali_subwindows(spikes.to(self.fuse[0].weight.dtype))
        sub = sub.reshape((n * SALI_COUNT,) + sub.shape[2:])
        length = sub.shape[1]
        est = torch.cat([b(sub[:, k:length - k]) for b, k in zip(self.branches, self.trims)], 1)
        est = est * self.attention(est)
        return self.fuse(est.reshape(n, SALI_COUNT * SALI_SCALES, h, w))


# ---------------------------------------------------------------------------------------------
# WGSE-1d: per-pixel multi-level 1-D DWT along time (PyWavelets' filters, zero padding)
# ---------------------------------------------------------------------------------------------

def wavelet_filters(wavelet: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """PyWavelets' (dec_lo, dec_hi, rec_lo, rec_hi) of a discrete wavelet as float64 tensors."""
    import pywt
    if not isinstance(wavelet, str) or wavelet not in pywt.wavelist(kind="discrete"):
        raise ValueError(f"unknown discrete wavelet {wavelet!r}: use a name from pywt.wavelist(kind='discrete'), "
                         "e.g. 'haar', 'db8'")
    w = pywt.Wavelet(wavelet)
    return tuple(torch.tensor(f, dtype=torch.float64) for f in (w.dec_lo, w.dec_hi, w.rec_lo, w.rec_hi))


def wavelet_band_lengths(length: int, wavelet: str, levels: int) -> list[int]:
    """Lengths of wavelet_coefficients_1d's bands [cA_J, cD_J, ..., cD_1] for a train of `length` steps."""
    filt = len(wavelet_filters(wavelet)[0])
    out = []
    for _ in range(levels):
        length = (length + filt - 1) // 2
        out.append(length)
    return [out[-1]] + out[::-1]


def _as_trains(x: torch.Tensor) -> tuple[torch.Tensor, tuple[int, ...]]:
    """(..., L, H, W) -> (B, 1, L, H * W) with the leading shape, for convs along time."""
    lead, (length, h, w) = x.shape[:-3], x.shape[-3:]
    return x.reshape((-1, 1, length, h * w)), tuple(lead) + (h, w)


def _from_trains(y: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    *lead, h, w = shape
    return y.reshape(tuple(lead) + (y.shape[2], h, w))


def _dwt_step(x: torch.Tensor, dec: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """One DWT level along dim 2 of (B, 1, L, P): full convolution with each filter, every second
    sample from the second (PyWavelets' mode="zero"): length (L + F - 1) // 2."""
    f = dec.shape[-2]
    y = F.conv2d(F.pad(x, (0, 0, f - 1, f - 1))[:, :, 1:], dec, stride=(2, 1))
    return y[:, :1], y[:, 1:]


def _idwt_step(a: torch.Tensor, d: torch.Tensor, rec_lo: torch.Tensor, rec_hi: torch.Tensor) -> torch.Tensor:
    """Inverse of _dwt_step: upsample, convolve with the reconstruction filters, keep the
    2 L - F + 2 samples PyWavelets keeps."""
    f = rec_lo.shape[-2]
    y = F.conv_transpose2d(a, rec_lo, stride=(2, 1)) + F.conv_transpose2d(d, rec_hi, stride=(2, 1))
    return y[:, :, f - 2: 2 * a.shape[2]]


def _filters_like(wavelet: str, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    dec_lo, dec_hi, rec_lo, rec_hi = wavelet_filters(wavelet)
    kw = dict(dtype=x.dtype, device=x.device)
    # conv2d correlates: flipped decomposition filters make it a convolution.
    dec = torch.stack([dec_lo.flip(0), dec_hi.flip(0)]).to(**kw).reshape(2, 1, -1, 1)
    return dec, rec_lo.to(**kw).reshape(1, 1, -1, 1), rec_hi.to(**kw).reshape(1, 1, -1, 1)


def _check_levels(levels: int) -> None:
    if isinstance(levels, bool) or not isinstance(levels, int) or levels < 1:
        raise ValueError(f"levels must be a positive integer, got {levels!r}")


def wavelet_coefficients_1d(spikes: torch.Tensor, wavelet: str = WGSE_WAVELET,
                            levels: int = WGSE_LEVELS) -> list[torch.Tensor]:
    """Multi-level 1-D discrete wavelet transform of every pixel's spike train along time (WGSE's
    1-D DWT representation: the temporal order of spikes is kept in the coefficients of each
    scale), equal to pywt.wavedec(train, wavelet, mode="zero", level=levels) per pixel, vectorised
    as strided convolutions with PyWavelets' filters.

    spikes: (..., T, H, W), 3 to 5 dims, bool / uint8 / float 0-1 (a float64 input is transformed in
    float64, anything else in float32). Returns [cA_levels, cD_levels, ..., cD_1], each
    (..., L_j, H, W) with the lengths of wavelet_band_lengths. Levels above PyWavelets' maximum for
    the length are allowed (WGSE uses 5 levels of db8 on 41 steps): the coarse bands then mostly
    carry the zero padding's boundary effects, as in WGSE.
    """
    s = _check_spikes(spikes, 3, 5, "wavelet_coefficients_1d")
    _check_levels(levels)
    dtype = spikes.dtype if spikes.dtype == torch.float64 else torch.float32
    x, shape = _as_trains(s.to(dtype))
    dec, _, _ = _filters_like(wavelet, x)
    details = []
    for _ in range(levels):
        x, d = _dwt_step(x, dec)
        details.append(d)
    return [_from_trains(c, shape) for c in [x] + details[::-1]]


def wavelet_reconstruct_1d(coefficients: Sequence[torch.Tensor], wavelet: str = WGSE_WAVELET) -> torch.Tensor:
    """Inverse of wavelet_coefficients_1d (pywt.waverec(..., mode="zero") per pixel): bands
    [cA_J, cD_J, ..., cD_1], each (..., L_j, H, W), -> (..., L, H, W). Perfect reconstruction: for a
    train of T steps the first T samples are the train (one more, about zero, when T is odd)."""
    if len(coefficients) < 2:
        raise ValueError(f"wavelet_reconstruct_1d: need [cA, cD_J, ..., cD_1], got {len(coefficients)} band(s)")
    a, shape = _as_trains(coefficients[0])
    _, rec_lo, rec_hi = _filters_like(wavelet, a)
    for band in coefficients[1:]:
        d, _ = _as_trains(band)
        if a.shape[2] == d.shape[2] + 1:  # as PyWavelets: the odd length's extra sample
            a = a[:, :, :-1]
        if a.shape[2] != d.shape[2]:
            raise ValueError(f"wavelet_reconstruct_1d: band lengths {a.shape[2]} and {d.shape[2]} do not match")
        a = _idwt_step(a, d, rec_lo, rec_hi)
    return _from_trains(a, shape)


class _BandBranch(nn.Module):
    """WGSE's temporal conv branch for one band, on every pixel's coefficient sequence (kernels
    along time only): residual TCN layer 1 -> hidden -> hidden (+ the band, ReLU), conv hidden -> 1."""

    def __init__(self, hidden: int, kernel: int = 3) -> None:
        super().__init__()
        self.pad = (kernel // 2, 0)
        self.tcn0 = nn.Conv2d(1, hidden, (kernel, 1))
        self.tcn1 = nn.Conv2d(hidden, hidden, (kernel, 1))
        self.out = nn.Conv2d(hidden, 1, (kernel, 1))

    def _conv(self, conv: nn.Conv2d, x: torch.Tensor) -> torch.Tensor:
        # channels-last input and weights: oneDNN runs these thin convs over (N, C, L, pixels)
        # about 3x faster that way (same arithmetic)
        w = conv.weight.contiguous(memory_format=torch.channels_last)
        return F.conv2d(x.contiguous(memory_format=torch.channels_last), w, conv.bias, padding=self.pad)

    def forward(self, band: torch.Tensor) -> torch.Tensor:
        y = F.relu(self._conv(self.tcn1, F.relu(self._conv(self.tcn0, band))) + band)
        return self._conv(self.out, y)


class WGSE1dRep(nn.Module):
    """Per-pixel DWT along time, one conv branch per band, inverse DWT, conv T -> C (module docstring)."""

    def __init__(self, window: int, channels: int, wavelet: str = WGSE_WAVELET, levels: int = WGSE_LEVELS,
                 hidden: int | None = None) -> None:
        super().__init__()
        _check_levels(levels)
        self.window, self.wavelet, self.levels = window, wavelet, levels
        dec, rec_lo, rec_hi = _filters_like(wavelet, torch.zeros(0))
        cl = torch.channels_last  # as _BandBranch: faster thin convs on the CPU
        self.register_buffer("dec", dec.contiguous(memory_format=cl), persistent=False)
        self.register_buffer("rec_lo", rec_lo.contiguous(memory_format=cl), persistent=False)
        self.register_buffer("rec_hi", rec_hi.contiguous(memory_format=cl), persistent=False)
        hidden = hidden or max(1, channels // 4)
        self.branches = nn.ModuleList(_BandBranch(hidden) for _ in range(levels + 1))
        self.out = conv_lrelu(window, channels)

    def forward(self, spikes: torch.Tensor, maps: torch.Tensor | None = None) -> torch.Tensor:
        _check_window_tensor(spikes, self.window, "WGSE1dRep")
        n, t, h, w = spikes.shape
        x = spikes.to(self.out[0].weight.dtype).reshape(n, 1, t, h * w).contiguous(memory_format=torch.channels_last)
        dec = self.dec.to(x.dtype)
        details = []
        for _ in range(self.levels):
            x, d = _dwt_step(x, dec)
            details.append(d)
        bands = [x] + details[::-1]
        bands = [branch(b) for branch, b in zip(self.branches, bands)]
        a = bands[0]
        rec_lo, rec_hi = self.rec_lo.to(a.dtype), self.rec_hi.to(a.dtype)
        for d in bands[1:]:
            if a.shape[2] == d.shape[2] + 1:
                a = a[:, :, :-1]
            a = _idwt_step(a, d, rec_lo, rec_hi)
        return self.out(a[:, 0, :t].reshape(n, t, h, w))


# ---------------------------------------------------------------------------------------------
# Registry, precomputed maps, cost
# ---------------------------------------------------------------------------------------------

PUBLISHED_REPS: dict[str, type[nn.Module]] = {"ast": ASTRep, "amim": AMIMRep, "sali": SALIRep, "wgse1d": WGSE1dRep}
PUBLISHED_REPRESENTATIONS: tuple[str, ...] = tuple(PUBLISHED_REPS)


def published_input_map(name: str, spikes: torch.Tensor) -> torch.Tensor | None:
    """The one-channel map representation `name` wants precomputed for each window:
    spikes (..., K, T, H, W) -> float32 (..., K, H, W), or None when it computes everything from the
    spike window inside forward. Only AMIM has one (its windowed TFI, amim_tfi); each window's map
    depends on that window's spikes alone."""
    if name not in PUBLISHED_REPS:
        raise ValueError(f"unknown published representation {name!r}: one of {PUBLISHED_REPRESENTATIONS}")
    if name != "amim":
        return None
    s = _check_spikes(spikes, 4, 5, f"published_input_map({name!r})")
    return amim_tfi(s)


def representation_cost(module: nn.Module, window: int = 41, size: int = 64,
                        with_map: bool = False) -> tuple[int, int]:
    """(parameters, FLOP) of a representation on one (1, window, size, size) window of sparse
    spikes, FLOP as counted by torch.utils.flop_counter.FlopCounterMode (2 per multiply-add)."""
    from torch.utils.flop_counter import FlopCounterMode
    g = torch.Generator().manual_seed(0)
    spikes = (torch.rand(1, window, size, size, generator=g) < 0.1).to(torch.float32)
    maps = torch.rand(1, 1, size, size, generator=g) if with_map else None
    counter = FlopCounterMode(display=False)
    with counter, torch.no_grad():
        module(spikes, maps)
    return sum(p.numel() for p in module.parameters()), int(counter.get_total_flops())
