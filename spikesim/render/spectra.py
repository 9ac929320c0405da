"""Light spectra in absolute photometric scale, on the wavelength grid Mitsuba renders.

Every light is described by a relative spectral distribution S(lambda) normalised so that one
photometric unit (1 lm, 1 cd, 1 lx or 1 cd/m^2) is K_m * integral S V = 1; the absolute spectral
quantity is then (photometric value) x S(lambda). colour-science supplies the CIE tables.

Why our own integrals: colour-science's `luminous_flux`/`luminous_efficacy` integrate over the
spectrum's own range only (docs/design.md section 4), so everything here is integrated on one fixed
grid, 360-830 nm, which is also Mitsuba's spectral range (MI_CIE_MIN/MI_CIE_MAX).
"""
from __future__ import annotations

import hashlib
from functools import lru_cache

import numpy as np

#: Wavelength grid, nm: Mitsuba's spectral range (MI_CIE_MIN = 360, MI_CIE_MAX = 830), 1 nm steps.
LAMBDA_MIN_NM = 360.0
LAMBDA_MAX_NM = 830.0
WAVELENGTHS_NM = np.arange(LAMBDA_MIN_NM, LAMBDA_MAX_NM + 0.5, 1.0)

#: Maximum luminous efficacy of radiation, lm/W (CIE 018:2019 / SI brochure, K_cd definition).
K_M = 683.002
#: Planck constant (J s) and speed of light (m/s), exact SI 2019 values.
PLANCK_H = 6.62607015e-34
LIGHT_C = 299792458.0

#: Colour-science names of the CIE illuminants we accept, with what each stands for.
#: A: incandescent/tungsten (CIE 015:2018); D50/D65: daylight; FL1-FL12 and FL3.x: fluorescent
#: lamps; LED-B1..B5, LED-BH1, LED-RGB1, LED-V1/V2: white LEDs (CIE 015:2018 Table 11.4);
#: HP1-HP5: high-pressure discharge lamps (HP1 = standard high-pressure sodium street lamp).
DAYLIGHT = {"D50": (0.3457, 0.3585), "D55": (0.3324, 0.3474), "D65": (0.3127, 0.3290), "D75": (0.2990, 0.3149)}


def _trapz(y: np.ndarray, x: np.ndarray) -> float:
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x)))


def integrate(values: np.ndarray) -> float:
    """Trapezoidal integral over WAVELENGTHS_NM (values per nm -> total)."""
    return _trapz(np.asarray(values, dtype=np.float64), WAVELENGTHS_NM)


@lru_cache(maxsize=None)
def photopic_v() -> np.ndarray:
    """CIE 1924 photopic luminous efficiency V(lambda) on WAVELENGTHS_NM (colour-science)."""
    from colour.colorimetry import SDS_LEFS_PHOTOPIC

    sd = SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    return np.interp(WAVELENGTHS_NM, sd.wavelengths, sd.values, left=0.0, right=0.0)


def available_spectra() -> list[str]:
    """Every light spectrum name `light_spectrum` accepts."""
    import colour

    names = set(colour.SDS_ILLUMINANTS.keys()) | set(DAYLIGHT) | {"A"}
    names -= {"ID65", "ID50", "B", "C", "E"}  # indoor-daylight variants and obsolete sources
    names = {n for n in names if not n.startswith("ISO")}
    return sorted(names)


@lru_cache(maxsize=None)
def _raw_spectrum(name: str) -> np.ndarray:
    import colour
    from colour.colorimetry import sd_CIE_illuminant_D_series, sd_CIE_standard_illuminant_A

    if name == "A":
        # Illuminant A is Planck's law at 2856 K, so it is exact over the whole grid
        # (the tabulated copy stops at 780 nm).
        shape = colour.SpectralShape(LAMBDA_MIN_NM, LAMBDA_MAX_NM, 1.0)
        sd = sd_CIE_standard_illuminant_A(shape)
        return np.asarray(sd.values, dtype=np.float64)
    if name in DAYLIGHT:
        # CIE daylight from its basis functions S0, S1, S2 (defined to 830 nm; CIE 015:2018
        # eq. 4.6), which reproduces the tabulated D65 within 0.2 % and extends it past 780 nm.
        sd = sd_CIE_illuminant_D_series(np.array(DAYLIGHT[name]))
        return np.interp(WAVELENGTHS_NM, sd.wavelengths, sd.values, left=0.0, right=0.0)
    if name not in available_spectra():
        raise KeyError(name)
    sd = colour.SDS_ILLUMINANTS[name]
    # Fluorescent, LED and discharge tables stop at 380-780 nm; these lamps emit next to nothing
    # outside that range (phosphor and LED emission bands), so the rest of the grid is zero.
    return np.interp(WAVELENGTHS_NM, sd.wavelengths, sd.values, left=0.0, right=0.0)


#: Spectra registered by `register_spectrum` (a scene's own emitters), by name.
_REGISTERED: dict[str, np.ndarray] = {}


def light_spectrum(name: str) -> np.ndarray:
    """Spectral quantity per photometric unit, W/nm per lm (or per cd, lx, cd/m^2).

    Normalised so that K_m * integral S V dlambda = 1: multiply by a lumen (candela, lux, nit)
    value to get the absolute spectral flux (intensity, irradiance, radiance). `name` is a CIE
    illuminant (`available_spectra`) or a name `register_spectrum` returned.
    """
    if name in _REGISTERED:
        return _REGISTERED[name]
    return _cie_spectrum(name)


@lru_cache(maxsize=None)
def _cie_spectrum(name: str) -> np.ndarray:
    raw = _raw_spectrum(name)
    s = raw / photometric(raw)
    s.setflags(write=False)
    return s


def photometric(values: np.ndarray) -> float:
    """The photometric quantity of a radiometric spectral one on WAVELENGTHS_NM:
    K_m * integral P(lambda) V(lambda) dlambda (lm from W/nm, cd from W sr^-1 nm^-1, lx from
    W m^-2 nm^-1, cd/m^2 from W m^-2 sr^-1 nm^-1; CIE S 017:2020, 17-21-050 "luminous quantity")."""
    return K_M * integrate(np.asarray(values, dtype=np.float64) * photopic_v())


def register_spectrum(values: np.ndarray) -> str:
    """Name an absolute spectral distribution on WAVELENGTHS_NM (a scene's own emitter,
    scene_emitters.py), so that everything that takes a light spectrum by name (light_spectrum,
    the pixel's electrons per lumen, the mono path's reflectances) takes it too. The name is a
    digest of the photometrically normalised shape, so one shape always gets one name."""
    v = np.asarray(values, dtype=np.float64)
    if v.shape != WAVELENGTHS_NM.shape or not np.all(np.isfinite(v)) or v.min() < 0:
        raise ValueError(f"a spectrum needs {WAVELENGTHS_NM.size} finite non-negative values on {LAMBDA_MIN_NM:g}-"
                         f"{LAMBDA_MAX_NM:g} nm")
    lum = photometric(v)
    if not lum > 0:
        raise ValueError("a spectrum with no visible light (zero luminous quantity) has no photometric scale")
    s = v / lum
    s.setflags(write=False)
    name = "xml-" + hashlib.sha256(np.round(s, 15).tobytes()).hexdigest()[:12]
    _REGISTERED.setdefault(name, s)
    return name


def photons_per_joule() -> np.ndarray:
    """lambda / (h c): photons per joule of radiant energy at each wavelength of the grid."""
    return WAVELENGTHS_NM * 1e-9 / (PLANCK_H * LIGHT_C)


def luminous_efficacy_of_radiation(name: str) -> float:
    """lm/W of the radiation itself over 360-830 nm (not a lamp's efficacy, which includes its
    heat and infrared losses: take those from the literature, see lights.LAMP_EFFICACY)."""
    return 1.0 / integrate(light_spectrum(name))


def regular_values(values: np.ndarray, step_nm: float = 5.0) -> tuple[float, float, np.ndarray]:
    """Resample a grid function to `step_nm` for a Mitsuba `regular` spectrum (start, end, values)."""
    grid = np.arange(LAMBDA_MIN_NM, LAMBDA_MAX_NM + 0.5 * step_nm, step_nm)
    return LAMBDA_MIN_NM, LAMBDA_MAX_NM, np.interp(grid, WAVELENGTHS_NM, values)


__all__ = [
    "WAVELENGTHS_NM", "LAMBDA_MIN_NM", "LAMBDA_MAX_NM", "K_M", "PLANCK_H", "LIGHT_C", "integrate",
    "photopic_v", "available_spectra", "light_spectrum", "photometric", "register_spectrum", "photons_per_joule",
    "luminous_efficacy_of_radiation", "regular_values",
]
