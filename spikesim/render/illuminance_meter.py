"""The illuminance at the subject as a light meter reads it: direct and indirect light, occlusion
included.

The analytic figure of a lighting condition (`LightingCondition.subject_illuminance_lux`) sums each
emitter's inverse-square or form-factor illuminance and ignores occlusion and inter-reflection. That
is exact for a lamp over an open surface and wrong for a surface lit only by bounced light (a
sphere's front under a ceiling lamp reads 0 lx while its picture saturates). Here the scene itself
is rendered at the subject:

- a tiny white Lambertian disk (reflectance 1, radius and offset `MeterGeometry`) lies on the
  subject, facing its normal; a `radiancemeter` looks at it along the normal. A Lambertian surface
  of reflectance rho under illuminance E has radiance L = rho E / pi, so E = pi L (the same relation
  the exposure chain uses, docs/design.md section 4). Unlike Mitsuba's `irradiancemeter`, which only
  counts light its rays hit and so misses point, spot and directional lamps (delta lights), the
  disk is lit by next-event estimation like any surface: every emitter type counts.
- the scene loads in Mitsuba's mono variant with a photometer's response in place of the pixel's
  (`PhotopicResponse`: K_m V(lambda), CIE 1924), so emitters are in lumens and the meter reads lux.
  Colours become their luminance reflectance under the lighting's spectra (mono.py), which is how a
  mono renderer carries inter-reflections: exact for grey surfaces, an approximation for coloured
  ones.
- the subject must lie on a surface, as the view centre does (the point the camera's central ray
  hits). A light file's subject is a nominal point, where its powers are stated (the LLR files put
  theirs on the road under the car, 4 mm inside a table top, 17 mm inside the fan's hub), so the
  meter is not used there (SceneRenderer.subject_illuminance).
- it is rendered twice: with the scene's integrator (total) and with a path tracer of depth 2
  (direct light only, occlusion included). Each is the mean of `repeats` independent renders; the
  standard error is their spread / sqrt(repeats).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import spectra
from .backend import mi, use_variant, variant_name
from .exposure import PixelResponse
from .lights import LightingCondition

#: Sensor id of the meter inside the metering scene.
METER_ID = "subject_illuminance_meter"


@dataclass(frozen=True)
class PhotopicResponse(PixelResponse):
    """A photometer in place of the silicon pixel: its spectral weight is K_m V(lambda) (lm/W), so
    a light of 1 lm yields 1 unit per second and a rendered irradiance is in lux."""

    def electrons_per_joule(self) -> np.ndarray:
        return spectra.K_M * spectra.photopic_v()


@dataclass(frozen=True)
class MeteredIlluminance:
    """The illuminance (lx) on the subject's surface, metered in the scene (module docstring)."""

    total_lux: float
    """Direct and indirect light, as the scene's integrator carries it."""
    total_se_lux: float
    direct_lux: float
    """Light straight from the emitters, occlusion included (a path of depth 2)."""
    direct_se_lux: float
    samples: int
    """Meter samples per figure (repeats x samples per render)."""

    def describe(self) -> dict[str, Any]:
        return {"total_illuminance_lux": self.total_lux, "total_illuminance_se_lux": self.total_se_lux,
                "metered_direct_illuminance_lux": self.direct_lux, "metered_direct_illuminance_se_lux": self.direct_se_lux,
                "meter_samples": self.samples,
                "meter": "a white Lambertian disk on the subject read by a radiancemeter, E = pi L, photopic "
                         "(spikesim.render.illuminance_meter)"}


@dataclass(frozen=True)
class MeterGeometry:
    """Where the meter sits, relative to the scene's scale at the subject."""

    relative_size: float = 2e-4
    """Disk radius and its height above the surface, times (1 + the largest coordinate of the
    subject): above Mitsuba's ray offset (about 9e-5 times the same scale), so the disk is not
    shadowed by the surface it lies on, and small enough to change no distance measurably."""

    def size(self, at: np.ndarray) -> float:
        return self.relative_size * (1.0 + float(np.max(np.abs(at))))


def _vec(v: Any) -> str:
    return ", ".join(f"{float(x):.9g}" for x in v)


def _meter_elements(at: np.ndarray, normal: np.ndarray, size: float, samples: int) -> list[ET.Element]:
    """The disk (one-sided, white, facing `normal`) and the radiancemeter looking at its centre."""
    centre = at + size * normal
    up = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    disk = ET.Element("shape", type="disk", id=METER_ID + "_disk")
    tf = ET.SubElement(disk, "transform", name="to_world")
    ET.SubElement(tf, "scale", value=f"{size:.9g}")
    # lookat maps +z (the disk's normal) to target - origin
    ET.SubElement(tf, "lookat", origin=_vec(centre), target=_vec(centre + normal), up=_vec(up))
    bsdf = ET.SubElement(disk, "bsdf", type="diffuse")
    ET.SubElement(bsdf, "spectrum", name="reflectance", value="1")
    sensor = ET.Element("sensor", type="radiancemeter", id=METER_ID)
    ET.SubElement(sensor, "point", name="origin", value=_vec(centre + 10.0 * size * normal))
    ET.SubElement(sensor, "vector", name="direction", value=_vec(-normal))
    film = ET.SubElement(sensor, "film", type="hdrfilm")
    ET.SubElement(film, "integer", name="width", value="1")
    ET.SubElement(film, "integer", name="height", value="1")
    ET.SubElement(film, "string", name="pixel_format", value="luminance")
    ET.SubElement(film, "rfilter", type="box")
    sampler = ET.SubElement(sensor, "sampler", type="independent")
    ET.SubElement(sampler, "integer", name="sample_count", value=str(samples))
    return [disk, sensor]


def _direct_only(root: ET.Element) -> ET.Element:
    """The scene with its integrator replaced by a path tracer of depth 2 (emitter to surface)."""
    out = ET.fromstring(ET.tostring(root))
    for el in [el for el in out if el.tag == "integrator"]:
        out.remove(el)
    integ = ET.Element("integrator", type="path")
    ET.SubElement(integ, "integer", name="max_depth", value="2")
    out.insert(0, integ)
    return out


def _read(root: ET.Element, samples: int, repeats: int, seed: int) -> tuple[float, float]:
    """Mean and standard error of pi L over `repeats` renders (lux)."""
    scene = mi.load_string(ET.tostring(root, encoding="unicode"), optimize=False)
    index = next(i for i, s in enumerate(scene.sensors()) if s.id() == METER_ID)
    vals = np.array([math.pi * float(np.asarray(mi.render(scene, sensor=index, spp=samples, seed=seed + k)).ravel()[0])
                     for k in range(repeats)])
    se = float(vals.std(ddof=1) / math.sqrt(repeats)) if repeats > 1 else float("nan")
    return float(vals.mean()), se


def meter_illuminance(xml_path: Path, lighting: LightingCondition, at: Any, normal: Any, *, device: str = "llvm",
                      samples: int = 1024, repeats: int = 4, seed: int = 0,
                      geometry: MeterGeometry = MeterGeometry()) -> MeteredIlluminance:
    """The illuminance on a surface at `at` facing `normal` in the scene `xml_path` under
    `lighting`, metered (module docstring). Leaves Mitsuba's variant as it found it."""
    from .scene import prepare_xml  # scene.py's loader; imported here, as scene.py does not need the meter

    if samples < 1 or repeats < 1:
        raise ValueError(f"samples={samples}, repeats={repeats}: the meter needs at least one of each")
    p = np.asarray(at, dtype=np.float64).reshape(3)
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n)) and np.linalg.norm(n) > 0):
        raise ValueError(f"the subject needs a finite point and a non-zero normal, got {list(p)} and {list(n)}")
    n = n / np.linalg.norm(n)
    before = mi.variant()
    use_variant(variant_name("mono", device))
    try:
        text, _, _ = prepare_xml(Path(xml_path), "mono", lighting, PhotopicResponse(), resolution=(1, 1))
        root = ET.fromstring(text)
        root.extend(_meter_elements(p, n, geometry.size(p), samples))
        total, total_se = _read(root, samples, repeats, seed)
        direct, direct_se = _read(_direct_only(root), samples, repeats, seed + repeats)
    finally:
        if before is not None:
            use_variant(before)
    return MeteredIlluminance(total, total_se, direct, direct_se, samples * repeats)


__all__ = ["meter_illuminance", "MeteredIlluminance", "MeterGeometry", "PhotopicResponse", "METER_ID"]
