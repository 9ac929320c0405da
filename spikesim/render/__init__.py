"""Rendering: physically lit, moving Mitsuba 3 scenes turned into y (expected spikes per step).

Stages, one module each: `lights` (spectra and photometric power -> emitters), `scene_emitters`
(a Mitsuba scene's own emitters, in its radiometric units -> the same), `exposure`
(radiance -> electrons -> y), `motion` (motion files), `animate` (motion -> scene parameters),
`scene` (XML preparation and loading), `reflectance` (colours as the sensor sees them, for the
mono path), `renderer` (SceneRenderer: frames and ground truth), `ground_truth` (EXR + PNG files),
`benchmark` (the measurements in docs/scenes.md).
Importing this package does not import Mitsuba until a renderer is created.
"""
from __future__ import annotations

from typing import Any

from .errors import LightError, MotionError, SceneError
from .exposure import Exposure, Optics, PixelResponse
from .motion import MotionSpec, load_motion, parse_motion

__all__ = ["SceneRenderer", "RenderSettings", "write_ground_truth", "SceneError", "MotionError", "LightError", "Exposure", "Optics",
           "PixelResponse", "MotionSpec", "load_motion", "parse_motion", "load_lights"]


def __getattr__(name: str) -> Any:
    # Mitsuba is heavy to import: load it only when a renderer or the light loader is asked for.
    if name in ("SceneRenderer", "RenderSettings"):
        from . import renderer
        return getattr(renderer, name)
    if name == "write_ground_truth":
        from .ground_truth import write_ground_truth
        return write_ground_truth
    if name == "load_lights":
        from .lights import load_lights
        return load_lights
    raise AttributeError(name)
