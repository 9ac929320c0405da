"""Scene loading: a Mitsuba XML file, made ready for one variant, with its lights added.

The XML holds geometry, materials, the integrator and the camera. Lights come from the scene's
light file, where their power is given in photometric units (lights.py), or, when there is no
light file, from the XML's own emitters, read in Mitsuba's radiometric units (scene_emitters.py).
A light file overrides the XML's emitters: they are removed (an emitting shape stays as geometry).
Loading does, in order:

1. parse the XML and check what Mitsuba would only report obscurely: a missing texture or mesh
   file, not exactly one sensor; take the XML's emitters out;
2. for the mono variant, replace every colour (RGB values and bitmap textures of reflectances)
   by its sensor reflectance under the lighting's spectrum (reflectance.py), so that the fast path
   weights colours as the silicon pixel does rather than by luminance;
3. replace the film by the variant's film at the requested resolution, always with the `box`
   reconstruction filter (docs/design.md section 4: a Gaussian filter mixes neighbouring pixels);
4. append the lighting condition's emitters;
5. load once with `mi.load_string` (re-loading scenes in a loop leaks, docs/design.md section 4), with
   `optimize=False`: Mitsuba 3.7+ otherwise merges meshes that share a BSDF into one shape, and
   a merged wheel could no longer be moved on its own (mitsuba3 issue #1796).
"""
from __future__ import annotations

import hashlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from . import spectra
from .backend import mi
from .errors import SceneError
from .exposure import PixelResponse
from .lights import LightingCondition, load_lights
from .scene_emitters import XML_LIGHTING, XML_LIGHTING_ALIASES, emitting_elements, has_emitters, xml_lighting
from .mono import to_sensor_reflectance

#: Film channel holding the electron-weighted radiance in the spectral variant.
SPECTRAL_CHANNEL = "electrons"


@dataclass(frozen=True)
class SceneFiles:
    """The files that make a scene: XML, motion (optional) and lights (None: the XML's own emitters)."""

    name: str
    xml: Path
    motion: Path | None
    lights: Path | None

    @classmethod
    def resolve(cls, scene: str | Path, motion: str | Path | None = None,
                lights: str | Path | None = None) -> "SceneFiles":
        """`scene` is a bundled scene's name (scenes.scene_path) or a path to an XML file; the
        motion and light files default to `motion.json` and `lights.json` beside it; without a
        light file the XML's own emitters light the scene."""
        p = Path(scene)
        if p.suffix.lower() != ".xml" and not p.exists():
            from scenes import SCENES, scene_path
            if str(scene).lower() not in SCENES:
                raise SceneError(p, f"neither a bundled scene ({', '.join(SCENES)}) nor an existing XML file")
            p = scene_path(str(scene))
        if p.is_dir():
            p = p / "scene.xml"
        if not p.is_file():
            raise SceneError(p, "scene XML file does not exist")
        m = Path(motion) if motion is not None else p.parent / "motion.json"
        if motion is not None and not m.is_file():
            raise SceneError(m, "motion file does not exist")
        lt = Path(lights) if lights is not None else p.parent / "lights.json"
        if lights is not None and not lt.is_file():
            raise SceneError(lt, "light file does not exist")
        if not lt.is_file() and not has_emitters(p):
            raise SceneError(p, f"has no emitter and there is no light file ({lt.name} beside it): "
                                "add Mitsuba emitters to the XML or write a lights.json")
        name = p.parent.name if p.name == "scene.xml" else p.stem
        return cls(name=name, xml=p.resolve(), motion=m.resolve() if m.is_file() else None,
                   lights=lt.resolve() if lt.is_file() else None)

    def lightings(self) -> dict[str, LightingCondition]:
        """The scene's lighting conditions by name: the light file's, or the XML's own emitters as
        `scene` (alias `normal`)."""
        if self.lights is not None:
            return load_lights(self.lights)
        lighting = xml_lighting(self.xml)
        return {XML_LIGHTING: lighting, **{alias: lighting for alias in XML_LIGHTING_ALIASES}}

    def digests(self) -> dict[str, str]:
        """sha256 of each file, so a description pins exactly what was rendered."""
        out = {}
        for key in ("xml", "motion", "lights"):
            path = getattr(self, key)
            if path is not None:
                out[key] = hashlib.sha256(path.read_bytes()).hexdigest()
        return out


def _film(variant: str, width: int, height: int, pixel: PixelResponse) -> ET.Element:
    if variant == "spectral":
        film = ET.Element("film", type="specfilm")
        ET.SubElement(film, "string", name="component_format", value="float32")
        srf = ET.SubElement(film, "spectrum", name=SPECTRAL_CHANNEL, type="regular")
        lo, hi, vals = spectra.regular_values(pixel.electrons_per_joule(), step_nm=1.0)
        # the film integrates L(lambda) * srf(lambda) without normalising the srf (specfilm.cpp),
        # so this srf makes it record electron-weighted radiance directly (exposure.py, step 1)
        ET.SubElement(srf, "float", name="wavelength_min", value=f"{lo:g}")
        ET.SubElement(srf, "float", name="wavelength_max", value=f"{hi:g}")
        ET.SubElement(srf, "string", name="values", value=", ".join(f"{v:.9g}" for v in vals))
    else:
        film = ET.Element("film", type="hdrfilm")
        ET.SubElement(film, "string", name="pixel_format", value="luminance" if variant == "mono" else "rgb")
        ET.SubElement(film, "string", name="component_format", value="float32")
    ET.SubElement(film, "integer", name="width", value=str(width))
    ET.SubElement(film, "integer", name="height", value=str(height))
    ET.SubElement(film, "rfilter", type="box")
    return film


def _int_param(el: ET.Element, name: str) -> int | None:
    for child in el:
        if child.tag == "integer" and child.get("name") == name:
            try:
                return int(child.get("value", ""))
            except ValueError:
                return None
    return None


def _take_out_emitters(xml_path: Path, root: ET.Element, lit_by_xml: bool) -> None:
    """Remove the XML's emitters: the lighting (from the light file, or the same emitters converted
    to the project's units by scene_emitters.xml_lighting) is appended afterwards."""
    top = emitting_elements(root)
    known = {id(em) for _, em in top}
    for el in root.iter():
        if el.tag == "emitter" and id(el) not in known:
            raise SceneError(xml_path, f"has an <emitter type={el.get('type')!r}> nested below the top level or "
                                       "a top-level shape; only those two places are supported")
    for holder, em in top:
        if holder is em or lit_by_xml:  # an XML-lit scene re-appends the emitting shape, converted
            if holder in list(root):
                root.remove(holder)
        else:
            holder.remove(em)  # overridden by the light file: the shape stays as geometry


def prepare_xml(xml_path: Path, variant: str, lighting: LightingCondition, pixel: PixelResponse,
                resolution: tuple[int, int] | None = None) -> tuple[str, str, tuple[int, int]]:
    """The XML text Mitsuba loads, the sensor's id, and the film (height, width)."""
    try:
        tree = ET.parse(xml_path)
    except ET.ParseError as exc:
        raise SceneError(xml_path, f"not well-formed XML: {exc}") from None
    root = tree.getroot()
    if root.tag != "scene":
        raise SceneError(xml_path, f"root element is <{root.tag}>, expected <scene>")
    base = xml_path.parent
    _take_out_emitters(xml_path, root, lit_by_xml=lighting.name == XML_LIGHTING and lighting.source == xml_path)
    for el in root.iter():
        if el.tag == "string" and el.get("name") == "filename":
            value = el.get("value", "")
            if "$" in value:
                continue  # a substitution parameter; Mitsuba reports it if unresolved
            f = Path(value) if Path(value).is_absolute() else base / value
            if not f.is_file():
                raise SceneError(xml_path, f"references file {value!r} (a texture, mesh or spectrum), which does "
                                           f"not exist (looked for {f})")
            el.set("value", str(f.resolve()))
        if el.tag == "include":
            raise SceneError(xml_path, "<include> is not supported: keep a scene in one XML file")
    if variant == "mono":
        to_sensor_reflectance(xml_path, root, lighting, pixel)
    sensors = [el for el in root if el.tag == "sensor"]
    if len(sensors) != 1:
        raise SceneError(xml_path, f"needs exactly one <sensor>, found {len(sensors)}")
    sensor = sensors[0]
    if sensor.get("type") != "perspective":
        raise SceneError(xml_path, f"sensor type {sensor.get('type')!r}: only 'perspective' is supported")
    sensor_id = sensor.get("id") or "camera"
    sensor.set("id", sensor_id)
    films = [el for el in sensor if el.tag == "film"]
    width = _int_param(films[0], "width") if films else None
    height = _int_param(films[0], "height") if films else None
    if resolution is not None:
        height, width = resolution
    if not width or not height:
        raise SceneError(xml_path, "the film needs integer width and height (400 x 250 for the spike camera)")
    for f in films:
        sensor.remove(f)
    sensor.append(_film(variant, width, height, pixel))
    for em in lighting.emitters:
        root.append(em.to_xml(variant, pixel))
    return ET.tostring(root, encoding="unicode"), sensor_id, (height, width)


def load_scene(xml_path: Path, text: str):
    """Instantiate the prepared scene, turning Mitsuba's errors into one naming the file."""
    try:
        return mi.load_string(text, optimize=False)
    except RuntimeError as exc:
        # Prefer Mitsuba's message on the original file: its line numbers are the user's.
        try:
            original = mi.load_file(str(xml_path), optimize=False)
            del original
        except RuntimeError as exc2:
            raise SceneError(xml_path, f"Mitsuba rejected the scene: {exc2}") from None
        raise SceneError(xml_path, f"Mitsuba rejected the scene once its film and lights were added: {exc}") from None


__all__ = ["SceneFiles", "prepare_xml", "load_scene", "SPECTRAL_CHANNEL"]
