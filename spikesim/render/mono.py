"""The mono fast path's colours: every reflectance in a scene as the silicon pixel sees it.

Mitsuba's mono variant would reduce a colour to its luminance (the eye's weighting); here each
RGB value becomes one number, its sensor reflectance under the lighting (reflectance.py), and each
bitmap texture of a reflectance becomes a single-channel linear EXR of those numbers, written to a
per-process temporary folder and cached by content. Only elements named like a reflectance or
transmittance are touched (not, e.g., a conductor's index of refraction or a raw data texture).
"""
from __future__ import annotations

import atexit
import hashlib
import logging
import re
import shutil
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .errors import SceneError
from .exposure import PixelResponse
from .lights import LightingCondition
from .reflectance import SensorReflectance, light_weight

log = logging.getLogger(__name__)

_COLOUR_NAME = re.compile(r"reflectance|transmittance")
_CACHE: dict[str, Path] = {}
_CACHE_DIR: Path | None = None


def _cache_dir() -> Path:
    global _CACHE_DIR
    if _CACHE_DIR is None:
        _CACHE_DIR = Path(tempfile.mkdtemp(prefix="spikesim-mono-"))
        atexit.register(shutil.rmtree, _CACHE_DIR, True)
    return _CACHE_DIR


def spectrum_mix(lighting: LightingCondition) -> dict[str, float]:
    """Each light spectrum's share of the illuminance at the lighting's subject (equal shares of
    the emitters when no subject is given)."""
    mix: dict[str, float] = {}
    for em in lighting.emitters:
        share = em.illuminance_at(*lighting.subject) if lighting.subject else 1.0
        mix[em.spectrum] = mix.get(em.spectrum, 0.0) + share
    if sum(mix.values()) <= 0:
        mix = {em.spectrum: 1.0 for em in lighting.emitters}
    total = sum(mix.values())
    return {k: v / total for k, v in mix.items()}


def _sensor_texture(path: Path, conv: SensorReflectance) -> Path | None:
    """A linear single-channel EXR of the texture's sensor reflectance (cached per process)."""
    from PIL import Image

    from spikesim.imageio import write_exr

    key = hashlib.sha256(path.read_bytes()).hexdigest()[:16] + "-" + conv.digest
    if key in _CACHE and _CACHE[key].is_file():
        return _CACHE[key]
    try:
        with Image.open(path) as im:
            img = np.asarray(im.convert("RGB") if im.mode not in ("RGB", "I;16") else im)
    except OSError:
        log.warning("%s: not an 8/16-bit image; the mono variant uses its luminance", path)
        return None
    out = _cache_dir() / f"{path.stem}-{key}.exr"
    write_exr(out, conv.of_srgb_image(img))
    _CACHE[key] = out
    return out


def to_sensor_reflectance(xml_path: Path, root: ET.Element, lighting: LightingCondition, pixel: PixelResponse) -> None:
    """Replace, in place, every reflectance or transmittance colour of a parsed scene (RGB values
    and bitmap textures) by its sensor reflectance under the lighting's spectrum mix."""
    conv = SensorReflectance(light_weight(spectrum_mix(lighting), pixel.electrons_per_joule()))
    for el in root.iter():
        if not _COLOUR_NAME.search(el.get("name", "")):
            continue
        if el.tag == "rgb":
            try:
                vals = [float(x) for x in re.split(r"[,\s]+", el.get("value", "").strip()) if x]
            except ValueError:
                raise SceneError(xml_path, f"<rgb name={el.get('name')!r}> has a non-numeric value "
                                           f"{el.get('value')!r}") from None
            if len(vals) == 1:
                vals *= 3
            if len(vals) != 3:
                raise SceneError(xml_path, f"<rgb name={el.get('name')!r}> needs 1 or 3 values, got {el.get('value')!r}")
            rho = float(conv.of_linear_rgb(np.array(vals)))
            el.tag = "spectrum"
            el.attrib = {"name": el.get("name"), "value": f"{rho:.6g}"}
        elif el.tag == "texture" and el.get("type") == "bitmap":
            raw = any(c.tag == "boolean" and c.get("name") == "raw" and c.get("value") == "true" for c in el)
            fn = next((c for c in el if c.tag == "string" and c.get("name") == "filename"), None)
            if raw or fn is None:
                continue
            out = _sensor_texture(Path(fn.get("value")), conv)
            if out is not None:
                fn.set("value", str(out))


__all__ = ["to_sensor_reflectance", "spectrum_mix"]
