"""The spike camera's configuration: geometry, readout and every noise term.

Units: light and charge are measured in thresholds. A pixel's input `y` is the expected number of
spikes per readout step (photo-current x readout period / threshold, docs/design.md section 2), so the
nominal threshold is 1 and every noise magnitude below is a fraction of it.

Each noise term is its own documented option (in the manner of v2e); a magnitude of 0 (or
`"off"`) switches it off, and the kernels then leave its code out entirely.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SHOT_NOISE_MODELS = ("off", "gaussian", "poisson", "renewal")
#: Physical ranges of the camera's scales (checked at construction). Threshold: a spike camera's
#: threshold is a fraction of its pixel's full well, and CMOS full-well capacities run 1e3-1e6
#: photo-electrons (Janesick, "Photon Transfer", 2007); below 10 e- one step's shot noise is no
#: longer near Gaussian (shot_noise="gaussian"), and a value like 1e-300 made every pixel fire
#: once and stop. Readout: 10 MHz to 1 Hz, around the 20-40 kHz of real spike cameras.
THRESHOLD_ELECTRONS_RANGE = (10.0, 1e8)
READOUT_PERIOD_RANGE_S = (1e-7, 1.0)

#: The built-in cameras: the published magnitudes, the published plus the terms measured on a
#: real recording, and the ideal pixel.
CAMERA_PRESETS = ("realistic", "measured", "noiseless", "scsim")

#: Irradiance above this many expected spikes per step is bounded to it at the sensor's input.
#: A pixel saturates at one spike per step, so any y above ~2 already fires at every step (the
#: accumulator is clamped to [-threshold, 2 threshold]); the bound only keeps gain, shot noise and
#: the accumulator finite for renderer fireflies and absurd inputs (y = 3.4e38 gave NaN
#: accumulators and dead pixels before it).
Y_MAX = 1000.0
#: The largest height or width of a camera (the PKU sensor is 250 x 400): a sensor of 10^6 rows
#: is a typo, and its state alone would not fit in memory.
MAX_SIDE = 1 << 16
PRECISIONS = ("float32", "float64")
DARK_CURRENT_LAWS = ("lognormal", "normal")
#: Switches added after the first camera, with their defaults: recorded only when not at their
#: default, as LATER_TERMS, so every camera made before them keeps its dictionary and identity.
LATER_SWITCHES = {"dark_current_law": "lognormal", "reset_rule": "threshold"}
RESET_RULES = ("threshold", "fired")

#: Noise terms and the value that switches each off.
NOISE_TERMS: dict[str, Any] = {
    "dark_current_hz": 0.0,
    "dark_current_spread": 0.0,
    "gain_spread": 0.0,
    "threshold_mismatch": 0.0,
    "threshold_offset": 0.0,
    "comparator_noise": 0.0,
    "shot_noise": "off",
    "reset_loss": 0.0,
    "random_initial_state": False,
    "row_gain_spread": 0.0,
    "column_gain_spread": 0.0,
    "outlier_pixel_fraction": 0.0,
    "outlier_gain_spread": 0.0,
}

#: Terms added after the first camera (measured on a real recording, docs/sensor.md "A camera
#: like the real one"). A camera records them only when they are on, so every camera made
#: without them keeps the dictionary, and the dataset identity, it had before they existed.
LATER_TERMS = ("row_gain_spread", "column_gain_spread", "outlier_pixel_fraction", "outlier_gain_spread")

#: The terms measured on the UHSR recording of a real PKU spike camera (250 x 250, 200 steps,
#: 0.031 spikes per step; docs/sensor.md "A camera like the real one"): the same no-reference
#: statistics (flat-region per-pixel rate spread, robust and plain, its tail beyond 30 %, the spread
#: of row and column medians) measured on the recording and on a simulated twin of it (the realistic
#: camera under the recording's own smoothed rate map), and these values chosen so the twin matches
#: the recording within the statistics' seed-to-seed noise. Hot and dead pixels (2 and 1 of 62,500)
#: and the inter-spike-interval shape (CV 0.037, as the realistic camera) needed no new term.
MEASURED_TERMS: dict[str, float] = {
    "gain_spread": 0.077,
    "row_gain_spread": 0.015,
    "column_gain_spread": 0.010,
    "outlier_pixel_fraction": 0.12,
    "outlier_gain_spread": 0.40,
}

#: SCSim's camera (Zhao et al. 2024, its `v2s.py`), its constants mapped onto this model's fields:
#: a 20 kHz readout, its dark current and spreads, and its shot noise at 5e4 electrons per threshold
#: (docs/sensor.md, "Other simulators' cameras", with what still differs and by how much). Run beside
#: this sensor with these values, mean rates agreed within 0.5 % at ten light levels.
SCSIM_TERMS: dict[str, Any] = {
    "readout_period_s": 50e-6,
    "dark_current_hz": 93.5,
    "dark_current_spread": 0.39,
    "gain_spread": 0.0577,
    "threshold_mismatch": 0.0029,
    "threshold_offset": 0.0455,
    "comparator_noise": 0.0058,
    "threshold_electrons": 5e4,
    "reset_loss": 0.002,
    "dark_current_law": "normal",
    "reset_rule": "fired",
}


@dataclass(frozen=True)
class SpikeCamera:
    """A spike camera: integrate-and-fire pixels read out every `readout_period_s`.

    The defaults are the published magnitudes (the "realistic" preset); `SpikeCamera.noiseless()`
    switches every noise term off.

    Saturation: at most one spike is read out per step. Charge that one spike per step cannot
    carry is discarded (the accumulator is clamped to [-threshold, 2 threshold], room for the
    residuals of a noisy comparator), so a pixel with y >= 1 fires at every step and its
    accumulator stays bounded.
    """

    height: int = 250
    """Rows of the sensor (400 x 250 is the PKU spike camera; docs/design.md section 2)."""
    width: int = 400
    """Columns of the sensor."""
    readout_period_s: float = 25e-6
    """T, the time between readouts: 25 us = 40 kHz (some sensors run at 20 kHz, 50 us)."""
    threshold_electrons: float = 1000.0
    """Photo-electrons one threshold represents; sets the size of photon shot noise and, with
    the optics and pixel response of the renderer's exposure calibration (docs/scenes.md,
    section 4: 20 um pixel, f/1.4), converts light into y: a white surface under 100 lux
    collects about 290 e- per 25 us step, so 1000 e- per threshold gives y ~ 0.3, the firing
    rate of indoor recordings."""

    dark_current_hz: float = 94.0
    """Mean dark current in thresholds per second: 0.47 % of the threshold per step at 20 kHz
    (SCSim 2024, SpikingSIM 2022), i.e. about 94 dark spikes/s. A current, so per step it
    scales with the readout period."""
    dark_current_spread: float = 0.39
    """Pixel-to-pixel coefficient of variation of the dark current (SCSim 2024: 39 %), drawn
    lognormal so it stays positive with the skew of real dark-current maps."""
    gain_spread: float = 0.058
    """Photo-response non-uniformity: standard deviation of the per-pixel gain (5.8 %)."""
    threshold_mismatch: float = 0.003
    """Per-pixel relative threshold error from capacitance mismatch (0.3 %)."""
    threshold_offset: float = 0.045
    """Per-pixel comparator voltage offset as a fraction of the threshold swing (4.5 %)."""
    comparator_noise: float = 0.006
    """Temporal comparator noise, redrawn at every comparison, fraction of threshold (0.6 %)."""
    shot_noise: str = "gaussian"
    """Photon (and dark-electron) shot noise: "off", "gaussian" (per-step increment with the
    Poisson variance, all backends), "poisson" (exact per-step Poisson, NumPy reference only) or
    "renewal" (drawn once per spike, all backends). Reaching the threshold sums ~threshold_electrons
    electrons, so the per-step models differ only in the third cumulant of the spike time,
    O(1/sqrt(threshold_electrons)); tests check they agree.

    "renewal" uses the time-rescaling of a Poisson process: with reset by subtraction, the spike
    times are where the expected charge reaches the arrival of each threshold's worth of electrons,
    so each interval's threshold charge is Gamma(k)/k (k = threshold x threshold_electrons) and the
    charge between spikes needs no draw: exact for Poisson electrons, counted by spike so that
    backends agree bit for bit without comparator noise. The golden statistics cannot tell it
    from "gaussian" at 1000 e- (docs/sensor.md)."""
    reset_loss: float = 0.002
    """Fraction of the integration lost in the step after a spike (reset/readout delay, 0.2 %)."""
    random_initial_state: bool = True
    """Start each accumulator uniform in [0, threshold) instead of empty."""
    precision: str = "float32"
    """Accumulator precision: "float32" (fast) or "float64"."""
    row_gain_spread: float = 0.0
    """Fixed-pattern gain of each row (shared readout line), standard deviation; 0 in the published
    camera, 0.015 measured on a real recording (the `measured` preset)."""
    column_gain_spread: float = 0.0
    """Fixed-pattern gain of each column (column amplifier), standard deviation; 0 in the published
    camera, 0.010 measured on a real recording (the `measured` preset)."""
    outlier_pixel_fraction: float = 0.0
    """Fraction of pixels whose gain is an outlier (the heavy tail of a real sensor's rate spread:
    4 % of flat-region pixels 30 % off their neighbours, against 0.3 % simulated); 0.12 measured."""
    outlier_gain_spread: float = 0.0
    """Standard deviation of an outlier pixel's extra gain factor (a normal around 1, clipped at
    0); 0.40 measured on a real recording (the `measured` preset)."""
    reset_rule: str = "threshold"
    """What a spike takes from the accumulator: "threshold" (the pixel's threshold) or "fired" (the
    level the noisy comparator fired at, threshold + its comparator noise that step: SCSim's rule;
    a pixel fires when the noise is low, so it keeps more charge: +0.5 % rate in the dark). The
    same with comparator_noise 0."""
    dark_current_law: str = "lognormal"
    """How the per-pixel dark current is drawn around its mean: "lognormal" (positive, with the skew
    of real dark-current maps) or "normal" (SCSim's law, clipped at 0: at a 39 % spread, 0.5 % of
    the pixels get no dark current and never fire in the dark; docs/sensor.md, "Other simulators'
    cameras")."""

    def __post_init__(self) -> None:
        _check_int("height", self.height)
        _check_int("width", self.width)
        _check_positive("readout_period_s", self.readout_period_s)
        if not READOUT_PERIOD_RANGE_S[0] <= self.readout_period_s <= READOUT_PERIOD_RANGE_S[1]:
            raise ValueError(f"readout_period_s={_shown(self.readout_period_s)} s is not a sensor readout period: expected "
                             f"{READOUT_PERIOD_RANGE_S[0]:g} to {READOUT_PERIOD_RANGE_S[1]:g} s (10 MHz to 1 Hz; spike "
                             "cameras read at 20-40 kHz)")
        _check_positive("threshold_electrons", self.threshold_electrons)
        if not THRESHOLD_ELECTRONS_RANGE[0] <= self.threshold_electrons <= THRESHOLD_ELECTRONS_RANGE[1]:
            raise ValueError(f"threshold_electrons={_shown(self.threshold_electrons)} is not a pixel's threshold: expected "
                             f"{THRESHOLD_ELECTRONS_RANGE[0]:g} to {THRESHOLD_ELECTRONS_RANGE[1]:g} photo-electrons "
                             "(CMOS full-well capacities are 1e3-1e6 e-; below 10 e- per spike the Gaussian shot "
                             "noise of one step is not a valid model)")
        for name in ("dark_current_hz", "dark_current_spread", "gain_spread", "threshold_mismatch",
                     "threshold_offset", "comparator_noise", "reset_loss", *LATER_TERMS):
            _check_nonnegative(name, getattr(self, name))
        # Spreads above these make the drawn pixel parameters meaningless (negative gains or
        # thresholds many sigma away); reject rather than clip silently.
        for name, limit in (("gain_spread", 0.3), ("threshold_mismatch", 0.2), ("threshold_offset", 0.2),
                            ("comparator_noise", 0.5), ("dark_current_spread", 5.0),
                            ("row_gain_spread", 0.3), ("column_gain_spread", 0.3), ("outlier_gain_spread", 1.0)):
            if getattr(self, name) > limit:
                raise ValueError(f"{name}={getattr(self, name)} is above the supported maximum {limit}")
        if self.outlier_pixel_fraction > 1.0:
            raise ValueError(f"outlier_pixel_fraction={self.outlier_pixel_fraction} is a fraction of the pixels (0..1)")
        if (self.outlier_pixel_fraction > 0) != (self.outlier_gain_spread > 0):
            raise ValueError("outlier_pixel_fraction and outlier_gain_spread go together: both 0 (off) or both > 0, got "
                             f"{self.outlier_pixel_fraction} and {self.outlier_gain_spread}")
        if self.reset_loss >= 1.0:
            raise ValueError(f"reset_loss={self.reset_loss} must be below 1 (it is a fraction of one step)")
        if self.dark_current_hz * self.readout_period_s >= 1.0:
            raise ValueError(
                f"dark_current_hz={self.dark_current_hz} gives {self.dark_current_hz * self.readout_period_s:.3g} "
                "thresholds per step: a dark current that saturates the pixel is not a dark current")
        if self.shot_noise not in SHOT_NOISE_MODELS:
            raise ValueError(f"shot_noise={self.shot_noise!r}; expected one of {SHOT_NOISE_MODELS}")
        if self.precision not in PRECISIONS:
            raise ValueError(f"precision={self.precision!r}; expected one of {PRECISIONS}")
        if self.reset_rule not in RESET_RULES:
            raise ValueError(f"reset_rule={self.reset_rule!r}; expected one of {RESET_RULES}")
        if self.dark_current_law not in DARK_CURRENT_LAWS:
            raise ValueError(f"dark_current_law={self.dark_current_law!r}; expected one of {DARK_CURRENT_LAWS}")
        if not isinstance(self.random_initial_state, bool):
            raise TypeError(f"random_initial_state must be a bool, got {self.random_initial_state!r}")

    # ---- derived quantities -------------------------------------------------------------------
    @property
    def readout_rate_hz(self) -> float:
        return 1.0 / self.readout_period_s

    @property
    def dark_per_step(self) -> float:
        """Mean dark current in thresholds per readout step (d in docs/design.md section 2)."""
        return self.dark_current_hz * self.readout_period_s

    @property
    def num_pixels(self) -> int:
        return self.height * self.width

    @property
    def is_noiseless(self) -> bool:
        return all(getattr(self, k) == v for k, v in NOISE_TERMS.items())

    @property
    def has_temporal_noise(self) -> bool:
        """Whether the stream depends on per-step random draws (else it is deterministic)."""
        return self.shot_noise != "off" or self.comparator_noise > 0

    # ---- presets and variations -------------------------------------------------------------
    @classmethod
    def realistic(cls, **overrides: Any) -> "SpikeCamera":
        """Every noise term on at its published magnitude."""
        return cls(**overrides)

    @classmethod
    def measured(cls, **overrides: Any) -> "SpikeCamera":
        """The realistic camera plus the fixed-pattern terms measured on a real recording
        (MEASURED_TERMS)."""
        return cls(**{**MEASURED_TERMS, **overrides})

    @classmethod
    def scsim(cls, **overrides: Any) -> "SpikeCamera":
        """SCSim's camera (SCSIM_TERMS), so that a dataset is made as that simulator makes one."""
        return cls(**{**SCSIM_TERMS, **overrides})

    @classmethod
    def noiseless(cls, **overrides: Any) -> "SpikeCamera":
        """The ideal integrate-and-fire pixel: no noise, empty accumulators at step 0."""
        return cls(**{**NOISE_TERMS, **overrides})

    def without(self, *terms: str) -> "SpikeCamera":
        """A copy with the named noise terms switched off."""
        unknown = [t for t in terms if t not in NOISE_TERMS]
        if unknown:
            raise ValueError(f"unknown noise term(s) {unknown}; known: {sorted(NOISE_TERMS)}")
        off = {t: NOISE_TERMS[t] for t in terms}
        for pair in (("outlier_pixel_fraction", "outlier_gain_spread"),):  # one term, two numbers
            if off.keys() & set(pair):
                off.update({t: NOISE_TERMS[t] for t in pair})
        return dataclasses.replace(self, **off)

    def replace(self, **changes: Any) -> "SpikeCamera":
        return dataclasses.replace(self, **changes)

    # ---- files --------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        for name in LATER_TERMS:  # recorded only when on (LATER_TERMS)
            if out[name] == NOISE_TERMS[name]:
                del out[name]
        for name, default in LATER_SWITCHES.items():  # likewise recorded only when switched
            if out[name] == default:
                del out[name]
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "SpikeCamera":
        if "preset" in data:
            data = dict(data)
            preset = data.pop("preset")
            if preset not in CAMERA_PRESETS:
                raise ValueError(f"unknown camera preset {preset!r}; expected one of {CAMERA_PRESETS}")
            base = cls.preset(preset)
            return base.replace(**_known_fields(cls, data))
        return cls(**_known_fields(cls, data))

    @classmethod
    def preset(cls, name: str) -> "SpikeCamera":
        """A built-in camera by name (CAMERA_PRESETS)."""
        if name not in CAMERA_PRESETS:
            raise ValueError(f"unknown camera preset {name!r}; expected one of {CAMERA_PRESETS}")
        return getattr(cls, name)()

    @classmethod
    def from_file(cls, path: str | Path) -> "SpikeCamera":
        """Load a camera from JSON (or TOML); unknown keys are an error naming the file."""
        from .config_io import load_config_file
        return load_config_file(path, cls.from_dict)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")


def _known_fields(cls: type, data: dict[str, Any]) -> dict[str, Any]:
    from .config_io import check_known_fields
    return check_known_fields(cls, data, "camera parameter(s)")


def _shown(value: Any) -> str:
    """A value for a message: a huge integer as its size, not its 400 digits."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10 ** 20:
        return f"an integer of about {int(abs(value).bit_length() * math.log10(2)) + 1} digits"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_int(name: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= MAX_SIDE:
        raise ValueError(f"{name} must be an integer in 1..{MAX_SIDE}, got {_shown(value)}")


def _finite(value: Any) -> float | None:
    """`value` as a finite float, or None (a bool, a string, NaN, inf, an int beyond float's range)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return None
    try:
        v = float(value)
    except OverflowError:
        return None
    return v if math.isfinite(v) else None


def _check_positive(name: str, value: Any) -> None:
    v = _finite(value)
    if v is None or v <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {_shown(value)}")


def _check_nonnegative(name: str, value: Any) -> None:
    v = _finite(value)
    if v is None or v < 0:
        raise ValueError(f"{name} must be a finite number >= 0, got {_shown(value)}")


__all__ = ["SpikeCamera", "NOISE_TERMS", "LATER_TERMS", "MEASURED_TERMS", "SCSIM_TERMS", "CAMERA_PRESETS", "SHOT_NOISE_MODELS", "PRECISIONS", "Y_MAX", "MAX_SIDE"]
