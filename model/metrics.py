"""Image-quality metrics in three conventions, all on y images clipped to [0, 1] (a spike camera
cannot report y > 1: saturation is one spike per step, and peers clamp their outputs the same way).

- Ours (`psnr`, `ssim`): float images, data range 1; PSNR = 10 log10(1 / MSE); SSIM from
  scikit-image's structural_similarity with gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False (an 11x11 Gaussian window: Wang et al. 2004, as WGSE and SpikeCV).
  No 8-bit quantisation and no gamma: those are for display only.
- The authors' released metric code (`psnr_8bit`, `ssim_8bit`): images quantised to 8 bits by
  truncation, floor(255 clip(y, 0, 1)), data range 255, and scikit-image's default SSIM (7x7
  uniform window, sample covariance). The convention of the paper's Table 1.
- Light-normalised (`psnr_norm`, `ssim_norm`): ours with the data range set to the ground truth's
  own peak (its 99.5th percentile) instead of 1, i.e. both images divided by the scene's light
  level. In the other two an image dark enough scores high whatever it shows (an all-black image
  scores about 60 dB on a low-light scene in the 8-bit convention); here it scores what it
  would in normal light. Per frame it keeps the plain PSNR's order (a constant shift), so it
  judges scenes of different light on one scale but does not stop a black image from beating a
  noisier reconstruction of a dark frame.
- Aligned (`psnr_aligned`): the light-normalised PSNR after the least-squares gain and offset that
  best map the prediction onto the ground truth, per frame. A black or constant image scores
  exactly the floor 20 log10(level / std(gt)); any image correlated with the ground truth (rho)
  scores 10 log10(1 / (1 - rho^2)) dB above it, so no image without structure can win. It rewards
  structure only: brightness errors are what the other columns measure.
"""
from __future__ import annotations

import math

import numpy as np
from skimage.metrics import structural_similarity

METRIC_CONVENTION = ("PSNR and SSIM on float y images clipped to [0, 1], data range 1; SSIM: "
                     "scikit-image structural_similarity, Gaussian window sigma 1.5 (11x11), "
                     "use_sample_covariance=False; no quantisation, no gamma.")
AUTHORS_CONVENTION = ("8-bit (the authors' metric code, the convention of the paper's Table 1): y clipped to "
                      "[0, 1], quantised by floor(255 y), data range 255; SSIM: scikit-image's default "
                      "structural_similarity (7x7 uniform window, sample covariance).")
NORMALISED_CONVENTION = ("light-normalised: as ours, with the data range set to the ground truth's 99.5th "
                         "percentile (its light level) instead of 1. Aligned: light-normalised PSNR after the "
                         "least-squares gain and offset from prediction to ground truth (a black or constant "
                         "image scores the floor, 20 log10(level / std(gt))).")
PEAK_PERCENTILE = 99.5
PEAK_FLOOR = 1e-4
"""The smallest light level the normalised metrics divide by (y; 0.1 spike per 1000 steps), so an
all-black ground truth does not divide by zero."""


def _prepare(pred: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(pred, dtype=np.float64)
    t = np.asarray(target, dtype=np.float64)
    if p.shape != t.shape or p.ndim != 2:
        raise ValueError(f"metrics need two (H, W) images of one shape, got {p.shape} and {t.shape}")
    if not (np.isfinite(p).all() and np.isfinite(t).all()):
        raise ValueError("metrics got NaN or Inf pixels")
    return np.clip(p, 0.0, 1.0), np.clip(t, 0.0, 1.0)


def psnr(pred: np.ndarray, target: np.ndarray) -> float:
    p, t = _prepare(pred, target)
    mse = float(np.mean((p - t) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


SSIM_MIN_SIDE = 11  # the Gaussian window, 2 * int(3.5 * 1.5 + 0.5) + 1


def ssim(pred: np.ndarray, target: np.ndarray) -> float:
    p, t = _prepare(pred, target)
    if min(p.shape) < SSIM_MIN_SIDE:
        raise ValueError(f"SSIM's 11x11 Gaussian window needs images of at least {SSIM_MIN_SIDE}x{SSIM_MIN_SIDE}, "
                         f"got {p.shape[0]}x{p.shape[1]}")
    return float(structural_similarity(p, t, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                       use_sample_covariance=False))


SSIM_8BIT_MIN_SIDE = 7  # scikit-image's default window


def quantise_8bit(y: np.ndarray) -> np.ndarray:
    """floor(255 clip(y, 0, 1)) as uint8: the authors' conversion of a y image to 8 bits (truncation)."""
    return np.floor(255.0 * np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)).astype(np.uint8)


def psnr_8bit(pred: np.ndarray, target: np.ndarray) -> float:
    """PSNR of the 8-bit images, data range 255 (the authors' convention)."""
    p, t = (quantise_8bit(x).astype(np.float64) for x in _prepare(pred, target))
    mse = float(np.mean((p - t) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(255.0 ** 2 / mse)


def ssim_8bit(pred: np.ndarray, target: np.ndarray) -> float:
    """scikit-image's default SSIM (7x7 uniform window) on the 8-bit images, data range 255."""
    p, t = (quantise_8bit(x) for x in _prepare(pred, target))
    if min(p.shape) < SSIM_8BIT_MIN_SIDE:
        raise ValueError(f"SSIM's 7x7 window needs images of at least {SSIM_8BIT_MIN_SIDE}x{SSIM_8BIT_MIN_SIDE}, "
                         f"got {p.shape[0]}x{p.shape[1]}")
    return float(structural_similarity(p, t, data_range=255))


def light_level(target: np.ndarray) -> float:
    """The ground truth's light level: its 99.5th percentile (at least PEAK_FLOOR)."""
    return max(float(np.percentile(target, PEAK_PERCENTILE)), PEAK_FLOOR)


def psnr_norm(pred: np.ndarray, target: np.ndarray) -> float:
    """PSNR with the ground truth's light level as the data range: 10 log10(level^2 / MSE)."""
    p, t = _prepare(pred, target)
    mse = float(np.mean((p - t) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(light_level(t) ** 2 / mse)


def ssim_norm(pred: np.ndarray, target: np.ndarray) -> float:
    """Our SSIM with the ground truth's light level as the data range."""
    p, t = _prepare(pred, target)
    if min(p.shape) < SSIM_MIN_SIDE:
        raise ValueError(f"SSIM's 11x11 Gaussian window needs images of at least {SSIM_MIN_SIDE}x{SSIM_MIN_SIDE}, "
                         f"got {p.shape[0]}x{p.shape[1]}")
    return float(structural_similarity(p, t, data_range=light_level(t), gaussian_weights=True, sigma=1.5,
                                       use_sample_covariance=False))


def psnr_aligned(pred: np.ndarray, target: np.ndarray) -> float:
    """Light-normalised PSNR of a + b pred, with a and b fitted to the ground truth by least squares."""
    p, t = _prepare(pred, target)
    p, t = p.ravel(), t.ravel()
    pc, tc = p - p.mean(), t - t.mean()
    var_p = float(pc @ pc)
    gain = float(pc @ tc) / var_p if var_p > 0 else 0.0  # a constant prediction: offset only
    mse = float(np.mean((tc - gain * pc) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(light_level(t) ** 2 / mse)


#: Every metric evaluate reports, in table order: name -> (function, label, format).
METRICS = {
    "psnr": (psnr, "PSNR", "{:.3f}"),
    "ssim": (ssim, "SSIM", "{:.5f}"),
    "psnr_8bit": (psnr_8bit, "PSNR 8-bit", "{:.3f}"),
    "ssim_8bit": (ssim_8bit, "SSIM 8-bit", "{:.5f}"),
    "psnr_norm": (psnr_norm, "PSNR light-norm.", "{:.3f}"),
    "ssim_norm": (ssim_norm, "SSIM light-norm.", "{:.5f}"),
    "psnr_aligned": (psnr_aligned, "PSNR aligned", "{:.3f}"),
}
