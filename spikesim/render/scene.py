"""Scene loading: a Mitsuba XML file, made ready for one variant, with its lights in sensor units.

The XML holds geometry, materials, the integrator, the camera and, optionally, its own emitters
in Mitsuba's radiometric units (scene_emitters.py). A lighting condition (`scene_lighting`) is
either those emitters, or a condition of the scene's light file (lights.py), which replaces them
(docs/scenes.md section 2, "The scene's own emitters"). Loading does, in order:

1. parse the XML and check what Mitsuba would only report obscurely: a missing texture or mesh
   file, not exactly one sensor;
2. for the mono variant, replace every colour (RGB values and bitmap textures of reflectances)
   by its sensor reflectance under the lighting's spectrum (reflectance.py), so that the fast path
   weights colours as the silicon pixel does rather than by luminance;
3. replace the film by the variant's film at the requested resolution, always with the `box`
   reconstruction filter (docs/design.md section 4: a Gaussian filter mixes neighbouring pixels);
4. set the XML's own emitters to the condition: those it lists get their emission in sensor
   units, the others are removed; append the light file's emitters;
5. load once with `mi.load_string` (re-loading scenes in a loop leaks, docs/design.md section 4), with
   `optimize=False`: Mitsuba 3.7+ otherwise merges meshes that share a BSDF into one shape, and
   a merged wheel could no longer be moved on its own (mitsuba3 issue #1796).
"""
from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from . import spectra
from .backend import mi
from .errors import LightError, SceneError
from .exposure import PixelResponse
from .lights import LightingCondition, load_lights
from .mono import to_sensor_reflectance
from .scene_checks import check_integrator, check_sensor_xml
from .scene_emitters import XmlEmitter, read_emitters
from .scene_files import SceneFiles, check_reference, file_references

#: Film channel holding the electron-weighted radiance in the spectral variant.
SPECTRAL_CHANNEL = "electrons"


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


#: The lighting condition of a scene without a light file: its own emitters. Named like the light
#: files' usual condition so that every command's default `--light normal` selects it.
OWN_LIGHTING = "normal"


def read_scene_xml(xml_path: Path) -> ET.Element:
    """The parsed scene, its file names made absolute; SceneError for what Mitsuba would report
    obscurely (malformed XML, a missing texture, mesh or spectrum file, an <include>)."""
    try:
        tree = ET.parse(xml_path)
    except ET.ParseError as exc:
        raise SceneError(xml_path, f"not well-formed XML: {exc}") from None
    root = tree.getroot()
    if root.tag != "scene":
        raise SceneError(xml_path, f"root element is <{root.tag}>, expected <scene>")
    for el in root.iter():
        if el.tag == "include":
            raise SceneError(xml_path, "<include> is not supported: keep a scene in one XML file")
    for ref in file_references(xml_path, root):
        if ref.path is None:
            continue  # a substitution parameter given at load time; Mitsuba reports it if unresolved
        check_reference(xml_path, ref)
        ref.element.set(ref.attribute, str(ref.path.resolve()))
    return root


def scene_lighting(files: SceneFiles, light: str = OWN_LIGHTING) -> LightingCondition:
    """The lighting condition `light` of a scene.

    With a light file, its condition `light`: it lists every light that is on, its own lights
    and, by id, any of the XML's emitters (optionally at a new power); the XML's emitters it does
    not list are off. Without one, the XML's own emitters, as condition "normal". A scene with
    neither is refused, naming the files."""
    own = read_emitters(files.xml, read_scene_xml(files.xml))
    if files.lights is not None:
        conditions = load_lights(files.lights, own)
        if light not in conditions:
            raise LightError(files.lights, f"has no lighting {light!r} (it has {sorted(conditions)})")
        return conditions[light]
    if not own:
        raise SceneError(files.xml, f"has no <emitter> and there is no light file "
                                    f"{files.xml.parent / 'lights.json'}: add an area, point, spot, constant or "
                                    "directional emitter (Mitsuba's units) or a lights.json (docs/scenes.md section 2)")
    if light != OWN_LIGHTING:
        raise LightError(files.xml, f"has no lighting {light!r}: without a lights.json beside it, the scene's own "
                                    f"emitters are its only lighting, {OWN_LIGHTING!r}")
    return LightingCondition(name=OWN_LIGHTING, emitters=own, description="the scene's own emitters",
                             reference=f"{files.xml.name}, Mitsuba's radiometric units", source=files.xml)


def _set_own_emitters(root: ET.Element, lighting: LightingCondition, variant: str, pixel: PixelResponse) -> None:
    """Give the XML's emitters that `lighting` lists their emission in sensor units; remove the rest."""
    lit = {e.index: e for e in lighting.emitters if isinstance(e, XmlEmitter)}
    parents = {child: parent for parent in root.iter() for child in parent}
    for k, el in enumerate([el for el in root.iter() if el.tag == "emitter"]):
        em = lit.get(k)
        if em is None:
            parents[el].remove(el)
            continue
        for c in [c for c in el if c.get("name") == em.quantity]:
            el.remove(c)
        el.append(em.emission_element(variant, pixel))


def prepare_xml(xml_path: Path, variant: str, lighting: LightingCondition, pixel: PixelResponse,
                resolution: tuple[int, int] | None = None) -> tuple[str, str, tuple[int, int]]:
    """The XML text Mitsuba loads, the sensor's id, and the film (height, width)."""
    root = read_scene_xml(xml_path)
    _set_own_emitters(root, lighting, variant, pixel)
    if variant == "mono":
        to_sensor_reflectance(xml_path, root, lighting, pixel)
    sensors = [el for el in root if el.tag == "sensor"]
    if len(sensors) != 1:
        raise SceneError(xml_path, f"needs exactly one <sensor>, found {len(sensors)}")
    sensor = sensors[0]
    if sensor.get("type") != "perspective":
        raise SceneError(xml_path, f"sensor type {sensor.get('type')!r}: only 'perspective' is supported")
    check_sensor_xml(xml_path, root, sensor)
    check_integrator(xml_path, root)
    sensor_id = sensor.get("id") or "camera"
    sensor.set("id", sensor_id)
    films = [el for el in sensor if el.tag == "film"]
    width = _int_param(films[0], "width") if films else None
    height = _int_param(films[0], "height") if films else None
    if resolution is not None:
        height, width = resolution
    if not width or not height or width < 1 or height < 1:
        raise SceneError(xml_path, f"the film needs positive integer width and height (400 x 250 for the spike "
                                   f"camera), got width {width} and height {height}")
    for f in films:
        sensor.remove(f)
    sensor.append(_film(variant, width, height, pixel))
    for em in lighting.emitters:
        if not isinstance(em, XmlEmitter):
            root.append(em.to_xml(variant, pixel))
    return ET.tostring(root, encoding="unicode"), sensor_id, (height, width)


def view_centre_subject(scene: Any, sensor_id: str) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """The subject when a light file names none: the surface point the camera sees at the centre
    of its image (rest pose), with its normal turned toward the camera; None if the central ray
    hits nothing or an emitter. Where a photographer would meter, and where `subject_illuminance_lux`
    reports."""
    import numpy as np

    sensor = next(s for s in scene.sensors() if s.id() == sensor_id)
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(0.5, 0.5), mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    if not bool(np.asarray(si.is_valid()).ravel()[0]):
        return None
    if bool(np.asarray(si.shape.is_emitter()).ravel()[0]):
        return None  # a lamp's own face: the light on it means nothing (it read 0 lx while the frame saturated)
    p = np.asarray(si.p, dtype=np.float64).ravel()[:3]
    n = np.asarray(si.n, dtype=np.float64).ravel()[:3]
    d = np.asarray(ray.d, dtype=np.float64).ravel()[:3]
    if n @ d > 0:
        n = -n
    return tuple(float(x) for x in p), tuple(float(x) for x in n / np.linalg.norm(n))


def with_subject(lighting: LightingCondition, scene: Any, sensor_id: str) -> LightingCondition:
    """The condition with a subject: its light file's, else the view centre's (so that its
    `subject_illuminance_lux()` answers for every scene the camera sees something of)."""
    if lighting.subject is not None:
        return lighting
    subject = view_centre_subject(scene, sensor_id)
    if subject is None:
        return lighting
    return dataclasses.replace(lighting, subject=subject, subject_from="view centre")


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


__all__ = ["SceneFiles", "prepare_xml", "load_scene", "scene_lighting", "read_scene_xml", "with_subject",
           "view_centre_subject", "OWN_LIGHTING", "SPECTRAL_CHANNEL"]
