"""A scene's own emitters: the `<emitter>`s of an ordinary Mitsuba 3 scene, in Mitsuba's units.

Units (Mitsuba 3 plugin reference, src/emitters/{area,point,spot,constant,directional}.cpp):
`area` and `constant` take a `radiance` in W m^-2 sr^-1, `point` and `spot` an `intensity` in
W sr^-1, `directional` an `irradiance` in W m^-2; in spectral variants each is per nm.

What a value means is decided by Mitsuba itself: each emitter's spectral element is loaded in
Mitsuba's `scalar_spectral` variant and evaluated on the 1 nm grid 360-830 nm (spectra.py), so a
value means here exactly what it means in a spectral Mitsuba render of the same file:

- `<spectrum value="400:0.1, 700:0.3"/>`, `type="regular"`, a `.spd` file: that spectral
  quantity, per nm (zero outside the given range);
- `<spectrum value="c"/>`: c per nm at every wavelength (an equal-energy spectrum);
- `<spectrum type="blackbody">`: Planck's law, per nm;
- `<rgb value="r, g, b"/>` (and `<float>`): Mitsuba's D65 illuminant times the colour's
  upsampled reflectance (Jakob and Hanika 2019), scaled so that its CIE Y, integral P ybar /
  integral ybar, equals the colour's luminance. So `<rgb value="1"/>` is D65 whose
  ybar-weighted mean is 1 W m^-2 sr^-1 nm^-1 per unit: 683.002 x 106.857 = 72,980 cd/m^2 as a
  radiance (72,900 with Mitsuba's tabulated D65), the same number in cd as an intensity (the same RGB value renders the same image in Mitsuba's
  RGB and spectral variants, and this is its absolute meaning there).

From the absolute spectral quantity P(lambda) the two numbers the project uses follow by the
same integrals as for a light file (docs/scenes.md section 2 and 4):

    photometric       P_v = K_m integral P(lambda) V(lambda) dlambda      (cd/m^2, cd or lx)
    electron-weighted P_q = integral P(lambda) QE(lambda) lambda/(h c) dlambda = P_v k_q(S)

with K_m = 683.002 lm/W and V the CIE 1924 photopic curve (CIE S 017:2020, 17-21-050), and S
= P / P_v the spectral shape, registered by name (spectra.register_spectrum) so that k_q, the
mono path's reflectances and the spectral film treat it like any CIE lamp. Each emitter becomes
an `XmlEmitter`, an EmitterSpec whose photometric value is P_v, so illuminance, flux and the
light file's power overrides (lights.load_lights) work on it unchanged.
"""
from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import spectra
from .errors import SceneError
from .exposure import PixelResponse
from .lights import EmitterSpec, spectrum_element

#: Mitsuba emitter type -> (the parameter holding its emission, its unit, our EmitterSpec type).
SUPPORTED = {
    "area": ("radiance", "W m^-2 sr^-1", "area"),
    "point": ("intensity", "W sr^-1", "point"),
    "spot": ("intensity", "W sr^-1", "spot"),
    "constant": ("radiance", "W m^-2 sr^-1", "sky"),
    "directional": ("irradiance", "W m^-2", "directional"),
}
#: The most an emitter may give per nm (in its own unit): 10^22 times the sun's spectral radiance.
#: Mitsuba renders in 32-bit floats (at most 3.4e38), and an emission of 1e38 per nm rendered
#: infinite pixels; a bound far below that leaves room for the render's own factors.
MAX_EMISSION_PER_NM = 1e30
#: Stratified samples per axis over an area emitter's surface for its illuminance integral.
AREA_SAMPLES_PER_AXIS = 64


@dataclass(frozen=True)
class XmlEmitter(EmitterSpec):
    """One `<emitter>` of the scene XML (the `index`-th in document order), with its emission
    converted as the module docstring says. `type` is the light-file vocabulary (constant ->
    "sky"; area on any shape -> "area"); `mitsuba_type` is the XML's."""

    index: int = 0
    mitsuba_type: str = ""
    quantity: str = ""
    given: str = ""
    """The emission element as written in the XML (for the record)."""
    area_m2: float | None = None
    samples: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(default=None, compare=False, repr=False)
    """Area emitters: surface points, normals and weights 1/(pdf N) of stratified samples."""

    def luminous_flux_lm(self) -> float:
        if self.type == "area":
            return math.pi * self.photometric * self.area_m2  # Lambertian, one-sided: F = pi L A
        return super().luminous_flux_lm()

    def illuminance_at(self, point: Any, normal: Any) -> float:
        """Direct illuminance (lx) at `point` facing `normal`, ignoring occlusion. An area
        emitter (Lambertian, emitting on its normal's side as Mitsuba's `area`) integrates
        L cos(theta_e) cos(theta_r) / d^2 over its surface by stratified samples."""
        if self.type != "area":
            return super().illuminance_at(point, normal)
        p = np.asarray(point, dtype=np.float64)
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        pts, nrm, w = self.samples
        v = p - pts  # from the light to the point
        d2 = np.sum(v * v, axis=-1)
        d = np.sqrt(d2)
        with np.errstate(divide="ignore", invalid="ignore"):
            cos_e = np.clip(np.sum(v * nrm, axis=-1) / d, 0.0, None)
            cos_r = np.clip(-(v @ n) / d, 0.0, None)
            g = np.where(d2 > 0, cos_e * cos_r / d2, 0.0)
        return float(self.photometric * np.sum(g * w))

    def emission_element(self, variant: str, pixel: PixelResponse) -> ET.Element:
        """The element that replaces the XML's own emission value for `variant`."""
        return spectrum_element(self.quantity, self.spectrum, self.photometric, variant, pixel)

    def describe(self, pixel: PixelResponse | None = None) -> dict[str, Any]:
        out = super().describe(pixel)
        out.update({"from": "scene XML", "mitsuba_type": self.mitsuba_type, "xml": self.given})
        if self.area_m2 is not None:
            out["area_m2"] = self.area_m2
            out["luminous_flux_lm"] = self.luminous_flux_lm()
        return out


def read_emitters(xml_path: Path, root: ET.Element) -> tuple[XmlEmitter, ...]:
    """Every `<emitter>` of a parsed scene (file names already absolute), in document order."""
    elements = [el for el in root.iter() if el.tag == "emitter"]
    if not elements:
        return ()
    from .backend import mi

    parents = {child: parent for parent in root.iter() for child in parent}
    previous = mi.variant()
    mi.set_variant("scalar_spectral")
    try:
        out = tuple(_read_emitter(xml_path, k, el, parents.get(el)) for k, el in enumerate(elements))
    finally:
        if previous:
            mi.set_variant(previous)
    ids = [e.id for e in out]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise SceneError(xml_path, f"emitter id(s) {dup} are used twice; give each <emitter> (or its shape) its own id")
    return out


def _where(k: int, el: ET.Element, parent: ET.Element | None) -> str:
    shape = f" in <shape id={parent.get('id')!r}>" if parent is not None and parent.tag == "shape" and parent.get("id") else ""
    ident = f" id={el.get('id')!r}" if el.get("id") else ""
    return f"<emitter type={el.get('type')!r}{ident}>{shape} (emitter {k + 1})"


def _read_emitter(xml_path: Path, k: int, el: ET.Element, parent: ET.Element | None) -> XmlEmitter:
    etype = el.get("type")
    where = _where(k, el, parent)
    if etype not in SUPPORTED:
        raise SceneError(xml_path, f"{where}: only {', '.join(SUPPORTED)} emitters are supported; light the scene "
                                   "with a lights.json instead (docs/scenes.md section 2)")
    quantity, unit, our_type = SUPPORTED[etype]
    if any(c.tag == "texture" for c in el):
        raise SceneError(xml_path, f"{where}: a textured emitter is not supported; give its {quantity} as an "
                                   "<rgb> or <spectrum>")
    given = [c for c in el if c.get("name") == quantity]
    if not given:  # Mitsuba's default for every supported emitter: its D65 spectrum at scale 1
        given = [ET.Element("float", name=quantity, value="1")]
    if len(given) != 1 or given[0].tag not in ("rgb", "spectrum", "float"):
        raise SceneError(xml_path, f"{where} needs one <rgb> or <spectrum name={quantity!r}>, in Mitsuba's units "
                                   f"({unit}, per nm in spectral variants)")
    values = _spectral_values(xml_path, where, given[0], quantity)
    if not np.all(np.isfinite(values)) or values.min() < 0:
        raise SceneError(xml_path, f"{where}: its {quantity} must be finite and non-negative")
    if values.max() > MAX_EMISSION_PER_NM:
        raise SceneError(xml_path, f"{where}: its {quantity} reaches {values.max():.3g} {unit} per nm, above the "
                                   f"{MAX_EMISSION_PER_NM:g} a render can carry in 32-bit floats (it would render "
                                   "infinite pixels); give it in Mitsuba's units")
    try:
        spectrum = spectra.register_spectrum(values)
    except ValueError:
        raise SceneError(xml_path, f"{where} emits no visible light (its {quantity} is zero wherever V(lambda) > 0); "
                                   "remove it or give it a power") from None
    if parent is not None and parent.tag == "shape":
        eid = el.get("id") or parent.get("id")
    else:
        eid = el.get("id")
    kw: dict[str, Any] = {"id": eid or f"emitter_{k + 1}", "type": our_type, "spectrum": spectrum,
                          "power": {f"xml_{quantity}": ET.tostring(given[0], encoding="unicode").strip()},
                          "photometric": spectra.photometric(values), "index": k, "mitsuba_type": etype,
                          "quantity": quantity, "given": ET.tostring(given[0], encoding="unicode").strip()}
    kw.update(_geometry(xml_path, where, etype, el, parent, quantity))
    return XmlEmitter(**kw)


def _spectral_values(xml_path: Path, where: str, given: ET.Element, quantity: str) -> np.ndarray:
    """The element's spectrum on spectra.WAVELENGTHS_NM, as Mitsuba's scalar_spectral variant
    evaluates it in an emitter: a probe point light with this intensity, seen from 1 m."""
    from .backend import mi

    probe = ET.Element("emitter", {"version": "3.0.0", "type": "point"})
    value = copy.deepcopy(given)
    value.set("name", "intensity")
    probe.append(value)
    ET.SubElement(probe, "point", name="position", value="0, 0, 1")
    try:
        em = mi.load_string(ET.tostring(probe, encoding="unicode"))
    except RuntimeError as exc:
        raise SceneError(xml_path, f"{where}: Mitsuba cannot read its {quantity}: {exc}") from None
    it = mi.Interaction3f()
    it.p = mi.Point3f(0.0, 0.0, 0.0)
    wl = spectra.WAVELENGTHS_NM
    padded = np.concatenate([wl, np.full((-wl.size) % 4, wl[-1])])
    out = []
    for i in range(0, padded.size, 4):
        it.wavelengths = [float(x) for x in padded[i:i + 4]]
        _, val = em.sample_direction(it, mi.Point2f(0.5, 0.5))  # intensity / (1 m)^2
        out.extend(float(v) for v in val)
    return np.asarray(out[:wl.size], dtype=np.float64)


def _neutral(el: ET.Element, quantity: str) -> ET.Element:
    """A copy of an emitter element with a unit spectrum in place of its emission (for geometry)."""
    out = copy.deepcopy(el)
    for c in [c for c in out if c.get("name") == quantity]:
        out.remove(c)
    ET.SubElement(out, "spectrum", name=quantity, value="1")
    out.set("version", "3.0.0")
    out.attrib.pop("id", None)
    return out


def _geometry(xml_path: Path, where: str, etype: str, el: ET.Element, parent: ET.Element | None,
              quantity: str) -> dict[str, Any]:
    """Where the emitter is, in EmitterSpec's terms, read from the emitter Mitsuba loads."""
    from .backend import mi

    if etype == "constant":
        return {}
    if etype == "area":
        return _area_geometry(xml_path, where, el, parent)
    try:
        params = mi.traverse(mi.load_string(ET.tostring(_neutral(el, quantity), encoding="unicode")))
    except RuntimeError as exc:
        raise SceneError(xml_path, f"{where}: Mitsuba rejected it: {exc}") from None
    if etype == "point":
        return {"position": tuple(float(x) for x in params["position"])}
    m = np.array(params["to_world"].matrix, dtype=np.float64)
    axis = m[:3, 2] / np.linalg.norm(m[:3, 2])
    if etype == "directional":
        return {"direction": tuple(axis)}
    position = m[:3, 3]
    up = m[:3, 1] / np.linalg.norm(m[:3, 1])
    return {"position": tuple(position), "target": tuple(position + axis), "up": tuple(up),
            "cutoff_deg": float(params["cutoff_angle"]), "beam_deg": float(params["beam_width"])}


def _area_geometry(xml_path: Path, where: str, el: ET.Element, parent: ET.Element | None) -> dict[str, Any]:
    """The shape an area emitter sits on: its area and stratified surface samples (Mitsuba's own
    shape sampling, so meshes, spheres, discs and rectangles are all handled)."""
    from .backend import mi

    if parent is None or parent.tag != "shape":
        raise SceneError(xml_path, f"{where}: an area emitter belongs inside a <shape>")
    shape = copy.deepcopy(parent)
    for c in [c for c in shape if c.tag in ("bsdf", "ref", "emitter", "medium")]:
        shape.remove(c)
    shape.set("version", "3.0.0")
    shape.attrib.pop("id", None)
    try:
        obj = mi.load_string(ET.tostring(shape, encoding="unicode"))
        n = AREA_SAMPLES_PER_AXIS
        pts, nrm, w = np.empty((n * n, 3)), np.empty((n * n, 3)), np.empty(n * n)
        for i in range(n):
            for j in range(n):
                ps = obj.sample_position(0.0, mi.Point2f((i + 0.5) / n, (j + 0.5) / n))
                pts[i * n + j], nrm[i * n + j], w[i * n + j] = tuple(ps.p), tuple(ps.n), float(ps.pdf)
        area = float(obj.surface_area())
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise SceneError(xml_path, f"{where}: its shape cannot be sampled for the illuminance it gives ({exc})") from None
    if not area > 0 or not np.all(w > 0):
        raise SceneError(xml_path, f"{where}: its shape has no area")
    return {"area_m2": area, "samples": (pts, nrm, 1.0 / (w * n * n))}


__all__ = ["XmlEmitter", "read_emitters", "SUPPORTED", "AREA_SAMPLES_PER_AXIS", "MAX_EMISSION_PER_NM"]
