"""A scene's own Mitsuba emitters: read from its XML in Mitsuba's radiometric units and given the
photometric value that carries them through the same exposure chain as a lights.json lamp.

Units (Mitsuba 3 plugin reference): an `area` or `constant` emitter's `radiance` is in
W m^-2 sr^-1, a `point` or `spot` emitter's `intensity` in W sr^-1, a `directional` emitter's
`irradiance` in W m^-2, each per nm in the spectral variants. Mitsuba makes an RGB value a
spectrum whose CIE Y equals the colour's luminance, relative to a flat spectrum of 1 per nm
(its `srgb_d65` uplift scales the D65 illuminant that way, and its film divides by the integral
of y-bar). So an emitter of luminance Y in Mitsuba's units has the photometric value

    K_m * integral(V dlambda) * Y      (cd/m^2, cd or lx)             [CIE 018:2019: K_m = 683 lm/W]

with integral(V) = 106.9 nm over 360-830 nm. The spectral shape of RGB and flat values is taken
as D65 (what Mitsuba's uplift multiplies); a tabulated spectrum keeps its luminance but is also
rendered with the D65 shape (docs/scenes.md, "Your own scene").
"""
from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import spectra
from .errors import LightError, SceneError
from .exposure import PixelResponse
from .lights import EmitterSpec, LightingCondition, _spectrum_element

#: The spectrum XML emitters are rendered with (Mitsuba's RGB uplift for emitters is D65-based).
XML_EMITTER_SPECTRUM = "D65"
#: The name of the lighting made from a scene's own emitters; "normal" is accepted as its alias so
#: that commands whose default lighting is "normal" work on such a scene unchanged.
XML_LIGHTING = "scene"
XML_LIGHTING_ALIASES = ("normal",)

#: Which child holds each emitter type's power, and the photometric unit it becomes.
_QUANTITY = {"area": ("radiance", "cd/m^2"), "constant": ("radiance", "cd/m^2"),
             "point": ("intensity", "cd"), "spot": ("intensity", "cd"), "directional": ("irradiance", "lx")}
#: Samples of the Monte Carlo estimate of an area light's illuminance (relative error ~ 1/sqrt(n)).
AREA_ILLUMINANCE_SAMPLES = 1 << 18


def luminance_to_photometric() -> float:
    """Photometric value per unit of Mitsuba luminance: K_m times the integral of V (lm/W nm)."""
    return spectra.K_M * spectra.integrate(spectra.photopic_v())


def _floats(text: str, path: Path, where: str) -> list[float]:
    try:
        return [float(t) for t in text.replace(",", " ").split()]
    except ValueError:
        raise SceneError(path, f"{where}: {text!r} is not a list of numbers") from None


def mitsuba_luminance(el: ET.Element, path: Path, where: str) -> float:
    """CIE Y, in Mitsuba's units, of an emitter's `<rgb>`, `<spectrum>` or `<float>` value."""
    value = el.get("value")
    if el.tag == "rgb" and value is not None:
        rgb = _floats(value, path, where)
        if len(rgb) == 1:
            rgb = rgb * 3
        if len(rgb) != 3:
            raise SceneError(path, f"{where}: an rgb value needs 3 numbers, got {value!r}")
        return float(np.dot([0.2126, 0.7152, 0.0722], rgb))  # linear sRGB luminance (IEC 61966-2-1)
    if el.tag == "float" and value is not None:
        return _floats(value, path, where)[0]
    if el.tag == "spectrum" and value is not None and ":" not in value:
        return _floats(value, path, where)[0]  # a flat spectrum: Y equals the value
    if el.tag == "spectrum" and value is not None:
        pairs = [p.split(":") for p in value.replace(" ", "").split(",") if p]
        try:
            wl, s = np.array([[float(a), float(b)] for a, b in pairs]).T
        except ValueError:
            raise SceneError(path, f"{where}: {value!r} is not a list of wavelength:value pairs") from None
        v = spectra.photopic_v()
        return spectra.integrate(np.interp(spectra.WAVELENGTHS_NM, wl, s, left=0.0, right=0.0) * v) / spectra.integrate(v)
    raise SceneError(path, f"{where}: only rgb, float or spectrum values are supported as an emitter's power "
                           f"(found <{el.tag}{' type=' + repr(el.get('type')) if el.get('type') else ''}>); "
                           "give the light in a lights.json instead")


def _power_child(em: ET.Element, quantity: str) -> ET.Element | None:
    return next((c for c in em if c.get("name") == quantity), None)


def _point(el: ET.Element | None) -> tuple[float, ...] | None:
    if el is None:
        return None
    if el.get("value") is not None:
        vals = [float(t) for t in el.get("value", "").replace(",", " ").split()]
        return tuple(vals * 3 if len(vals) == 1 else vals)
    return tuple(float(el.get(k, "0")) for k in ("x", "y", "z"))


def _lookat(em: ET.Element) -> ET.Element | None:
    tr = next((c for c in em if c.tag == "transform" and c.get("name") == "to_world"), None)
    return None if tr is None else next((c for c in tr if c.tag == "lookat"), None)


def _child(em: ET.Element, tag: str, name: str) -> ET.Element | None:
    return next((c for c in em if c.tag == tag and c.get("name") == name), None)


def _analytic(em: ET.Element, etype: str, eid: str, photometric: float, path: Path) -> EmitterSpec:
    """A point, spot, directional or constant emitter as the equivalent lights.json emitter."""
    kw: dict[str, Any] = {"id": eid, "spectrum": XML_EMITTER_SPECTRUM, "photometric": photometric,
                          "power": {"from_scene_xml": True}}
    look = _lookat(em)
    if etype == "point":
        pos = _point(_child(em, "point", "position")) or (_point_attr(look, "origin") if look is not None else None)
        if pos is None:
            raise SceneError(path, f"point emitter {eid!r} needs a <point name=\"position\"> (or a to_world lookat)")
        return EmitterSpec(type="point", position=pos, **kw)
    if etype == "spot":
        if look is None:
            raise SceneError(path, f"spot emitter {eid!r} needs a to_world <lookat origin=... target=...>")
        # Mitsuba's spot defaults: cutoff_angle 20 degrees, beam_width 3/4 of it (spot.cpp)
        cutoff = _float_param(em, "cutoff_angle", 20.0)
        beam = _float_param(em, "beam_width", 0.75 * cutoff)
        return EmitterSpec(type="spot", position=_point_attr(look, "origin"), target=_point_attr(look, "target"),
                           up=_point_attr(look, "up") or (0.0, 0.0, 1.0), cutoff_deg=cutoff, beam_deg=beam, **kw)
    if etype == "directional":
        d = _point(_child(em, "vector", "direction"))
        if d is None and look is not None:
            d = tuple(np.subtract(_point_attr(look, "target"), _point_attr(look, "origin")))
        if d is None:
            raise SceneError(path, f"directional emitter {eid!r} needs a <vector name=\"direction\">")
        return EmitterSpec(type="directional", direction=tuple(np.asarray(d) / np.linalg.norm(d)), **kw)
    return EmitterSpec(type="sky", **kw)


def _float_param(em: ET.Element, name: str, default: float) -> float:
    el = _child(em, "float", name)
    return default if el is None else float(el.get("value", default))


def _point_attr(look: ET.Element, key: str) -> tuple[float, ...] | None:
    v = look.get(key)
    return None if v is None else tuple(float(t) for t in v.replace(",", " ").split())


@dataclass(frozen=True)
class AreaEmitter:
    """An `area` emitter on any shape of the XML, kept as that shape's XML with its radiance
    replaced; its illuminance is a Monte Carlo estimate on the shape alone (no occlusion, as for
    lights.json lamps)."""

    id: str
    shape_xml: str
    photometric: float
    spectrum: str = XML_EMITTER_SPECTRUM
    type: str = "area"

    def to_xml(self, variant: str, pixel: PixelResponse) -> ET.Element:
        shape = ET.fromstring(self.shape_xml)
        em = next(c for c in shape if c.tag == "emitter")
        for c in [c for c in em if c.get("name") == "radiance"]:
            em.remove(c)
        em.append(_spectrum_element("radiance", self.spectrum, self.photometric, variant, pixel))
        return shape

    def illuminance_at(self, point: Any, normal: Any) -> float:
        return self.photometric * _area_illuminance_per_luminance(self.shape_xml, tuple(point), tuple(normal))

    def luminous_flux_lm(self) -> float:
        return math.nan  # the emitting area of an arbitrary shape is not computed

    def describe(self, pixel: PixelResponse | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {"id": self.id, "type": "area", "spectrum": self.spectrum,
                               "photometric": self.photometric, "photometric_unit": "cd/m^2", "source": "scene XML"}
        if pixel is not None:
            out["electrons_per_lumen_second"] = pixel.electrons_per_lumen_second(self.spectrum)
        return out


def _area_illuminance_per_luminance(shape_xml: str, point: tuple, normal: tuple) -> float:
    """Integral over the shape's emitting surface of cos_e cos_r / d^2 dA (sr), by emitter sampling
    in Mitsuba (the shape alone, radiance 1, seeded so that the estimate is reproducible)."""
    from .backend import dr, mi, use_variant, variant_name

    previous = mi.variant()
    use_variant(variant_name("mono", "llvm"))
    try:
        shape = ET.fromstring(shape_xml)
        em = next(c for c in shape if c.tag == "emitter")
        for c in [c for c in em if c.get("name") == "radiance"]:
            em.remove(c)
        ET.SubElement(em, "spectrum", name="radiance", value="1")
        scene = mi.load_string(f'<scene version="3.0.0">{ET.tostring(shape, encoding="unicode")}</scene>')
        n = AREA_ILLUMINANCE_SAMPLES
        u = np.random.default_rng(0).random((2, n), dtype=np.float32)
        it = dr.zeros(mi.Interaction3f, n)
        it.p = mi.Point3f(*[float(c) for c in point])
        nrm = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
        ds, weight = scene.sample_emitter_direction(it, mi.Point2f(u[0], u[1]), False)
        cos_r = dr.maximum(dr.dot(ds.d, mi.Vector3f(*[float(c) for c in nrm])), 0.0)
        return float(dr.mean(weight[0] * cos_r)[0]) if dr.width(weight[0]) else 0.0
    finally:
        if previous is not None and previous != mi.variant():
            use_variant(previous)


def _resolved(shape: ET.Element, base: Path) -> ET.Element:
    """A copy of a shape with its file references made absolute (it is re-appended elsewhere)."""
    out = copy.deepcopy(shape)
    for el in out.iter():
        if el.tag == "string" and el.get("name") == "filename" and "$" not in el.get("value", ""):
            f = Path(el.get("value", ""))
            el.set("value", str(f if f.is_absolute() else (base / f).resolve()))
    return out


def emitting_elements(root: ET.Element) -> list[tuple[ET.Element, ET.Element]]:
    """(element to remove from the root, the emitter) for every emitter of the scene: top-level
    emitters, and shapes that carry an area emitter."""
    out = []
    for el in root:
        if el.tag == "emitter":
            out.append((el, el))
        elif el.tag == "shape":
            out.extend((el, c) for c in el if c.tag == "emitter")
    return out


def has_emitters(xml_path: Path) -> bool:
    try:
        return bool(emitting_elements(ET.parse(xml_path).getroot()))
    except ET.ParseError:
        return False  # prepare_xml reports the parse error with its position


def _subject_from_camera(root: ET.Element) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """Where the camera looks (its lookat target), facing the camera: the subject by default."""
    sensor = next((el for el in root if el.tag == "sensor"), None)
    look = _lookat(sensor) if sensor is not None else None
    if look is None or look.get("target") is None or look.get("origin") is None:
        return None
    target, origin = np.asarray(_point_attr(look, "target")), np.asarray(_point_attr(look, "origin"))
    n = origin - target
    return tuple(target.tolist()), tuple((n / np.linalg.norm(n)).tolist())


def xml_lighting(xml_path: Path) -> LightingCondition:
    """The lighting made of the scene's own emitters, converted to photometric values."""
    root = ET.parse(xml_path).getroot()
    factor = luminance_to_photometric()
    emitters: list[Any] = []
    for i, (holder, em) in enumerate(emitting_elements(root)):
        etype = em.get("type", "")
        if etype not in _QUANTITY:
            raise LightError(xml_path, f"emitter type {etype!r} is not supported; the scene's own emitters may be "
                                       f"{sorted(_QUANTITY)} (or describe the lights in a lights.json)")
        quantity, _ = _QUANTITY[etype]
        child = _power_child(em, quantity)
        where = f"<emitter type={etype!r}>'s {quantity}"
        if child is None:
            raise LightError(xml_path, f"{where} is not given (Mitsuba's default of 1 W would be a guess: give it)")
        y = mitsuba_luminance(child, xml_path, where)
        if not (math.isfinite(y) and y > 0):
            raise LightError(xml_path, f"{where} has luminance {y:g}: an emitter's power must be positive")
        eid = holder.get("id") or em.get("id") or f"{etype}_{i}"
        if etype == "area":
            emitters.append(AreaEmitter(id=eid, shape_xml=ET.tostring(_resolved(holder, xml_path.parent), encoding="unicode"),
                                        photometric=factor * y))
        else:
            emitters.append(_analytic(em, etype, eid, factor * y, xml_path))
    if not emitters:
        raise LightError(xml_path, "has no emitter and no lights.json beside it: add one or the other")
    return LightingCondition(name=XML_LIGHTING, emitters=tuple(emitters), subject=_subject_from_camera(root),
                             description="the scene's own Mitsuba emitters, converted from W m^-2 sr^-1 (W sr^-1, W m^-2)",
                             reference="Mitsuba 3 emitter units; photometry: CIE 018:2019 (K_m = 683 lm/W)",
                             source=xml_path)


__all__ = ["XML_LIGHTING", "XML_LIGHTING_ALIASES", "XML_EMITTER_SPECTRUM", "AreaEmitter", "xml_lighting",
           "has_emitters", "emitting_elements", "luminance_to_photometric", "mitsuba_luminance"]
