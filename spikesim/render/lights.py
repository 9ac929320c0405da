"""Physical light sources: a spectrum and a power in photometric units, turned into Mitsuba emitters.

A scene's lights live in `lights.json` beside its XML, one entry per lighting condition
("normal", "low"). Each emitter has a type, a CIE spectrum (colour-science) and exactly one power
specification in real units; see docs/scenes.md for the schema and the levels used.

Units inside the renderer: the photometric value (cd, cd/m^2 or lx) times the spectrum's
electron yield (PixelResponse.electrons_per_lumen_second) gives the electron-weighted quantity the
film records (exposure.py). Radiometric relations used (docs/design.md section 4):
isotropic point lamp I = F / (4 pi); Lambertian area light L = F / (pi A); sky of uniform
luminance L gives E = pi L on an unobstructed plane; illuminance from a point source
E = I cos(theta) / d^2 (inverse-square law).
"""
from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import spectra
from .errors import LightError, read_json
from .exposure import PixelResponse

EMITTER_TYPES = ("point", "spot", "rectangle", "directional", "sky")

#: Power specifications and which emitter types accept each ("area": a scene XML's own area
#: emitter on any shape, scene_emitters.py; a light file refers to it by id).
POWER_KINDS = {
    "intensity_cd": ("point", "spot"),
    "luminance_cd_m2": ("rectangle", "sky", "area"),
    "luminous_flux_lm": ("point", "spot", "rectangle", "area"),
    "electrical_power_w": ("point", "rectangle", "area"),
    "illuminance_lux": EMITTER_TYPES + ("area",),
}

#: Lamp luminous efficacies, lm per electrical W. Sources: the "Lighting efficiency" table of
#: Wikipedia's "Luminous efficacy" article (incandescent values from Keefe, "Traditional and
#: LED lighting", 2007), and the U.S. DOE "LED lighting facts" ranges for LED lamps.
LAMP_EFFICACY_LM_PER_W = {
    "incandescent_40w_120v": 12.6,   # 40 W tungsten incandescent, 120 V
    "incandescent_100w_120v": 17.5,  # 100 W tungsten incandescent, 120 V
    "incandescent_100w_230v": 13.8,  # 100 W tungsten incandescent, 220-230 V
    "fluorescent_t8": 90.0,          # T8 tube with electronic ballast, 80-100 lm/W (midpoint)
    "led_lamp": 100.0,               # retrofit white LED lamp, 80-120 lm/W typical (midpoint)
}

#: Upper bounds that catch unit mistakes: nothing on the ground is lit by more than direct
#: sunlight (~100-130 klx at noon, Wikipedia "Lux"); the largest stadium floodlights emit
#: ~2e5 lm; a luminance above ~1.6e9 cd/m^2 (the sun's disc) is not a lamp.
MAX_ILLUMINANCE_LUX = 1.5e5
MAX_FLUX_LM = 2.0e6
MAX_INTENSITY_CD = 1.0e7
MAX_LUMINANCE_CD_M2 = 1.6e9
MAX_ELECTRICAL_W = 1.0e5


def _vec(path: Path, where: str, value: Any, n: int = 3) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64) if isinstance(value, (list, tuple)) else None
    if arr is None or arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise LightError(path, f"{where} must be a list of {n} finite numbers, got {value!r}")
    return arr


def _unit(path: Path, where: str, value: Any) -> np.ndarray:
    v = _vec(path, where, value)
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        raise LightError(path, f"{where} is the zero vector")
    return v / norm


def _spot_falloff(cos_theta: np.ndarray, cutoff_rad: float, beam_rad: float) -> np.ndarray:
    """Mitsuba 3's spot profile (src/emitters/spot.cpp): 1 inside the beam, linear in angle to 0
    at the cutoff."""
    theta = np.arccos(np.clip(cos_theta, -1.0, 1.0))
    ramp = (cutoff_rad - theta) / max(cutoff_rad - beam_rad, 1e-12)
    return np.where(cos_theta > math.cos(cutoff_rad), np.where(theta <= beam_rad, 1.0, ramp), 0.0)


def _look_at_basis(position: np.ndarray, target: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mitsuba's look_at frame: (left, up', dir) with dir from position to target."""
    d = target - position
    if not np.linalg.norm(d) > 0:
        raise ValueError("target coincides with position")
    d = d / np.linalg.norm(d)
    left = np.cross(up, d)
    if np.linalg.norm(left) < 1e-9:
        raise ValueError("up is parallel to the viewing direction")
    left = left / np.linalg.norm(left)
    return left, np.cross(d, left), d


@dataclass(frozen=True)
class EmitterSpec:
    """One physical light source, validated, with its photometric quantity resolved:
    `photometric` is the intensity in cd (point, spot), luminance in cd/m^2 (rectangle, sky) or
    illuminance in lx perpendicular to the beam (directional)."""

    id: str
    type: str
    spectrum: str
    power: dict[str, Any]
    photometric: float
    position: tuple[float, ...] | None = None
    target: tuple[float, ...] | None = None
    up: tuple[float, ...] = (0.0, 0.0, 1.0)
    size: tuple[float, float] | None = None
    direction: tuple[float, ...] | None = None
    cutoff_deg: float = 20.0
    beam_deg: float = 15.0

    # ---- photometry ---------------------------------------------------------------------------
    def luminous_flux_lm(self) -> float:
        """Total emitted luminous flux (inf for directional and sky, which have no finite flux)."""
        if self.type == "point":
            return 4.0 * math.pi * self.photometric
        if self.type == "spot":
            return self.photometric * _spot_solid_angle(self.cutoff_deg, self.beam_deg)
        if self.type == "rectangle":
            return math.pi * self.photometric * self.size[0] * self.size[1]
        return math.inf

    def illuminance_at(self, point: Any, normal: Any) -> float:
        """Direct illuminance (lx) this emitter gives a surface at `point` facing `normal`,
        ignoring occlusion."""
        p = np.asarray(point, dtype=np.float64)
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        if self.type == "sky":
            return math.pi * self.photometric
        if self.type == "directional":
            d = np.asarray(self.direction) / np.linalg.norm(self.direction)
            return self.photometric * max(0.0, float(-d @ n))
        if self.type in ("point", "spot"):
            to_light = np.asarray(self.position) - p
            dist = float(np.linalg.norm(to_light))
            if dist == 0.0:
                return math.inf
            cos_r = max(0.0, float(to_light @ n) / dist)
            factor = 1.0
            if self.type == "spot":
                _, _, axis = _look_at_basis(np.asarray(self.position), np.asarray(self.target), np.asarray(self.up))
                factor = float(_spot_falloff(np.array(float(-to_light @ axis) / dist),
                                             math.radians(self.cutoff_deg), math.radians(self.beam_deg)))
            return self.photometric * factor * cos_r / dist ** 2
        return self.photometric * _rectangle_geometry(self, p, n)

    # ---- Mitsuba ------------------------------------------------------------------------------
    def to_xml(self, variant: str, pixel: PixelResponse) -> ET.Element:
        """The Mitsuba XML element for this emitter in `variant` ("mono", "spectral", "rgb")."""
        quantity = {"point": "intensity", "spot": "intensity", "rectangle": "radiance",
                    "directional": "irradiance", "sky": "radiance"}[self.type]
        spec = spectrum_element(quantity, self.spectrum, self.photometric, variant, pixel)
        if self.type == "rectangle":
            shape = ET.Element("shape", type="rectangle", id=self.id)
            tr = ET.SubElement(shape, "transform", name="to_world")
            ET.SubElement(tr, "scale", x=_f(self.size[0] / 2), y=_f(self.size[1] / 2), z="1")
            ET.SubElement(tr, "lookat", origin=_v(self.position), target=_v(self.target), up=_v(self.up))
            bsdf = ET.SubElement(shape, "bsdf", type="diffuse")
            ET.SubElement(bsdf, "spectrum" if variant != "rgb" else "rgb", name="reflectance", value="0")
            em = ET.SubElement(shape, "emitter", type="area")
            em.append(spec)
            return shape
        if self.type == "sky":
            em = ET.Element("emitter", type="constant", id=self.id)
        else:
            em = ET.Element("emitter", type=self.type, id=self.id)
        if self.type == "point":
            ET.SubElement(em, "point", name="position", value=_v(self.position))
        elif self.type == "spot":
            tr = ET.SubElement(em, "transform", name="to_world")
            ET.SubElement(tr, "lookat", origin=_v(self.position), target=_v(self.target), up=_v(self.up))
            ET.SubElement(em, "float", name="cutoff_angle", value=_f(self.cutoff_deg))
            ET.SubElement(em, "float", name="beam_width", value=_f(self.beam_deg))
        elif self.type == "directional":
            ET.SubElement(em, "vector", name="direction", value=_v(self.direction))
        em.append(spec)
        return em

    def describe(self, pixel: PixelResponse | None = None) -> dict[str, Any]:
        unit = {"point": "cd", "spot": "cd", "rectangle": "cd/m^2", "area": "cd/m^2", "directional": "lx",
                "sky": "cd/m^2"}[self.type]
        out: dict[str, Any] = {"id": self.id, "type": self.type, "spectrum": self.spectrum, "power": self.power,
                               "photometric": self.photometric, "photometric_unit": unit}
        flux = self.luminous_flux_lm()
        if math.isfinite(flux):
            out["luminous_flux_lm"] = flux
        if pixel is not None:
            out["electrons_per_lumen_second"] = pixel.electrons_per_lumen_second(self.spectrum)
        for k in ("position", "target", "up", "size", "direction"):
            if getattr(self, k) is not None and (k != "up" or self.type in ("spot", "rectangle")):
                out[k] = list(getattr(self, k))
        if self.type == "spot":
            out["cutoff_deg"], out["beam_deg"] = self.cutoff_deg, self.beam_deg
        return out


def _f(x: float) -> str:
    return f"{float(x):.9g}"


def _v(x: Any) -> str:
    return ", ".join(_f(c) for c in x)


def _spot_solid_angle(cutoff_deg: float, beam_deg: float) -> float:
    """Integral of the spot's falloff over the sphere, sr (flux = intensity x this)."""
    theta = np.linspace(0.0, math.radians(cutoff_deg), 4001)
    f = _spot_falloff(np.cos(theta), math.radians(cutoff_deg), math.radians(beam_deg))
    g = f * np.sin(theta)
    return 2.0 * math.pi * float(np.sum(0.5 * (g[1:] + g[:-1]) * np.diff(theta)))


def _rectangle_geometry(em: EmitterSpec, p: np.ndarray, n: np.ndarray, samples: int = 256) -> float:
    """Integral over a one-sided Lambertian rectangle of cos(theta_e) cos(theta_r) / d^2 dA (sr):
    the illuminance at p per unit luminance (midpoint rule; error < 1e-4 at a distance of one
    rectangle size)."""
    left, upv, d = _look_at_basis(np.asarray(em.position), np.asarray(em.target), np.asarray(em.up))
    w, h = em.size
    s = (np.arange(samples) + 0.5) / samples - 0.5
    a, b = np.meshgrid(s * w, s * h, indexing="ij")
    pts = np.asarray(em.position) + a[..., None] * left + b[..., None] * upv
    v = pts - p
    dist2 = np.sum(v * v, axis=-1)
    dist = np.sqrt(dist2)
    cos_r = np.clip(v @ n / dist, 0.0, None)
    cos_e = np.clip(-(v @ d) / dist, 0.0, None)  # the rectangle emits toward +d only
    return float(np.sum(cos_r * cos_e / dist2) * (w * h) / samples ** 2)


def spectrum_element(name: str, spectrum: str, photometric: float, variant: str,
                     pixel: PixelResponse) -> ET.Element:
    """The emission of a light as Mitsuba's `name` parameter in `variant`: the absolute spectrum
    (photometric value x normalised spectrum, W/nm per unit) in spectral, its electron-weighted
    scalar (photometric value x k_q) in mono. Used for light-file and scene-XML emitters alike."""
    if variant == "mono":
        value = photometric * pixel.electrons_per_lumen_second(spectrum)
        return ET.Element("spectrum", name=name, value=_f(value))
    if variant == "spectral":
        lo, hi, vals = spectra.regular_values(spectra.light_spectrum(spectrum) * photometric, step_nm=1.0)
        el = ET.Element("spectrum", name=name, type="regular")
        ET.SubElement(el, "float", name="wavelength_min", value=_f(lo))
        ET.SubElement(el, "float", name="wavelength_max", value=_f(hi))
        ET.SubElement(el, "string", name="values", value=", ".join(_f(v) for v in vals))
        return el
    if variant == "rgb":
        rgb = preview_rgb(spectrum) * photometric * pixel.electrons_per_lumen_second(spectrum)
        return ET.Element("rgb", name=name, value=_v(rgb))
    raise ValueError(f"variant={variant!r}")


def preview_rgb(spectrum: str) -> np.ndarray:
    """Linear sRGB of a light with luminance 1 (for RGB previews only; out-of-gamut clipped)."""
    from colour.colorimetry import MSDS_CMFS

    cmfs = MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    wl = spectra.WAVELENGTHS_NM
    xyz = np.array([spectra.integrate(spectra.light_spectrum(spectrum) * np.interp(wl, cmfs.wavelengths, cmfs.values[:, i], left=0, right=0))
                    for i in range(3)])
    xyz /= xyz[1]
    m = np.array([[3.2404542, -1.5371385, -0.4985314], [-0.9692660, 1.8760108, 0.0415560],
                  [0.0556434, -0.2040259, 1.0572252]])  # XYZ -> linear sRGB (IEC 61966-2-1, D65)
    return np.clip(m @ xyz, 0.0, None)


# ---- parsing -------------------------------------------------------------------------------------
_COMMON_KEYS = {"id", "type", "spectrum", "power", "comment"}
_TYPE_KEYS = {
    "point": {"position"},
    "spot": {"position", "target", "up", "cutoff_deg", "beam_deg"},
    "rectangle": {"position", "target", "up", "size"},
    "directional": {"direction"},
    "sky": set(),
}


def parse_emitter(path: Path, where: str, data: Any) -> EmitterSpec:
    """Validate one emitter entry of a light file and resolve its photometric quantity."""
    if not isinstance(data, dict):
        raise LightError(path, f"{where} must be an object, got {type(data).__name__}")
    etype = data.get("type")
    if etype not in EMITTER_TYPES:
        raise LightError(path, f"{where}.type={etype!r}; expected one of {EMITTER_TYPES}")
    unknown = set(data) - _COMMON_KEYS - _TYPE_KEYS[etype]
    if unknown:
        raise LightError(path, f"{where}: unknown key(s) {sorted(unknown)} for a {etype} emitter")
    eid = data.get("id")
    if not isinstance(eid, str) or not eid.replace("_", "").isalnum():
        raise LightError(path, f"{where}.id={eid!r} must be a name of letters, digits and underscores")
    spectrum = data.get("spectrum")
    if spectrum not in spectra.available_spectra():
        raise LightError(path, f"{where}.spectrum={spectrum!r} is not a known light spectrum; "
                               f"expected one of {spectra.available_spectra()}")
    kw: dict[str, Any] = {"id": eid, "type": etype, "spectrum": spectrum}
    if etype in ("point", "spot", "rectangle"):
        kw["position"] = tuple(_vec(path, f"{where}.position", data.get("position")))
    if etype in ("spot", "rectangle"):
        kw["target"] = tuple(_vec(path, f"{where}.target", data.get("target")))
        if np.array_equal(kw["target"], kw["position"]):
            raise LightError(path, f"{where}: target must differ from position (it sets where the light points)")
        if "up" in data:
            kw["up"] = tuple(_unit(path, f"{where}.up", data["up"]))
        else:  # +z unless the emitter faces along z, then +y
            axis = np.asarray(kw["target"]) - np.asarray(kw["position"])
            vertical = np.linalg.norm(np.cross(axis, [0.0, 0.0, 1.0])) < 1e-6 * max(np.linalg.norm(axis), 1e-300)
            kw["up"] = (0.0, 1.0, 0.0) if vertical else (0.0, 0.0, 1.0)
        try:
            _look_at_basis(np.asarray(kw["position"]), np.asarray(kw["target"]), np.asarray(kw["up"]))
        except (ValueError, FloatingPointError):
            raise LightError(path, f"{where}: 'up' must not be parallel to the direction from position to target") from None
    if etype == "rectangle":
        size = _vec(path, f"{where}.size", data.get("size"), n=2)
        if np.any(size <= 0):
            raise LightError(path, f"{where}.size={list(size)} must be positive (metres)")
        kw["size"] = (float(size[0]), float(size[1]))
    if etype == "directional":
        kw["direction"] = tuple(_unit(path, f"{where}.direction", data.get("direction")))
    if etype == "spot":
        cutoff = data.get("cutoff_deg", 20.0)
        beam = data.get("beam_deg", 0.75 * cutoff if isinstance(cutoff, (int, float)) else None)
        if not all(isinstance(x, (int, float)) for x in (cutoff, beam)) or not 0 < beam <= cutoff < 90:
            raise LightError(path, f"{where}: need 0 < beam_deg <= cutoff_deg < 90, got {beam!r}, {cutoff!r}")
        kw["cutoff_deg"], kw["beam_deg"] = float(cutoff), float(beam)
    power = data.get("power")
    kw["power"] = power
    kw["photometric"] = 1.0
    spec = EmitterSpec(**kw)
    return EmitterSpec(**{**kw, "photometric": _resolve_power(path, where, spec, power)})


def _positive(path: Path, where: str, value: Any, limit: float, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise LightError(path, f"{where}={value!r} must be a finite number of {unit}")
    if value <= 0:
        raise LightError(path, f"{where}={value} {unit}: a light's power must be positive")
    if value > limit:
        raise LightError(path, f"{where}={value:g} {unit} is absurd for a real light (limit {limit:g} {unit}); "
                               "check the units")
    return float(value)


def _resolve_power(path: Path, where: str, em: EmitterSpec, power: Any) -> float:
    """The emitter's photometric quantity (cd, cd/m^2 or lx) from its power specification."""
    if not isinstance(power, dict):
        raise LightError(path, f"{where}.power must be an object with one of {sorted(POWER_KINDS)}")
    kinds = [k for k in power if k in POWER_KINDS]
    extra = set(power) - set(POWER_KINDS) - {"lamp", "at", "normal", "comment"}
    if len(kinds) != 1 or extra:
        raise LightError(path, f"{where}.power needs exactly one of {sorted(POWER_KINDS)} "
                               f"(got keys {sorted(power)})")
    kind = kinds[0]
    pw = f"{where}.power.{kind}"
    if em.type not in POWER_KINDS[kind]:
        raise LightError(path, f"{pw} is not defined for a {em.type} emitter (use one of "
                               f"{[k for k, t in POWER_KINDS.items() if em.type in t]})")
    value = power[kind]
    if kind == "intensity_cd":
        return _positive(path, pw, value, MAX_INTENSITY_CD, "cd")
    if kind == "luminance_cd_m2":
        return _positive(path, pw, value, MAX_LUMINANCE_CD_M2, "cd/m^2")
    if kind in ("luminous_flux_lm", "electrical_power_w"):
        if kind == "electrical_power_w":
            watts = _positive(path, pw, value, MAX_ELECTRICAL_W, "W")
            lamp = power.get("lamp")
            if lamp not in LAMP_EFFICACY_LM_PER_W:
                raise LightError(path, f"{where}.power.lamp={lamp!r}; electrical power needs a lamp with a "
                                       f"known efficacy, one of {sorted(LAMP_EFFICACY_LM_PER_W)}")
            flux = watts * LAMP_EFFICACY_LM_PER_W[lamp]
        else:
            flux = _positive(path, pw, value, MAX_FLUX_LM, "lm")
        return flux / (em.luminous_flux_lm() / em.photometric)
    # illuminance_lux
    lux = _positive(path, pw, value, MAX_ILLUMINANCE_LUX, "lx")
    if em.type == "directional":
        return lux
    if em.type == "sky":
        return lux / math.pi
    at = _vec(path, f"{where}.power.at", power.get("at"))
    normal = _unit(path, f"{where}.power.normal", power.get("normal"))
    per_unit = em.illuminance_at(at, normal)
    if not per_unit > 0 or not math.isfinite(per_unit):
        raise LightError(path, f"{where}: the {em.type} emitter does not illuminate power.at={list(at)} "
                               f"(facing {list(normal)}), so its illuminance there cannot be set")
    return lux / per_unit


@dataclass(frozen=True)
class LightingCondition:
    """One named lighting of a scene ("normal", "low"): its emitters and why they are what they are."""

    name: str
    emitters: tuple[EmitterSpec, ...]
    description: str = ""
    reference: str = ""
    subject: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    """A point and normal where the condition's illuminance is reported (the subject)."""
    source: Path | None = field(default=None, compare=False)
    subject_from: str = "light file"
    """Where the subject came from: the light file's `subject`, or "view centre" (the surface the
    camera sees at the centre of its image, scene.view_centre_subject) when it gives none."""

    def illuminance_lux(self, at: Any, normal: Any) -> float:
        """Direct illuminance (lx) of all the condition's emitters on a surface at `at` facing
        `normal`, ignoring occlusion and inter-reflection."""
        return float(sum(e.illuminance_at(at, normal) for e in self.emitters))

    def subject_illuminance_lux(self) -> float | None:
        """Direct illuminance (lx) at the subject, whatever the lights (light file or scene XML);
        None when the condition has no subject."""
        if self.subject is None:
            return None
        return self.illuminance_lux(*self.subject)

    def describe(self, pixel: PixelResponse | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "description": self.description, "reference": self.reference,
                               "emitters": [e.describe(pixel) for e in self.emitters]}
        if self.subject is not None:
            out["subject"] = {"at": list(self.subject[0]), "normal": list(self.subject[1]), "from": self.subject_from,
                              "direct_illuminance_lux": self.subject_illuminance_lux()}
        return out


def _scene_emitter_entry(path: Path, where: str, data: dict[str, Any], own: dict[str, Any]) -> EmitterSpec:
    """A light-file entry without a `type`: one of the scene XML's own emitters, by id, kept where
    and as the XML puts it; a `power` given here replaces its XML level (the spectral shape stays)."""
    eid = data.get("id")
    if eid not in own:
        raise LightError(path, f"{where} has no 'type' and the scene XML has no emitter with id {eid!r} "
                               f"(its emitters: {sorted(own) or 'none'}); give a type ({', '.join(EMITTER_TYPES)}) "
                               "or an XML emitter's id")
    unknown = set(data) - {"id", "power", "comment"}
    if unknown:
        raise LightError(path, f"{where}: unknown key(s) {sorted(unknown)} for the scene's own emitter {eid!r} "
                               "(only 'power' can be set; its geometry and spectrum are the XML's)")
    em = own[eid]
    if "power" not in data:
        return em
    unit = dataclasses.replace(em, photometric=1.0)
    return dataclasses.replace(em, power=data["power"], photometric=_resolve_power(path, where, unit, data["power"]))


def load_lights(path: str | Path, scene_emitters: tuple[EmitterSpec, ...] = ()) -> dict[str, LightingCondition]:
    """Read and validate a light file: {condition: {description, reference, subject, emitters}}.

    `scene_emitters` are the scene XML's own emitters (scene_emitters.read_emitters): an entry
    that names one by id and gives no type switches it on, optionally at a new power. Emitters
    of the XML that a condition does not list are off under that condition."""
    path = Path(path)
    own = {e.id: e for e in scene_emitters}
    data = read_json(path, LightError, "light file")
    if not isinstance(data, dict) or not data:
        raise LightError(path, "must be an object mapping condition names (e.g. 'normal', 'low') to lightings")
    out = {}
    for name, cond in data.items():
        if name.startswith("_"):
            continue  # comments
        where = name
        if not isinstance(cond, dict):
            raise LightError(path, f"{where} must be an object")
        unknown = set(cond) - {"description", "reference", "subject", "emitters"}
        if unknown:
            raise LightError(path, f"{where}: unknown key(s) {sorted(unknown)}")
        ems = cond.get("emitters")
        if not isinstance(ems, list) or not ems:
            raise LightError(path, f"{where}.emitters must be a non-empty list")
        emitters = tuple(_scene_emitter_entry(path, f"{where}.emitters[{i}]", e, own)
                         if isinstance(e, dict) and "type" not in e else parse_emitter(path, f"{where}.emitters[{i}]", e)
                         for i, e in enumerate(ems))
        ids = [e.id for e in emitters]
        if len(set(ids)) != len(ids):
            raise LightError(path, f"{where}: duplicate emitter ids {ids}")
        subject = None
        if "subject" in cond:
            s = cond["subject"]
            if not isinstance(s, dict):
                raise LightError(path, f"{where}.subject must be an object with 'at' and 'normal'")
            subject = (tuple(_vec(path, f"{where}.subject.at", s.get("at"))),
                       tuple(_unit(path, f"{where}.subject.normal", s.get("normal"))))
        out[name] = LightingCondition(name=name, emitters=emitters, description=str(cond.get("description", "")),
                                      reference=str(cond.get("reference", "")), subject=subject, source=path)
    if not out:
        raise LightError(path, "defines no lighting condition")
    return out


#: Keys of a light's record whose values scale with its power.
_POWER_KEYS = ("power", "photometric")


def _scales_with_power(key: str) -> bool:
    return key in _POWER_KEYS or "lux" in key or key.endswith(("_lm", "_cd", "_w"))


def scale_light_amounts(record: Any, factor: float) -> Any:
    """A light record (spikesim.render.lights: conditions, emitters) with every amount that
    scales with emitter power multiplied by `factor` (light transport is linear in it)."""
    if isinstance(record, dict):
        return {k: (v * factor if _scales_with_power(k) and isinstance(v, (int, float)) and not isinstance(v, bool)
                    else scale_light_amounts(v, factor)) for k, v in record.items()}
    if isinstance(record, list):
        return [scale_light_amounts(v, factor) for v in record]
    return record


__all__ = ["scale_light_amounts", "EmitterSpec", "LightingCondition", "load_lights", "parse_emitter", "LAMP_EFFICACY_LM_PER_W",
           "EMITTER_TYPES", "POWER_KINDS", "preview_rgb", "spectrum_element"]
