"""A camera fitted from a user's own recordings (`spikesim calibrate`): dark current and its spread
from a dark recording, the pixels' response spread from a flat one, row and column patterns from a
scene, each with the uncertainty its counting statistics give.

Every estimate splits its recording into two halves in time and works on per-pixel rates r_a, r_b.
The fixed pattern (what a camera field describes) is in both halves; the counting noise of a
finite recording is independent between them. So the pattern's variance across pixels is
cov(r_a, r_b), free of the counting noise that var(r) would add (the split-half estimator of
fixed-pattern noise, as photon-transfer methods use it). Its standard error over n pixels is
sqrt((var_a var_b + cov^2) / (n - 1)) (the variance of a sample covariance of two normals).

What the recordings determine, and what calibrate writes (docs/sensor.md, "Calibrating a camera"):
- dark: the mean dark rate d / theta, and its spread. Without light a pixel's rate is its dark
  current over its threshold, so the spread is that of d / theta: written as dark_current_spread.
- flat (uniform light, dark subtracted pixel by pixel): the response g / theta. Gain spread and
  threshold mismatch and offset act on light alike (rate = (g y + d) / theta), so a flat at any
  number of levels measures sqrt(gain^2 + mismatch^2 + offset^2) only. Calibrate writes it as
  gain_spread and the threshold terms as 0: the same mean rate in every pixel under any light.
  (Two flats check linearity instead: their response maps must agree up to one factor.)
- flat, outliers: the relative responses as a mixture of the pixels' spread and a share of outlier
  pixels (SpikeCamera's outlier terms), by EM, kept where two components beat one (BIC); then
  gain_spread is the narrow part.
- scene: the rates relative to their neighbourhood's median; the spread of row and column means of
  that ratio, by the same split-half covariance, less what the pixels' own spread adds to a line's
  mean (their residual variance over the line's pixels): `fit_scene`. It holds the scene's own
  texture that varies by row or column at scales the median keeps (a car scene of a camera with
  no row or column pattern gave 0.24 and 0.16, round ten), which one recording cannot tell apart
  from a fixed pattern; so `spikesim calibrate` does not write it (`check_scene_lit` only).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .camera import SpikeCamera

#: A pixel is hot when its log dark rate lies this many robust standard deviations (1.4826 MAD)
#: above the median: far beyond a lognormal spread of 39 % (5 sigma: 1 pixel in 3.5 million).
HOT_PIXEL_Z = 5.0
#: Above this mean rate (spikes per step) a flat is too bright: a pixel cannot fire twice in a
#: step, so the rate stops following the light (saturation at 1).
FLAT_MAX_RATE = 0.5
#: Above this mean rate (spikes per step) a "dark" recording is lit: 0.05 is 2,000 Hz of dark
#: current at the 25 us readout, 20 times the published camera's 94 Hz.
DARK_MAX_RATE = 0.05
#: Side of the median filter that gives each pixel of a scene its neighbourhood's rate (as
#: pipelines/real_camera.py's rate map).
NEIGHBOURHOOD_PX = 9
#: The fewest steps a recording may have: two halves of at least this many steps each.
MIN_STEPS = 100


@dataclass(frozen=True)
class Fitted:
    """One fitted camera field: its value, one standard error, and where it came from."""

    field: str
    value: float
    uncertainty: float
    source: str

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class HalfRates:
    """Per-pixel rates (spikes per step) of a recording's two halves in time, (H, W) each."""

    a: np.ndarray
    b: np.ndarray
    steps: int
    path: str

    @property
    def mean(self) -> np.ndarray:
        return (self.a + self.b) / 2.0


def half_rates(read_steps: Any, num_steps: int, path: str, chunk: int = 4096) -> HalfRates:
    """Per-pixel spike counts of each half of a recording, read in chunks (memory: one chunk).
    `read_steps(start, stop)` gives bool (n, H, W)."""
    if num_steps < 2 * MIN_STEPS:
        raise ValueError(f"{path}: {num_steps} steps; calibration needs at least {2 * MIN_STEPS} "
                         "(two halves of a recording)")
    half = num_steps // 2
    counts = []
    for lo, hi in ((0, half), (half, 2 * half)):
        total = None
        for start in range(lo, hi, chunk):
            part = np.asarray(read_steps(start, min(start + chunk, hi))).sum(axis=0, dtype=np.int64)
            total = part if total is None else total + part
        counts.append(total / float(half))
    return HalfRates(counts[0], counts[1], 2 * half, path)


def split_half_spread(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(standard deviation, its standard error) of the pattern shared by two noisy copies a, b
    (module docstring); 0 when the covariance is not positive (no pattern above the noise)."""
    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    n = a.size
    if n < 3:
        raise ValueError(f"a spread needs at least 3 samples, got {n}")
    cov = float(np.mean((a - a.mean()) * (b - b.mean()))) * n / (n - 1)
    se_cov = math.sqrt((a.var(ddof=1) * b.var(ddof=1) + cov * cov) / (n - 1))
    if cov <= 1e-12 * (a.mean() ** 2 + b.mean() ** 2):  # no pattern above rounding: identical pixels
        return 0.0, math.sqrt(se_cov)
    sd = math.sqrt(cov)
    return sd, se_cov / (2.0 * sd)


def hot_pixels(rate: np.ndarray) -> np.ndarray:
    """Mask of hot pixels: log rate beyond HOT_PIXEL_Z robust deviations above the median."""
    fired = rate > 0
    if fired.sum() < 10:
        return np.zeros(rate.shape, bool)
    logs = np.log(rate[fired])
    mad = float(np.median(np.abs(logs - np.median(logs)))) * 1.4826
    hot = np.zeros(rate.shape, bool)
    hot[fired] = logs > np.median(logs) + HOT_PIXEL_Z * max(mad, 1e-12)
    return hot


@dataclass(frozen=True)
class DarkFit:
    fitted: list[Fitted]
    hot: np.ndarray
    rates: HalfRates


def fit_dark(dark: HalfRates, readout_period_s: float) -> DarkFit:
    """dark_current_hz (mean dark rate / readout period: thresholds per second, the model's ideal
    threshold) and dark_current_spread (split-half spread over the mean), hot pixels left out of
    both and counted."""
    r = dark.mean
    hot = hot_pixels(r)
    keep = ~hot
    n = int(keep.sum())
    mean = float(r[keep].mean())
    where = f"{Path(dark.path).name} ({dark.steps} steps, dark)"
    if mean > DARK_MAX_RATE:  # a lit recording given as dark was fitted as 8,096 Hz of dark current (round six)
        raise ValueError(f"{dark.path}: a dark recording fires {mean:.3g} spikes per step on average, more than "
                         f"{DARK_MAX_RATE:g} ({DARK_MAX_RATE / readout_period_s:,.0f} Hz of dark current, 20 times the "
                         "published 94 Hz): it is lit; record it with the lens capped")
    if mean <= 0:
        return DarkFit([Fitted("dark_current_hz", 0.0, 1.0 / (dark.steps * n * readout_period_s), where),
                        Fitted("dark_current_spread", 0.0, 0.0, where)], hot, dark)
    se_mean = float(r[keep].std(ddof=1)) / math.sqrt(n) if n > 1 else mean
    sd, se_sd = split_half_spread(dark.a[keep], dark.b[keep])
    return DarkFit([Fitted("dark_current_hz", mean / readout_period_s, se_mean / readout_period_s, where),
                    Fitted("dark_current_spread", sd / mean, se_sd / mean, where)], hot, dark)


def fit_flat(flat: HalfRates, dark: HalfRates | None, camera: SpikeCamera) -> tuple[list[Fitted], float]:
    """gain_spread: the split-half spread of the dark-subtracted response over its mean (the
    combination sqrt(gain^2 + mismatch^2 + offset^2): module docstring); returns it and the flat's
    light, y (spikes per step of an average pixel)."""
    where = f"{Path(flat.path).name} ({flat.steps} steps, flat)"
    mean_rate = float(flat.mean.mean())
    if mean_rate > FLAT_MAX_RATE:
        raise ValueError(f"{flat.path}: mean rate {mean_rate:.3f} spikes per step is too bright to fit a response "
                         f"(above {FLAT_MAX_RATE}: pixels near saturation stop following the light); record a "
                         "dimmer flat")
    if dark is not None:
        if dark.a.shape != flat.a.shape:
            raise ValueError(f"{flat.path} is {flat.a.shape[0]} x {flat.a.shape[1]}, the dark recording "
                             f"{dark.a.shape[0]} x {dark.a.shape[1]}")
        resp_a, resp_b = flat.a - dark.a, flat.b - dark.b
        hot = hot_pixels(dark.mean)
    else:  # the camera's mean dark rate, taken out uniformly
        resp_a = flat.a - camera.dark_per_step
        resp_b = flat.b - camera.dark_per_step
        where += ", the camera's mean dark current subtracted (no dark recording)"
        hot = np.zeros(flat.a.shape, bool)
    keep = ~hot
    y = float(((resp_a + resp_b) / 2)[keep].mean())
    if y <= 0:
        raise ValueError(f"{flat.path}: no light above the dark current (mean response {y:.3g} spikes per step)")
    sd, se = split_half_spread(resp_a[keep], resp_b[keep])
    return [Fitted("gain_spread", sd / y, se / y, where)], y


#: A two-component fit (outlier pixels) is kept only when it explains the flat's responses better
#: than one normal by this much Bayesian information criterion (strong evidence, Kass & Raftery).
OUTLIER_BIC_MARGIN = 10.0
#: Bootstrap resamples of the pixels for the outlier fit's standard errors.
OUTLIER_BOOTSTRAP = 20


def _mixture(e: np.ndarray, noise_var: float, iterations: int = 200) -> tuple[float, float, float, float]:
    """(f, sd0, sd1, log-likelihood gain over one normal) of relative responses e: a share f of
    outlier pixels N(0, sd1^2) among N(0, sd0^2), both widened by the counting noise, by EM."""
    v_all = float(np.mean(e * e))
    v0, v1, f = v_all * 0.5, v_all * 4.0, 0.1
    for _ in range(iterations):
        p0 = (1 - f) * np.exp(-e * e / (2 * v0)) / np.sqrt(v0)
        p1 = f * np.exp(-e * e / (2 * v1)) / np.sqrt(v1)
        w = p1 / np.maximum(p0 + p1, 1e-300)
        f = float(np.clip(w.mean(), 1e-6, 0.5))
        v1 = max(float(np.sum(w * e * e) / max(w.sum(), 1e-12)), noise_var * 1.0001)
        v0 = max(float(np.sum((1 - w) * e * e) / max((1 - w).sum(), 1e-12)), noise_var * 1.0001)
    ll2 = float(np.sum(np.log((1 - f) * np.exp(-e * e / (2 * v0)) / np.sqrt(2 * np.pi * v0)
                              + f * np.exp(-e * e / (2 * v1)) / np.sqrt(2 * np.pi * v1))))
    ll1 = float(np.sum(-e * e / (2 * v_all) - 0.5 * np.log(2 * np.pi * v_all)))
    return f, math.sqrt(max(v0 - noise_var, 0.0)), math.sqrt(max(v1 - noise_var, 0.0)), ll2 - ll1


def fit_outliers(flat: HalfRates, dark: HalfRates | None, camera: SpikeCamera, seed: int = 0) -> list[Fitted]:
    """outlier_pixel_fraction and outlier_gain_spread from a flat: the relative responses are a
    mixture of the pixels' gain spread and a share of outlier pixels with an extra gain factor
    N(1, s) (SpikeCamera's outlier terms), fitted by EM with the counting noise (from the two halves)
    taken out; kept when two components beat one by OUTLIER_BIC_MARGIN, else both 0. Standard
    errors by a bootstrap over the pixels."""
    where = f"{Path(flat.path).name} ({flat.steps} steps, flat)"
    ra, rb = (flat.a - dark.a, flat.b - dark.b) if dark is not None else (flat.a - camera.dark_per_step,
                                                                         flat.b - camera.dark_per_step)
    keep = ~hot_pixels(dark.mean) if dark is not None else np.ones(ra.shape, bool)
    mean = float(((ra + rb) / 2)[keep].mean())
    e = (((ra + rb) / 2)[keep] / mean - 1.0).ravel()
    noise_var = float(np.var((ra - rb)[keep] / mean)) / 4.0  # of the halves' mean
    f, sd0, sd1, gain = _mixture(e, noise_var)
    if 2 * gain < 3 * math.log(e.size) + OUTLIER_BIC_MARGIN or sd1 <= sd0:  # 3 parameters against 1
        return [Fitted("outlier_pixel_fraction", 0.0, 0.0, where + ": no outlier population"),
                Fitted("outlier_gain_spread", 0.0, 0.0, where + ": no outlier population")]
    spread = math.sqrt(max(sd1 ** 2 - sd0 ** 2, 0.0))
    rng = np.random.default_rng(seed)
    boot = []
    for _ in range(OUTLIER_BOOTSTRAP):
        bf, b0, b1, _ = _mixture(rng.choice(e, e.size), noise_var)
        boot.append((bf, math.sqrt(max(b1 ** 2 - b0 ** 2, 0.0)), b0))
    se_f, se_s, se_0 = (float(np.std(v, ddof=1)) for v in zip(*boot))
    # with outliers, the pixels' own spread is the mixture's narrow part, not the whole flat's
    return [Fitted("outlier_pixel_fraction", f, se_f, where), Fitted("outlier_gain_spread", spread, se_s, where),
            Fitted("gain_spread", sd0, se_0, where + ", without its outlier pixels")]


def combine(fits: Sequence[Fitted]) -> Fitted:
    """Several estimates of one field (flats at two levels) as their inverse-variance mean."""
    if len(fits) == 1:
        return fits[0]
    w = np.array([1.0 / max(f.uncertainty, 1e-12) ** 2 for f in fits])
    v = np.array([f.value for f in fits])
    return Fitted(fits[0].field, float((w * v).sum() / w.sum()), float(1.0 / math.sqrt(w.sum())),
                  " + ".join(f.source for f in fits))


#: A scene recording must fire at least this many times the dark rate on average: below it the
#: "gain" measured is the dark current's own pattern (round nine: a lens-capped recording given as
#: --scene was fitted as row and column spreads of 0.067 and 0.023).
SCENE_MIN_OVER_DARK = 3.0


def check_scene_lit(scene: HalfRates, dark: HalfRates | None = None, dark_rate: float | None = None) -> None:
    """A ValueError naming the recording when a scene fires less than SCENE_MIN_OVER_DARK times
    the dark rate (`dark`'s, else `dark_rate`, spikes per step): it is dark, not a scene."""
    if dark is not None:
        dark_rate = float(dark.mean.mean())
    if dark_rate is not None and float(scene.mean.mean()) < SCENE_MIN_OVER_DARK * dark_rate:
        raise ValueError(f"{scene.path}: a scene recording fires {float(scene.mean.mean()):.3g} spikes per step on "
                         f"average, less than {SCENE_MIN_OVER_DARK:g} times the dark rate ({dark_rate:.3g}): it is dark; "
                         "a scene recording is lit")


def fit_scene(scene: HalfRates, dark: HalfRates | None = None, dark_rate: float | None = None) -> list[Fitted]:
    """row_gain_spread and column_gain_spread from a scene: each pixel's rate over its
    neighbourhood's median (NEIGHBOURHOOD_PX), averaged along rows and columns in each half; the
    split-half spread of those means across rows (columns). `dark_rate` (spikes per step: the dark
    recording's, else the camera's dark current) refuses a scene that is no brighter than dark.

    Only for a scene whose texture the median takes out (smooth, or finer than the neighbourhood):
    texture that varies by row or column at larger scales is in both halves as a fixed pattern is,
    and is read as one (round ten: 0.24 and 0.16 from a car scene of a camera with none), which
    one recording cannot tell apart. `spikesim calibrate` does not use it for that reason."""
    from scipy.ndimage import median_filter

    where = f"{Path(scene.path).name} ({scene.steps} steps, scene)"
    check_scene_lit(scene, dark, dark_rate)
    a, b = (scene.a - dark.a, scene.b - dark.b) if dark is not None else (scene.a, scene.b)
    local = median_filter(scene.mean if dark is None else (a + b) / 2, size=NEIGHBOURHOOD_PX, mode="reflect")
    lit = local > max(float(np.percentile(local, 10)), 1e-6)  # where there is light to measure a gain on
    if lit.any(axis=1).sum() < 3 or lit.any(axis=0).sum() < 3:
        # a spikeless or dark recording gave NumPy's warnings and "a spread needs at least 3 samples, got 0" (round eight)
        raise ValueError(f"{where}: too little light for a gain to be measured (lit pixels in "
                         f"{int(lit.any(axis=1).sum())} row(s) and {int(lit.any(axis=0).sum())} column(s), at least 3 "
                         "of each needed); record a lit, textured scene")
    ra = np.where(lit, a / np.where(lit, local, 1.0), np.nan)
    rb = np.where(lit, b / np.where(lit, local, 1.0), np.nan)
    # What is left of each ratio once its row's and column's means are taken out: the pixels' own gain
    # spread and the texture the median misses. Fixed, so in both halves, it reaches a row's mean as
    # var / (the row's pixels): 0.007 / 0.009 of row / column spread read on a camera with none
    # (64 x 100, round six). Its split-half variance is taken out of each line's.
    res = [r - np.nanmean(r, axis=1, keepdims=True) - np.nanmean(r, axis=0, keepdims=True) + np.nanmean(r)
           for r in (ra, rb)]
    both = np.isfinite(res[0]) & np.isfinite(res[1])
    pixel_var = max(float(np.cov(res[0][both], res[1][both])[0, 1]), 0.0) if both.sum() > 2 else 0.0
    out = []
    for field, axis in (("row_gain_spread", 1), ("column_gain_spread", 0)):
        ma, mb = np.nanmean(ra, axis=axis), np.nanmean(rb, axis=axis)
        ok = np.isfinite(ma) & np.isfinite(mb)
        sd, se = split_half_spread(ma[ok], mb[ok])
        counts = np.sum(np.isfinite(ra) & np.isfinite(rb), axis=axis)[ok]
        leak = pixel_var * float(np.mean(1.0 / np.maximum(counts, 1)))
        var = sd * sd - leak
        # the standard error of the variance carries over; of the spread, it is se_var / (2 sd)
        se_var = 2.0 * sd * se if sd > 0 else se * se
        out.append(Fitted(field, math.sqrt(var) if var > 0 else 0.0,
                          se_var / (2.0 * math.sqrt(var)) if var > se_var else math.sqrt(se_var), where))
    return out


#: Which recording (and its flag) each fitted field comes from, for the errors that name it.
FIELD_RECORDING = {"dark_current_hz": ("--dark", "a dark recording (lens capped)"),
                   "dark_current_spread": ("--dark", "a dark recording (lens capped)"),
                   "gain_spread": ("--flat", "a flat recording (uniform light)"),
                   "outlier_pixel_fraction": ("--flat", "a flat recording (uniform light)"),
                   "outlier_gain_spread": ("--flat", "a flat recording (uniform light)"),
                   "row_gain_spread": ("--scene", "a scene recording"),
                   "column_gain_spread": ("--scene", "a scene recording")}


def calibrated_camera(base: SpikeCamera, fitted: Sequence[Fitted]) -> SpikeCamera:
    """`base` with every fitted field set; a fitted gain spread also sets the threshold mismatch and
    offset to 0 (it holds them: module docstring). A fitted value the camera model does not take is
    refused naming the field, its value and error, the recording and the flag, and what to do."""
    changes = {f.field: float(f.value) for f in fitted}
    if "gain_spread" in changes:
        changes.update(threshold_mismatch=0.0, threshold_offset=0.0)
    try:
        return base.replace(**changes)
    except ValueError as exc:
        # round ten: "gain_spread=0.333... is above the supported maximum 0.3" named no recording, no flag
        # and no way forward (a valid camera of gain_spread 0.3 and threshold_offset 0.2 measures 0.36)
        culprit = next((f for f in fitted if str(exc).startswith(f"{f.field}=")), None)
        if culprit is None:
            raise ValueError(f"the camera fitted from {', '.join(sorted({f.source for f in fitted}))} is not one the "
                             f"camera model takes: {exc}; check those recordings, or calibrate from fewer of them "
                             "(an unfitted field keeps --camera's value)") from None
        flag, what = FIELD_RECORDING.get(culprit.field, ("its recording", "its recording"))
        held = (" (a flat measures gain spread, threshold mismatch and offset together, sqrt(gain^2 + mismatch^2 + "
                "offset^2), and the file holds them as gain_spread alone)" if culprit.field == "gain_spread" else "")
        raise ValueError(f"{flag} {culprit.source}: fitted {culprit.field} = {culprit.value:.4g} +- "
                         f"{culprit.uncertainty:.2g}{held}, outside the camera model's range ({exc}); a camera file "
                         f"cannot hold it. Check that the recording is {what} of this camera; if it is, its camera "
                         f"is outside what the simulator models: calibrate without {flag} to keep --camera's "
                         f"{culprit.field}, or write the camera file by hand") from None


__all__ = ["Fitted", "HalfRates", "DarkFit", "half_rates", "split_half_spread", "hot_pixels", "fit_dark", "fit_flat",
           "fit_outliers",
           "check_scene_lit", "fit_scene", "combine", "calibrated_camera", "FIELD_RECORDING"]
