"""The reflectance a silicon pixel sees: sRGB colours weighted by a light spectrum and the QE.

Why: the mono variant renders one number per surface, and Mitsuba's mono mode would use the
colour's luminance Y (the eye's weighting, V(lambda)). A silicon sensor weights the spectrum by
QE(lambda) lambda / (h c) instead, which sees far more of a red paint than V(lambda) does (under
daylight our red car reads 1.9x brighter spectrally than by its luminance). So for the mono path
every colour is replaced by its *sensor reflectance* under the scene's light,

    rho_s = integral rho(lambda) S(lambda) w(lambda) dlambda / integral S(lambda) w(lambda) dlambda,

with rho(lambda) Mitsuba's own RGB -> spectrum model (Jakob and Hanika, "A Low-Dimensional
Function Space for Efficient Spectral Upsampling", Eurographics 2019; `mi.srgb_model_fetch`), the
same model the spectral variant uses. For light that reaches the camera after one diffuse
bounce under one light spectrum, mono then equals spectral exactly; only inter-reflections
(products of two reflectances) remain approximate.
"""
from __future__ import annotations

import hashlib
import numpy as np

from . import spectra

#: Wavelengths (nm) of the reflectance integrals: 5 nm steps over Mitsuba's range.
GRID_NM = np.arange(spectra.LAMBDA_MIN_NM, spectra.LAMBDA_MAX_NM + 0.1, 5.0)
#: Nodes per axis of the lookup table over sRGB-encoded colours (trilinear in between).
LUT_NODES = 49
_LUTS: dict[str, np.ndarray] = {}


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _sigmoid_poly(coeffs: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Jakob-Hanika reflectance: S(c0 l^2 + c1 l + c2), S(x) = 1/2 + x / (2 sqrt(1 + x^2))."""
    x = coeffs[..., 0:1] * lam ** 2 + coeffs[..., 1:2] * lam + coeffs[..., 2:3]
    with np.errstate(over="ignore", invalid="ignore"):
        s = 0.5 + x / (2.0 * np.sqrt(1.0 + x * x))
    return np.where(np.isinf(x), (np.sign(x) + 1) / 2, s)


def _coefficients(linear_rgb: np.ndarray) -> np.ndarray:
    """Mitsuba's upsampling coefficients for (N, 3) linear RGB in [0, 1]."""
    from .backend import mi

    m = mi.scalar_rgb  # the table is the same in every variant; this works before any set_variant
    rgb = np.clip(np.asarray(linear_rgb, dtype=np.float64).reshape(-1, 3), 0.0, 1.0)
    fetch = m.srgb_model_fetch
    return np.array([tuple(fetch(c)) for c in rgb.tolist()], dtype=np.float64).reshape(-1, 3)


class SensorReflectance:
    """Maps sRGB colours to sensor reflectance under one spectral weight S(lambda) w(lambda)."""

    def __init__(self, weight: np.ndarray):
        """`weight` on spectra.WAVELENGTHS_NM: the light's spectrum times the pixel's e/J."""
        w = np.interp(GRID_NM, spectra.WAVELENGTHS_NM, np.asarray(weight, dtype=np.float64))
        if not np.all(np.isfinite(w)) or w.min() < 0 or w.sum() <= 0:
            raise ValueError("spectral weight must be finite, non-negative and not all zero")
        self._w = w / w.sum()  # 5 nm grid, uniform: a sum is the integral up to a constant
        self.digest = hashlib.sha256(self._w.tobytes()).hexdigest()[:16]

    def of_linear_rgb(self, linear_rgb: np.ndarray) -> np.ndarray:
        """Sensor reflectance of linear RGB colours (..., 3), exact (one model fetch per colour)."""
        arr = np.asarray(linear_rgb, dtype=np.float64)
        coeffs = _coefficients(arr)
        rho = _sigmoid_poly(coeffs, GRID_NM[None, :])
        return (rho @ self._w).reshape(arr.shape[:-1])

    def _lut(self) -> np.ndarray:
        if self.digest not in _LUTS:  # ~0.5 s to build; shared by every renderer with this weight
            nodes = np.linspace(0.0, 1.0, LUT_NODES)
            grid = np.stack(np.meshgrid(nodes, nodes, nodes, indexing="ij"), axis=-1)
            _LUTS[self.digest] = self.of_linear_rgb(srgb_to_linear(grid))
        return _LUTS[self.digest]

    def of_srgb_image(self, img: np.ndarray) -> np.ndarray:
        """Sensor reflectance (H, W) float32 of an 8-bit sRGB image (H, W, 3|4) via a lookup table
        (trilinear over sRGB-encoded values; error < 0.2 % of full scale, tests/render)."""
        from scipy.interpolate import RegularGridInterpolator

        a = np.asarray(img)
        if a.ndim == 2:
            a = np.repeat(a[..., None], 3, axis=2)
        rgb = a[..., :3].astype(np.float64) / (255.0 if a.dtype == np.uint8 else (65535.0 if a.dtype == np.uint16 else 1.0))
        nodes = np.linspace(0.0, 1.0, LUT_NODES)
        interp = RegularGridInterpolator((nodes, nodes, nodes), self._lut())
        return interp(rgb.reshape(-1, 3)).reshape(rgb.shape[:2]).astype(np.float32)


def light_weight(spectrum_mix: dict[str, float], electrons_per_joule: np.ndarray) -> np.ndarray:
    """Sum over light spectra of share * S(lambda) per lumen, times the sensor's e/J: the weight of
    the reflectance integral. `spectrum_mix` maps spectrum names to their share of the light."""
    total = np.zeros_like(spectra.WAVELENGTHS_NM)
    for name, share in spectrum_mix.items():
        total += share * spectra.light_spectrum(name)
    return total * electrons_per_joule


__all__ = ["SensorReflectance", "light_weight", "srgb_to_linear", "GRID_NM"]
