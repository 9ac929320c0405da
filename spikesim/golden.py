"""Golden statistics: a regression check of a camera model (the built-in realistic one, a user's
own, or changed simulator code) against a stored reference, with a measured detection power.

A fixed test scene is simulated and a few statistics are measured per band of light, each with a
standard error from batch means over pixel blocks (pixels are independent, so block means are
too). The bands: darkness, 0.003, 0.03 and 0.3 spikes per step, and a `switch` band at 0.9 for the
first half of the steps and 0.3 for the second. Each statistic answers to particular noise terms:

- `rate_per_step`: dark current (dark band), gain and threshold offsets (lit bands);
- `rate_cv`, the pixel-to-pixel spread of the rate: dark-current spread (dark band), gain spread
  and threshold offset (lit bands);
- `isi_cv2`, the squared coefficient of variation of each pixel's inter-spike intervals: shot
  noise, and comparator noise (whose jitter adds (comparator_noise / shot sigma)^2 ~ 4 % to it);
- `rate_ratio` (switch band), each pixel's rate at 0.9 over its rate at 0.3: the pixel's own gain
  and threshold cancel, leaving what depends on the light level itself, reset loss above all;
- `fano_41`, `dark_fraction_41`: what a 41-step window sees.

A statistic fails when |measured - reference| exceeds z_crit combined standard errors, with z_crit
set by a Bonferroni correction so that an unchanged camera fails the whole check with probability
FAMILY_FALSE_ALARM. The measurement uses another seed than the reference, so a pass is statistical
agreement, not a replay.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .camera import SpikeCamera
from .simulate import Simulator
from .stream import SpikeStream

#: Design of the test scene (spikes per step per band; the switch band's two halves).
LEVELS_Y = (0.0, 0.003, 0.03, 0.3)
SWITCH_Y = (0.9, 0.3)
BANDS = tuple(f"y={y:g}" for y in LEVELS_Y) + ("switch",)
HEIGHT, WIDTH = 256, 160
WINDOW = 41
NUM_STEPS = 100 * WINDOW
BLOCKS = 64
REFERENCE_SEED = 0
MEASURE_SEED = 1
#: Probability that an unchanged camera fails the check (any statistic), by Bonferroni.
FAMILY_FALSE_ALARM = 1e-3
#: The project's own reference: the realistic camera on the NumPy backend.
PACKAGED_REFERENCE = Path(__file__).with_name("data") / "golden_realistic.json"
LAYOUT_VERSION = 2


def test_frames(camera: SpikeCamera) -> tuple[np.ndarray, np.ndarray]:
    """The two y frames of the test scene (first and second half of the steps)."""
    band = WIDTH // len(BANDS)
    first = np.zeros((HEIGHT, WIDTH), np.float32)
    for i, y in enumerate(LEVELS_Y):
        first[:, i * band:(i + 1) * band] = y
    second = first.copy()
    first[:, len(LEVELS_Y) * band:] = SWITCH_Y[0]
    second[:, len(LEVELS_Y) * band:] = SWITCH_Y[1]
    return first, second


def golden_camera(camera: SpikeCamera | None = None) -> SpikeCamera:
    """The camera at the test scene's size (the reference's: SpikeCamera.realistic())."""
    return dataclasses.replace(camera or SpikeCamera.realistic(), height=HEIGHT, width=WIDTH)


def simulate(camera: SpikeCamera, backend: str, seed: int) -> SpikeStream:
    first, second = test_frames(camera)
    half = NUM_STEPS // 2
    frames = [first] * half + [second] * (NUM_STEPS - half)
    return Simulator(golden_camera(camera), backend=backend, seed=seed).run(iter(frames))


def _isi_moments(spikes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel: number of ISIs, their mean and variance (spikes: bool (N, P)), one step at a time
    (a pass over the steps costs far less than sorting every spike by pixel)."""
    p = spikes.shape[1]
    last = np.full(p, -1, np.int64)
    n = np.zeros(p)
    s1 = np.zeros(p)
    s2 = np.zeros(p)
    for t in range(spikes.shape[0]):
        fired = np.flatnonzero(spikes[t])
        prev = last[fired]
        seen = fired[prev >= 0]
        d = (t - prev[prev >= 0]).astype(np.float64)
        n[seen] += 1
        s1[seen] += d
        s2[seen] += d * d
        last[fired] = t
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / n
        var = (s2 - n * mean ** 2) / (n - 1)
    return n, mean, var


def _per_pixel(stream: SpikeStream) -> dict[str, np.ndarray]:
    s = stream.unpack().reshape(stream.num_steps, -1)
    half = NUM_STEPS // 2
    rate = s.mean(axis=0, dtype=np.float64)
    counts = s[: (NUM_STEPS // WINDOW) * WINDOW].reshape(-1, WINDOW, s.shape[1]).sum(axis=1, dtype=np.float64)
    mean_c = counts.mean(axis=0)
    n, mean_isi, var_isi = _isi_moments(s[:half])  # the first half: one light level for every band
    with np.errstate(invalid="ignore", divide="ignore"):
        fano = np.where(mean_c > 0, counts.var(axis=0, ddof=1) / mean_c, np.nan)
        isi_cv2 = np.where(n >= 3, var_isi / mean_isi ** 2, np.nan)
        ratio = s[:half].mean(axis=0, dtype=np.float64) / s[half:].mean(axis=0, dtype=np.float64)
    return {"rate_per_step": rate, "fano_41": fano, "dark_fraction_41": (counts == 0).mean(axis=0),
            "isi_cv2": isi_cv2, "rate_ratio": np.where(np.isfinite(ratio), ratio, np.nan)}


def _mean_and_se(values: np.ndarray) -> dict[str, float] | None:
    blocks = [b[np.isfinite(b)] for b in np.array_split(values, BLOCKS)]
    means = np.array([b.mean() for b in blocks if b.size])
    if means.size < BLOCKS // 2:
        return None  # too few pixels with the statistic defined (e.g. no ISIs in darkness)
    se = float(means.std(ddof=1) / math.sqrt(means.size))
    if se == 0:
        return None  # the same in every pixel (a 41-step window at y = 0.03 is never dark): no information
    return {"value": float(np.nanmean(values)), "se": se}


def _cv_and_se(values: np.ndarray) -> dict[str, float] | None:
    if not values.mean() > 0:
        return None
    blocks = [b for b in np.array_split(values, BLOCKS) if b.mean() > 0]
    cvs = np.array([b.std() / b.mean() for b in blocks])
    return {"value": float(values.std() / values.mean()), "se": float(cvs.std(ddof=1) / math.sqrt(cvs.size))}


def _binomial_ok(fraction: float, pixels: int) -> bool:
    """Whether a fraction of windows is far enough from 0 and 1 for its block means to be normal:
    at least 10 expected windows on each side per block (the usual rule for the binomial)."""
    windows_per_block = pixels / BLOCKS * (NUM_STEPS // WINDOW)
    return min(fraction, 1.0 - fraction) * windows_per_block >= 10


#: Which statistics each band reports.
_BAND_STATS = {"rate_per_step", "rate_cv", "fano_41", "dark_fraction_41", "isi_cv2"}


def measure(camera: SpikeCamera | None = None, backend: str = "numpy", seed: int = MEASURE_SEED) -> dict[str, Any]:
    """The statistics of `camera` (default realistic) on the test scene, with standard errors."""
    cam = golden_camera(camera)
    per_pixel = _per_pixel(simulate(cam, backend, seed))
    band = WIDTH // len(BANDS)
    cols = np.tile(np.arange(WIDTH), HEIGHT)
    stats: dict[str, dict[str, dict[str, float]]] = {}
    for i, name in enumerate(BANDS):
        # pixels in column-major block order, so that each block spans many rows
        sel = np.flatnonzero(np.minimum(cols // band, len(BANDS) - 1) == i)
        sel = sel.reshape(HEIGHT, -1).T.ravel()
        entry = {}
        wanted = {"rate_ratio"} if name == "switch" else _BAND_STATS
        for stat in sorted(wanted):
            if stat == "rate_cv":
                value = _cv_and_se(per_pixel["rate_per_step"][sel])
            else:
                value = _mean_and_se(per_pixel[stat][sel])
            if stat == "dark_fraction_41" and value is not None and not _binomial_ok(value["value"], sel.size):
                value = None
            if value is not None:
                entry[stat] = value
        stats[name] = entry
    return {"layout": LAYOUT_VERSION, "design": design(), "camera": cam.to_dict(), "backend": backend, "seed": seed,
            "stats": stats}


def design() -> dict[str, Any]:
    """The test scene a reference was measured on (compare refuses another)."""
    return {"levels_y": list(LEVELS_Y), "switch_y": list(SWITCH_Y), "height": HEIGHT, "width": WIDTH,
            "num_steps": NUM_STEPS, "window": WINDOW, "blocks": BLOCKS}


def z_critical(num_statistics: int, family_false_alarm: float = FAMILY_FALSE_ALARM) -> float:
    """Two-sided normal quantile with a Bonferroni correction over the statistics."""
    from scipy.stats import norm

    return float(norm.isf(family_false_alarm / (2 * num_statistics)))


@dataclass(frozen=True)
class Row:
    band: str
    statistic: str
    value: float
    reference: float
    z: float
    passed: bool


def compare(measured: dict[str, Any], reference: dict[str, Any],
            family_false_alarm: float = FAMILY_FALSE_ALARM) -> list[Row]:
    """One row per statistic of the reference: the measured value, z-score and verdict."""
    if measured.get("design") != reference.get("design"):
        raise ValueError("the reference was measured on another test scene "
                         f"({reference.get('design')}); write a new one with `spikesim golden --write`")
    pairs = [(band, name, g) for band, entry in reference["stats"].items() for name, g in entry.items()]
    z_crit = z_critical(len(pairs), family_false_alarm)
    rows = []
    for band, name, g in pairs:
        m = measured["stats"].get(band, {}).get(name)
        if m is None:
            rows.append(Row(band, name, math.nan, g["value"], math.inf, False))
            continue
        se = math.hypot(g["se"], m["se"])
        z = (m["value"] - g["value"]) / se if se > 0 else (0.0 if m["value"] == g["value"] else math.inf)
        rows.append(Row(band, name, m["value"], g["value"], z, abs(z) <= z_crit))
    return rows


def load_reference(path: str | Path | None = None) -> dict[str, Any]:
    """A stored reference (default: the project's own), checked enough that `compare` cannot trip
    over a damaged file; errors name the file."""
    path = PACKAGED_REFERENCE if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"golden reference {path} does not exist; write one with "
                                "`spikesim golden --write --camera CAMERA -o REF.json`")
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"golden reference {path}: not valid JSON ({exc})") from None
    problem = _layout_problem(data)
    if problem:
        raise ValueError(f"golden reference {path}: {problem}")
    return data


def _layout_problem(data: Any) -> str | None:
    if not isinstance(data, dict) or data.get("layout") != LAYOUT_VERSION:
        return f"not a layout-{LAYOUT_VERSION} golden reference"
    stats = data.get("stats")
    if not isinstance(stats, dict) or not stats:
        return "no 'stats' object"
    for band, entry in stats.items():
        if not isinstance(entry, dict):
            return f"stats[{band!r}] is not an object"
        for name, g in entry.items():
            if not (isinstance(g, dict) and all(isinstance(g.get(k), (int, float)) and math.isfinite(g[k])
                                                for k in ("value", "se"))):
                return f"stats[{band!r}][{name!r}] lacks a finite 'value' and 'se'"
    return None


def write_reference(measured: dict[str, Any], path: str | Path) -> Path:
    """Write a reference atomically (temporary file, then rename)."""
    import os

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_text(json.dumps(measured, indent=2) + "\n")
    os.replace(tmp, path)
    return path


# ---- detection power -----------------------------------------------------------------------
#: The camera parameters the power study scales, and what each stands for. Scaling
#: threshold_electrons by f scales the shot-noise variance by 1/f.
POWER_TERMS = ("dark_current_hz", "dark_current_spread", "gain_spread", "threshold_offset",
               "threshold_mismatch", "threshold_electrons", "comparator_noise", "reset_loss")
POWER_CHANGES = (-0.5, -0.2, -0.1, 0.1, 0.2, 0.5, 1.0)


def changed(camera: SpikeCamera, term: str, change: float) -> SpikeCamera:
    return dataclasses.replace(camera, **{term: getattr(camera, term) * (1.0 + change)})


def detection_power(reference: dict[str, Any], camera: SpikeCamera | None = None, backend: str = "numpy",
                    seeds: Sequence[int] = (1, 2, 3, 4), terms: Sequence[str] = POWER_TERMS,
                    changes: Sequence[float] = POWER_CHANGES, progress: Any = None) -> dict[str, Any]:
    """Fraction of seeds at which the check fails, per term and relative change (and for the
    unchanged camera: the false-alarm rate), with the statistic that failed most often."""
    cam = golden_camera(camera)
    out: dict[str, Any] = {"seeds": list(seeds), "backend": backend, "unchanged": None, "terms": {}}

    def rate(c: SpikeCamera) -> dict[str, Any]:
        fails, which = 0, {}
        for s in seeds:
            rows = compare(measure(c, backend, s), reference)
            bad = [r for r in rows if not r.passed]
            fails += bool(bad)
            for r in bad:
                which[f"{r.band} {r.statistic}"] = which.get(f"{r.band} {r.statistic}", 0) + 1
            if progress is not None:
                progress.update(1)
        return {"detected": fails / len(seeds), "failing": max(which, key=which.get) if which else None}

    out["unchanged"] = rate(cam)
    for term in terms:
        out["terms"][term] = {f"{c:+.0%}": rate(changed(cam, term, c)) for c in changes}
    return out


__all__ = ["measure", "compare", "load_reference", "write_reference", "detection_power", "golden_camera",
           "z_critical", "Row", "PACKAGED_REFERENCE", "POWER_TERMS", "POWER_CHANGES", "BANDS"]
