"""Checks that a scene can light the sensor at all, made before anything is written, as the
emitters are checked (scene_emitters.py): an integrator that returns radiance, a camera whose
parameters are finite and make an image, frames that are finite, and ground truth that is not
black while the lights are on. Without them a NaN field of view or an `aov` integrator rendered
black images that were written as data with exit status 0."""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from .errors import SceneError
from .scene_files import substitute, xml_defaults

#: Mitsuba 3 integrators whose result is the radiance reaching the camera (the C++ plugins and the
#: differentiable Python ones). Not: aov, depth, moment, stokes (other quantities), or
#: volprim_rf_basic (a radiance field of volumetric primitives, not a scene's light).
RADIANCE_INTEGRATORS = ("path", "volpath", "volpathmis", "direct", "ptracer", "prb", "prb_basic", "prbvolpath",
                        "direct_projective", "prb_projective")

BLACK_Y = 1e-9
"""Ground truth whose brightest pixel stays below this y (spikes per step) over every image is
black: a pixel would fire once in 10^9 steps (7 hours at 40 kHz), 10^6 times less often than
from the sensor's own dark current. A scene whose lights are on and that renders this dark sees
nothing lit: its camera, integrator or emitters are wrong."""


def check_integrator(xml_path: Path, root: ET.Element) -> None:
    """A SceneError naming the XML when its integrator does not return radiance."""
    for el in (el for el in root if el.tag == "integrator"):
        kind = el.get("type")
        if kind not in RADIANCE_INTEGRATORS:
            raise SceneError(xml_path, f"<integrator type={kind!r}> does not render the light reaching the camera; "
                                       f"use one that does: {', '.join(RADIANCE_INTEGRATORS)} (or none: path)")


def _float_param(xml_path: Path, sensor: ET.Element, name: str, defaults: dict[str, str]) -> float | None:
    for child in sensor:
        if child.tag == "float" and child.get("name") == name:
            given = child.get("value", "")
            text = substitute(given, defaults)
            if text is None:
                return None  # a parameter given at load time: checked once loaded
            try:
                return float(text)
            except ValueError:
                raise SceneError(xml_path, f"sensor {name} {given!r} is not a number") from None
    return None


def check_sensor_xml(xml_path: Path, root: ET.Element, sensor: ET.Element) -> None:
    """The camera's parameters as written: a finite field of view in (0, 180) degrees, finite
    positive clip distances with near < far."""
    defaults = xml_defaults(root)
    fov = _float_param(xml_path, sensor, "fov", defaults)
    if fov is not None and not (math.isfinite(fov) and 0 < fov < 180):
        raise SceneError(xml_path, f"sensor fov {fov:g} must be a finite angle between 0 and 180 degrees")
    near = _float_param(xml_path, sensor, "near_clip", defaults)
    far = _float_param(xml_path, sensor, "far_clip", defaults)
    for name, value in (("near_clip", near), ("far_clip", far)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise SceneError(xml_path, f"sensor {name} {value:g} must be a finite positive distance")
    if near is not None and far is not None and not near < far:
        raise SceneError(xml_path, f"sensor near_clip {near:g} must be less than far_clip {far:g}")


def check_camera(xml_path: Path, to_world: np.ndarray, x_fov_deg: float) -> None:
    """The camera as Mitsuba loaded it (whatever gave its values: fov, focal_length, a lookat):
    a finite field of view in (0, 180) degrees and a finite, invertible placement."""
    if not (math.isfinite(x_fov_deg) and 0 < x_fov_deg < 180):
        raise SceneError(xml_path, f"the camera's horizontal field of view is {x_fov_deg:g} degrees; it must be "
                                   "finite and between 0 and 180 (check fov or focal_length)")
    m = np.asarray(to_world, dtype=np.float64)
    if not np.all(np.isfinite(m)) or abs(np.linalg.det(m[:3, :3])) < 1e-12:
        raise SceneError(xml_path, "the camera's to_world transform is not finite or not invertible (a lookat whose "
                                   "origin equals its target, or up along the view?)")


def brightest_emitters(emitters: Any, n: int = 3) -> str:
    """The `n` brightest of a lighting's emitters (LightingCondition.describe()["emitters"]) in
    words, e.g. "'lamp' (point, 6.8e+42 cd)": the usual suspects of an infinite frame."""
    rows = [e for e in (emitters or []) if isinstance(e, dict)]
    rows.sort(key=lambda e: -float(e.get("photometric") or 0.0))
    return ", ".join(f"{e.get('id')!r} ({e.get('type')}, {float(e.get('photometric') or 0.0):.3g} "
                     f"{e.get('photometric_unit', '')})".replace(" )", ")") for e in rows[:n])


def non_finite_frame_error(xml_path: Path, what: str, lighting: Any = None) -> SceneError:
    """A SceneError naming the XML and, when `lighting` is given, its brightest emitters, for a
    frame that is not finite (`what` says which and how many pixels)."""
    emitters = ""
    try:
        emitters = brightest_emitters(lighting.describe()["emitters"]) if lighting is not None else ""
    except (AttributeError, KeyError, TypeError, ValueError):
        pass
    suspects = f"; its emitters, brightest first: {emitters}" if emitters else ""
    return SceneError(xml_path, f"{what}; check the camera, the materials and the emitters{suspects}")


def check_frame(xml_path: Path, step: int, y: np.ndarray, lighting: Any = None) -> None:
    """A SceneError naming the XML, the step and the brightest emitters (`lighting`) when a
    rendered frame has non-finite pixels."""
    bad = ~np.isfinite(y)
    if bad.any():
        raise non_finite_frame_error(xml_path, f"step {step} rendered {int(bad.sum())} non-finite pixel(s) (NaN or "
                                               f"infinite) of {y.size}", lighting)


def check_lit(xml_path: Path, max_y: float, images: int, lighting: Any = None) -> None:
    """A SceneError naming the XML when `images` ground-truth images of a lit scene are black
    (their brightest pixel below BLACK_Y)."""
    if images and max_y < BLACK_Y:
        lux = None
        try:
            lux = lighting.subject_illuminance_lux() if lighting is not None else None
        except (AttributeError, ValueError, TypeError):
            lux = None
        lit = f" ({lux:.4g} lx at the subject)" if isinstance(lux, (int, float)) and lux > 0 else ""
        raise SceneError(xml_path, f"its ground truth is black (brightest pixel y = {max_y:.3g} spikes per step "
                                   f"over {images} image(s)) although its lights are on{lit}: the camera sees nothing "
                                   "lit; check the camera, the integrator and the emitters")


__all__ = ["RADIANCE_INTEGRATORS", "BLACK_Y", "check_integrator", "check_sensor_xml", "check_camera", "check_frame",
           "check_lit", "brightest_emitters", "non_finite_frame_error"]
