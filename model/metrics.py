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
  exactly the floor 20 log10(level / std(gt)); any image correlated with the ground truth (rho > 0)
  scores 10 log10(1 / (1 - rho^2)) dB above it, so no image without structure can win. The gain is
  at least 0: an image anti-correlated with the truth (its negative) scores the floor, not the
  truth's own score. It rewards structure only: brightness errors are what the other columns measure.
- Aligned SSIM (`ssim_aligned`): SSIM in the same spirit. The prediction gets the gain (and the
  offset that matches the means) that maximise its SSIM, as the aligned PSNR gets the pair that
  minimises its error; SSIM is taken at the ground truth's light level as the data range; then it
  is rescaled so that an image without structure scores 0 and a perfect one 1: (S - S0) / (1 - S0),
  S0 the SSIM of the constant image at the ground truth's mean (gain 0). Why: plain SSIM rewards
  flat regions matched by anything flat, so in low light `black` scores 0.97 where TFP scores 0.87,
  and light-normalised SSIM does not stop it either. Gain 0 is always a candidate, so no image
  scores below 0 and black or constant images score exactly 0, at every light level; the gain is
  searched at 0 or above, so a negative of the truth scores 0 too. (With the
  least-squares gain instead, a noisy image scored below the constant: SSIM penalises noise that
  MSE's fit keeps.)
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
                         "least-squares gain (at least 0) and offset from prediction to ground truth (a black, "
                         "constant or inverted image scores the floor, 20 log10(level / std(gt))); aligned SSIM: "
                         "light-normalised SSIM "
                         "after the gain (offset matching the means) that maximises it, rescaled so that the constant "
                         "image at the ground truth's mean scores 0 and a perfect one 1 (no image scores below 0).")
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


def aligned_prediction(pred: np.ndarray, target: np.ndarray) -> np.ndarray:
    """a + b pred with a and b the least-squares fit to the target, b >= 0 (float64, both already
    prepared); a constant prediction gets the offset only: the target's mean."""
    pc = pred - pred.mean()
    return target.mean() + aligned_gain(pc, target) * pc


def aligned_gain(pc: np.ndarray, target: np.ndarray) -> float:
    """The least-squares gain from the centred prediction `pc` to the target, at least 0: a negative
    gain turned a photographic negative of the truth into the truth (round eight: an inverted image
    scored inf dB and an aligned SSIM of 1), so an image that is anti-correlated with the truth
    gets gain 0 and scores as the constant image, the floor."""
    var_p = float(np.vdot(pc, pc))
    return max(0.0, float(np.vdot(pc, target - target.mean())) / var_p) if var_p > 0 else 0.0


def psnr_aligned(pred: np.ndarray, target: np.ndarray) -> float:
    """Light-normalised PSNR of a + b pred, with a and b fitted to the ground truth by least squares."""
    p, t = _prepare(pred, target)
    mse = float(np.mean((t - aligned_prediction(p, t)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(light_level(t) ** 2 / mse)


#: SSIM's constants (Wang et al. 2004; scikit-image's K1, K2) and its Gaussian window (sigma 1.5
#: truncated at 3.5 sigma: 11 x 11), as `ssim` uses them.
SSIM_K1, SSIM_K2, SSIM_SIGMA, SSIM_TRUNCATE = 0.01, 0.03, 1.5, 3.5


class AffineSSIM:
    """SSIM(a + b pred, target) for every gain b, the offset a matching the means, from the local
    moments computed once: Gaussian filters are linear, so the aligned image's local mean is
    a + b mu_p, its variance b^2 var_p and its covariance b cov. Equal to scikit-image's
    structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False) on the
    aligned image (tested), at the cost of one search over b instead of one SSIM per gain."""

    def __init__(self, pred: np.ndarray, target: np.ndarray, data_range: float) -> None:
        from scipy.ndimage import gaussian_filter

        def blur(x: np.ndarray) -> np.ndarray:
            return gaussian_filter(x, sigma=SSIM_SIGMA, truncate=SSIM_TRUNCATE, mode="reflect")
        r = (SSIM_MIN_SIDE - 1) // 2  # scikit-image averages the SSIM map inside its window's reach
        crop = (slice(r, -r), slice(r, -r))
        self.mu_p, self.mu_t = blur(pred)[crop], blur(target)[crop]
        self.var_p = blur(pred * pred)[crop] - self.mu_p ** 2
        self.var_t = blur(target * target)[crop] - self.mu_t ** 2
        self.cov = blur(pred * target)[crop] - self.mu_p * self.mu_t
        self.mean_p, self.mean_t = float(pred.mean()), float(target.mean())
        self.c1, self.c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2

    def __call__(self, gain: float) -> float:
        mu = self.mean_t + gain * (self.mu_p - self.mean_p)
        num = (2 * mu * self.mu_t + self.c1) * (2 * gain * self.cov + self.c2)
        den = (mu ** 2 + self.mu_t ** 2 + self.c1) * (gain ** 2 * self.var_p + self.var_t + self.c2)
        return float(np.mean(num / den))


def ssim_aligned(pred: np.ndarray, target: np.ndarray) -> float:
    """(S - S0) / (1 - S0): S the light-normalised SSIM of a + b pred at the gain b that maximises
    it (the offset a matching the means; b searched between 0 and twice the least-squares gain,
    itself at least 0),
    S0 that of the constant image at the ground truth's mean (b = 0), so that no image scores
    below an image without structure, and those score exactly 0 (module docstring). 1.0 for a ground
    truth without structure (S0 = 1: nothing to recover, as the aligned PSNR's infinity)."""
    from scipy.optimize import minimize_scalar

    p, t = _prepare(pred, target)
    if min(p.shape) < SSIM_MIN_SIDE:
        raise ValueError(f"SSIM's 11x11 Gaussian window needs images of at least {SSIM_MIN_SIDE}x{SSIM_MIN_SIDE}, "
                         f"got {p.shape[0]}x{p.shape[1]}")
    score = AffineSSIM(p, t, light_level(t))
    floor = score(0.0)
    if 1.0 - floor < 1e-12:
        return 1.0
    ls_gain = aligned_gain(p - p.mean(), t)  # at least 0: a negative of the truth is no reconstruction of it
    best = max(floor, score(ls_gain))
    if ls_gain != 0.0:
        found = minimize_scalar(lambda g: -score(g), bounds=sorted((0.0, 2.0 * ls_gain)), method="bounded",
                                options={"xatol": 1e-6 * abs(ls_gain)})
        best = max(best, -float(found.fun))
    return (best - floor) / (1.0 - floor)


#: Every metric evaluate reports, in table order: name -> (function, label, format).
METRICS = {
    "psnr": (psnr, "PSNR", "{:.3f}"),
    "ssim": (ssim, "SSIM", "{:.5f}"),
    "psnr_8bit": (psnr_8bit, "PSNR 8-bit", "{:.3f}"),
    "ssim_8bit": (ssim_8bit, "SSIM 8-bit", "{:.5f}"),
    "psnr_norm": (psnr_norm, "PSNR light-norm.", "{:.3f}"),
    "ssim_norm": (ssim_norm, "SSIM light-norm.", "{:.5f}"),
    "psnr_aligned": (psnr_aligned, "PSNR aligned", "{:.3f}"),
    "ssim_aligned": (ssim_aligned, "SSIM aligned", "{:.4f}"),
}
