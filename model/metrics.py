"""Image-quality metrics, one convention everywhere (DESIGN.md 5, "Ours"):

- float images on the y scale, both clipped to [0, 1] (a spike camera cannot report y > 1, and
  peers clamp their outputs the same way), data range 1;
- PSNR = 10 log10(1 / MSE);
- SSIM from scikit-image's structural_similarity with gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False (an 11x11 Gaussian window: Wang et al. 2004, as WGSE and SpikeCV).
No 8-bit quantisation and no gamma: those are for display only.
"""
from __future__ import annotations

import math

import numpy as np
from skimage.metrics import structural_similarity

METRIC_CONVENTION = ("PSNR and SSIM on float y images clipped to [0, 1], data range 1; SSIM: "
                     "scikit-image structural_similarity, Gaussian window sigma 1.5 (11x11), "
                     "use_sample_covariance=False; no quantisation, no gamma.")


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
