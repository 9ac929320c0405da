"""Exposure calibration: renderer radiance -> sensor-plane irradiance -> electrons -> y.

The chain (each factor a field below, each with its source):

1. The renderer's film holds *electron-weighted radiance* L_q in photo-electrons s^-1 m^-2 sr^-1:
   the scene radiance L(lambda) weighted by the pixel's spectral response,
   L_q = integral L(lambda) QE(lambda) lambda/(h c) dlambda. (Lights are set up in these units by
   `lights.py`; the spectral variant applies the weight in the film, the mono variant folds it
   into each light's scalar emission.)
2. Camera equation, object far from the lens: sensor-plane irradiance
   E_q = L_q * pi * tau * cos^4(theta) / (4 N^2)
   (docs/scenes.md section 4; e.g. Ray, *Applied Photographic Optics*, 3rd ed., section 8.3).
3. Electrons per readout step: e = E_q * pitch^2 * fill_factor * T.
4. y = e / threshold_electrons (docs/design.md section 2: y is expected spikes per step).

Default assumptions (documented in docs/scenes.md, chosen with spikesim.camera.SpikeCamera's
estimate): a 20 um pixel (the 400 x 250 array is then 8 x 5 mm), fill factor 0.3, a silicon
photodiode with peak QE 0.75 at 510 nm, an f/1.4 lens with 90 % transmittance. With them a white
Lambertian surface under 100 lx of D65 daylight collects ~290 photo-electrons per 25 us step,
y ~ 0.29 (0.18-0.41 across the CIE lamps), and 1 lx gives 1/100 of that (`white_surface_y`).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import silicon, spectra


def _check_range(owner: str, name: str, value: float, lo: float, hi: float, lo_open: bool = True) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ValueError(f"{owner}.{name}={value!r} must be a finite number")
    if (value <= lo if lo_open else value < lo) or value > hi:
        raise ValueError(f"{owner}.{name}={value} is outside {'(' if lo_open else '['}{lo}, {hi}]")


@dataclass(frozen=True)
class Optics:
    """The lens in front of the sensor."""

    f_number: float = 1.4
    """N. f/1.4 is a fast C-mount lens, the usual choice for high-speed recording."""
    transmittance: float = 0.9
    """tau: a multi-coated lens transmits ~90 % (Ray, Applied Photographic Optics, section 8.3)."""
    cos4_falloff: bool = False
    """Natural vignetting cos^4(theta) of the field angle. Off by default: ground truth then
    shows the scene's radiance uniformly across the frame, as the published spike datasets do."""

    def __post_init__(self) -> None:
        _check_range("Optics", "f_number", self.f_number, 0.5, 64.0)
        _check_range("Optics", "transmittance", self.transmittance, 0.0, 1.0)
        if not isinstance(self.cos4_falloff, bool):
            raise ValueError(f"Optics.cos4_falloff={self.cos4_falloff!r} must be a bool")

    @property
    def irradiance_per_radiance(self) -> float:
        """E / L on the optical axis: pi tau / (4 N^2) (camera equation, object at infinity)."""
        return math.pi * self.transmittance / (4.0 * self.f_number ** 2)

    def falloff(self, height: int, width: int, x_fov_deg: float) -> np.ndarray:
        """Per-pixel relative illumination, cos^4 of each pixel centre's field angle (or ones)."""
        if not self.cos4_falloff:
            return np.ones((height, width), dtype=np.float32)
        tx = math.tan(math.radians(x_fov_deg) / 2.0)
        ty = tx * height / width
        u = ((np.arange(width) + 0.5) / width * 2.0 - 1.0) * tx
        v = ((np.arange(height) + 0.5) / height * 2.0 - 1.0) * ty
        tan2 = u[None, :] ** 2 + v[:, None] ** 2
        return (1.0 / (1.0 + tan2) ** 2).astype(np.float32)  # cos^4 = 1 / (1 + tan^2)^2


@dataclass(frozen=True)
class PixelResponse:
    """Pixel geometry and its silicon photodiode's spectral quantum efficiency."""

    pixel_pitch_m: float = 20e-6
    """Pixel pitch. Assumed 20 um (spikesim.camera.SpikeCamera's estimate): integrate-and-fire
    pixels carry a comparator and reset logic, so they are large."""
    fill_factor: float = 0.3
    """Photosensitive fraction of the pixel (assumption): an integrate-and-fire pixel spends much
    of its area on the comparator and reset circuit; 3T active pixels reach 30-50 %."""
    dead_layer_um: float = 0.1
    """Surface layer whose carriers recombine before collection (blue loss); silicon.py."""
    collection_depth_um: float = 4.0
    """Depth from which carriers are collected: depletion plus diffusion length (red loss)."""
    stack_transmittance: float = 0.85
    """Transmittance of the oxide/nitride stack above the photodiode (reflection losses)."""

    def __post_init__(self) -> None:
        _check_range("PixelResponse", "pixel_pitch_m", self.pixel_pitch_m, 0.0, 1e-3)
        _check_range("PixelResponse", "fill_factor", self.fill_factor, 0.0, 1.0)
        _check_range("PixelResponse", "dead_layer_um", self.dead_layer_um, 0.0, 5.0, lo_open=False)
        _check_range("PixelResponse", "collection_depth_um", self.collection_depth_um, 0.0, 100.0)
        _check_range("PixelResponse", "stack_transmittance", self.stack_transmittance, 0.0, 1.0)
        if self.dead_layer_um >= self.collection_depth_um:
            raise ValueError("PixelResponse.dead_layer_um must be below collection_depth_um")

    @property
    def area_m2(self) -> float:
        return self.pixel_pitch_m ** 2

    def quantum_efficiency(self, wavelength_nm: np.ndarray | None = None) -> np.ndarray:
        """QE(lambda), electrons per photon on the photosensitive area (fill factor excluded)."""
        wl = spectra.WAVELENGTHS_NM if wavelength_nm is None else wavelength_nm
        return silicon.quantum_efficiency(wl, self.dead_layer_um, self.collection_depth_um,
                                          self.stack_transmittance)

    def electrons_per_joule(self) -> np.ndarray:
        """The sensor's spectral weight QE(lambda) lambda / (h c) on spectra.WAVELENGTHS_NM, e/J."""
        return self.quantum_efficiency() * spectra.photons_per_joule()

    def electron_rate(self, spectral: np.ndarray) -> float:
        """The electron-weighted quantity of a radiometric spectral one on spectra.WAVELENGTHS_NM,
        integral P(lambda) QE(lambda) lambda / (h c) dlambda: e s^-1 m^-2 sr^-1 from a spectral
        radiance in W m^-2 sr^-1 nm^-1 (and likewise for intensity, irradiance, flux)."""
        return spectra.integrate(np.asarray(spectral, dtype=np.float64) * self.electrons_per_joule())

    def electrons_per_lumen_second(self, spectrum: str) -> float:
        """Photo-electrons per second per lumen of light with this spectrum (e s^-1 lm^-1):
        the factor that turns a photometric quantity into the electron-weighted one."""
        return self.electron_rate(spectra.light_spectrum(spectrum))


@dataclass(frozen=True)
class Exposure:
    """Everything between scene radiance and y, for one camera."""

    optics: Optics = field(default_factory=Optics)
    pixel: PixelResponse = field(default_factory=PixelResponse)
    readout_period_s: float = 25e-6
    """T (spikesim.camera.SpikeCamera.readout_period_s)."""
    threshold_electrons: float = 1000.0
    """Photo-electrons per threshold (spikesim.camera.SpikeCamera.threshold_electrons)."""

    def __post_init__(self) -> None:
        # the camera's own ranges: a threshold of 1e-300 rendered non-finite frames that blamed the scene,
        # a 1e-12 s period rendered frames simulate then refused (round nine)
        from ..camera import READOUT_PERIOD_RANGE_S, THRESHOLD_ELECTRONS_RANGE
        _check_range("Exposure", "readout_period_s", self.readout_period_s, *READOUT_PERIOD_RANGE_S, lo_open=False)
        _check_range("Exposure", "threshold_electrons", self.threshold_electrons, *THRESHOLD_ELECTRONS_RANGE,
                     lo_open=False)

    @classmethod
    def for_camera(cls, camera: Any = None, optics: Optics | None = None,
                   pixel: PixelResponse | None = None) -> "Exposure":
        """Take T and the threshold from a SpikeCamera (or anything with those attributes)."""
        kw: dict[str, Any] = {"optics": optics or Optics(), "pixel": pixel or PixelResponse()}
        if camera is not None:
            kw["readout_period_s"] = float(camera.readout_period_s)
            kw["threshold_electrons"] = float(camera.threshold_electrons)
        return cls(**kw)

    @property
    def y_per_radiance(self) -> float:
        """y per unit of electron-weighted radiance (e s^-1 m^-2 sr^-1), on the optical axis."""
        return (self.optics.irradiance_per_radiance * self.pixel.area_m2 * self.pixel.fill_factor
                * self.readout_period_s / self.threshold_electrons)

    def gain_map(self, height: int, width: int, x_fov_deg: float) -> np.ndarray:
        """Film value -> y, per pixel (the cos^4 falloff when enabled)."""
        return (self.optics.falloff(height, width, x_fov_deg) * self.y_per_radiance).astype(np.float32)

    def white_surface_y(self, illuminance_lux: float, spectrum: str = "D65", reflectance: float = 1.0) -> float:
        """Analytic y of a Lambertian surface of reflectance rho under illuminance E (on axis):
        L_q = rho * E * k_q / pi (docs/design.md section 4), then the chain above."""
        e_q = illuminance_lux * self.pixel.electrons_per_lumen_second(spectrum)
        return reflectance * e_q / math.pi * self.y_per_radiance

    # ---- configuration files -----------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"optics": asdict(self.optics), "pixel": asdict(self.pixel),
                "readout_period_s": self.readout_period_s, "threshold_electrons": self.threshold_electrons}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Exposure":
        from ..config_io import check_known_fields
        check_known_fields(cls, data, "exposure keys")
        kw = dict(data)
        if "optics" in kw:
            kw["optics"] = Optics(**kw["optics"])
        if "pixel" in kw:
            kw["pixel"] = PixelResponse(**kw["pixel"])
        return cls(**kw)

    @classmethod
    def from_file(cls, path: str | Path) -> "Exposure":
        from ..config_io import load_config_file
        return load_config_file(path, cls.from_dict)


__all__ = ["Optics", "PixelResponse", "Exposure"]
