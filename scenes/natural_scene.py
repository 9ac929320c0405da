"""RLLR's `natural` content: random high-speed scenes whose surfaces carry natural image statistics.

The `procedural` content (scenes/random_scene.py) textures everything with value noise, stripes,
checkers and discs and lights it at 30-250 lx: a network trained on it smooths a real camera's
texture and draws level with a window average on other simulators' REDS content (docs/model.md).
This builder keeps the same scene format and lamps, and changes what the network learns from:

- surfaces: dead-leaves textures (grey and colour, textured leaves) and crops of the photographs
  and textures bundled in scikit-image's wheel (scenes/natural_textures.py), their licences
  recorded in the scene's `content.json`;
- objects: image-textured cards (photographs on thin panels), textured spheres, cubes and
  cylinders, and a few uniform meshes; each still, spinning (30-6000 rpm) or crossing the view
  (0.2-20 m/s), drawn log-uniformly so slow motions are as common per decade as fast ones;
- the camera: still, panning or shaking, at an image speed drawn log-uniformly in
  CAMERA_PX_PER_STEP (REDS-like to faster), and at a distance and field of view that vary the
  pixel scale of everything (with the dataset's resolution scales, spikesim.generation.plan);
- lamps: the same random lamps over NATURAL_LAMPS_LUX, before RLLR's darkening.

A scene is its seed, its lamps' range, NATURAL_GENERATOR_VERSION and the installed scikit-image's
version (its pictures).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from scenes.natural_textures import dead_leaves, package_photo, save_srgb
from scenes.random_scene import _material, mesh_xml, random_lamps, scene_start, scene_xml, solid_xml

#: Lamps' illuminance at the subject before darkening (log-uniform). With the log-uniform
#: darkening down to 0.005 this spans 0.1-1000 lx at the subject: from the darkest LLR light to
#: past the saturation of bright surfaces (y = 1 near 250-300 lx), whose targets training clips
#: at the sensor's saturation (model/data.py).
NATURAL_LAMPS_LUX = (20.0, 1000.0)
#: The camera's image speed when it moves, pixels per 25 us step at the frame's centre, drawn
#: log-uniformly: from barely moving to faster than REDS content.
CAMERA_PX_PER_STEP = (0.02, 1.5)
NATURAL_GENERATOR_VERSION = 1
"""Raise with any change that builds another scene from the same seed (as GENERATOR_VERSION)."""

_BACKDROP_TEXTURE = 512
_OBJECT_TEXTURE = 256


def _surface(rng: np.random.Generator, folder: Path, name: str, size: int, records: list[dict],
             photo_share: float = 0.5) -> str:
    """Write one texture (dead leaves or a package photo) and return its path in the scene."""
    rel = f"textures/{name}.png"
    if rng.random() < photo_share:
        img, rec = package_photo(rng, size)
        rec = {"kind": "photo", **rec}
    else:
        colour = bool(rng.random() < 0.7)
        img = dead_leaves(rng, size, colour=colour)
        rec = {"kind": "dead-leaves", "colour": colour, "licence": "generated from the scene's seed"}
    img = img * rng.uniform(0.5, 1.0)  # surfaces are not all white paper
    save_srgb(img, folder / rel)
    records.append({"file": rel, **rec})
    return rel


def _bitmap(rel: str, tile: tuple[float, float] = (1.0, 1.0)) -> str:
    uv = (f'<transform name="to_uv"><scale x="{tile[0]:g}" y="{tile[1]:g}"/></transform>'
          if tile != (1.0, 1.0) else "")
    return (f'<texture type="bitmap" name="reflectance"><string name="filename" value="{rel}"/>'
            f'<string name="wrap_mode" value="mirror"/>{uv}</texture>')


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _camera_motion(rng: np.random.Generator, eye: np.ndarray, fov_deg: float, width: int,
                   readout_period_s: float) -> tuple[dict | None, dict]:
    """The camera's motion entry (None: still) and its record: kind and image speed (px/step)."""
    px_per_rad = width / (2 * math.tan(math.radians(fov_deg) / 2))  # at the frame's centre
    speed = _log_uniform(rng, *CAMERA_PX_PER_STEP)
    omega = speed / (px_per_rad * readout_period_s)  # rad/s
    kind = str(rng.choice(["still", "pan", "shake"], p=[0.4, 0.35, 0.25]))
    if kind == "still":
        return None, {"kind": "still", "px_per_step": 0.0}
    if kind == "pan":
        axis = [0.0, 0.0, 1.0] if rng.random() < 0.75 else [1.0, 0.0, 0.0]  # pan or tilt
        rpm = omega * 60 / (2 * math.pi) * float(rng.choice([-1, 1]))
        return ({"targets": ["camera"], "motions": [{"type": "rotation", "axis": axis, "rpm": rpm,
                                                   "center": eye.round(4).tolist()}]},
                {"kind": "pan", "px_per_step": speed, "rpm": rpm})
    # Shake: random small turns about axes across the view, a key every 1 ms, cubic between keys,
    # each key's turn sized so the mean image speed is about `speed`.
    dt = 1e-3
    keys = []
    for k in range(32):
        turn = math.degrees(omega * dt) * rng.uniform(0.5, 1.5) * (k > 0)
        a = rng.normal(size=3) * np.array([1.0, 0.2, 1.0])
        keys.append({"t": k * dt, "rotate_axis": (a / np.linalg.norm(a)).round(4).tolist(),
                     "rotate_deg": round(float(turn), 5)})
    return ({"targets": ["camera"], "motions": [{"type": "keyframes", "interpolation": "catmull_rom",
                                               "pivot": eye.round(4).tolist(), "keys": keys}]},
            {"kind": "shake", "px_per_step": speed})


def build_natural_scene(seed: int, folder: str | Path, resolution: tuple[int, int] = (250, 400),
                        lamps_lux: tuple[float, float] = NATURAL_LAMPS_LUX,
                        readout_period_s: float = 25e-6) -> tuple[Path, Path, Path, str]:
    """Write a natural random scene into `folder` (module docstring); returns (xml, motion,
    lights, light name), as scenes.random_scene.build_random_scene."""
    rng, folder, lo_lux, hi_lux = scene_start(seed, folder, lamps_lux, 4321)
    h, w = resolution
    distance = float(rng.uniform(1.5, 4.0))
    eye = np.array([0.0, -distance, 1.0])
    fov = float(rng.uniform(25, 70))
    textures: list[dict] = []
    shapes = []
    # Backdrop wide enough for a pan of the whole stream: three views across, texture tiled.
    back_y = float(rng.uniform(0.6, 2.5))
    half = (distance + back_y) * math.tan(math.radians(fov) / 2)
    rel = _surface(rng, folder, "backdrop", _BACKDROP_TEXTURE, textures, photo_share=0.6)
    shapes.append(f'''<shape type="rectangle" id="backdrop"><transform name="to_world"><scale x="{3.5 * half:.3f}" y="{3.5 * half:.3f}"/>
        <rotate x="1" angle="90"/><translate x="0" y="{back_y:.3f}" z="1.0"/></transform>
        <bsdf type="diffuse">{_bitmap(rel, (3.0, 3.0))}</bsdf></shape>''')
    rel = _surface(rng, folder, "floor", _BACKDROP_TEXTURE, textures, photo_share=0.4)
    shapes.append(f'''<shape type="rectangle" id="floor"><transform name="to_world"><scale x="{3.5 * half:.3f}" y="{distance + back_y:.3f}"/>
        <translate x="0" y="0" z="0"/></transform>
        <bsdf type="diffuse">{_bitmap(rel, (4.0, 4.0))}</bsdf></shape>''')
    objects = []
    for i in range(int(rng.integers(2, 7))):
        oid = f"object{i}"
        size = float(rng.uniform(0.06, 0.45))
        depth = float(rng.uniform(-distance + 0.6, back_y - 0.2))  # between the camera and the backdrop
        reach = (distance + depth) * math.tan(math.radians(fov) / 2)
        center = np.array([rng.uniform(-reach, reach) * 0.8, depth, rng.uniform(0.3, 1.7)])
        kind = str(rng.choice(["card", "solid", "mesh"], p=[0.4, 0.45, 0.15]))
        if kind == "card":  # a photograph or dead-leaves print on a panel facing the camera, tilted
            rel = _surface(rng, folder, oid, _OBJECT_TEXTURE, textures, photo_share=0.7)
            aspect = float(rng.uniform(0.6, 1.6))
            tilt = rng.uniform(-35, 35, 2)
            shapes.append(
                f'<shape type="rectangle" id="{oid}"><transform name="to_world">'
                f'<scale x="{size * aspect:.4f}" y="{size:.4f}"/><rotate x="1" angle="{90 + tilt[0]:.2f}"/>'
                f'<rotate z="1" angle="{tilt[1]:.2f}"/>'
                f'<translate x="{center[0]:.4f}" y="{center[1]:.4f}" z="{center[2]:.4f}"/></transform>'
                f'{_material(rng, _bitmap(rel))}</shape>')
        elif kind == "solid":
            solid = str(rng.choice(["sphere", "cube", "cylinder"]))
            rel = _surface(rng, folder, oid, _OBJECT_TEXTURE, textures, photo_share=0.5)
            shapes.append(solid_xml(solid, oid, size, center, _material(rng, _bitmap(rel))))
        else:
            shapes.append(mesh_xml(rng, oid, size, center, folder, 0.03))
        motions = []
        if rng.random() < 0.9:  # else still
            if rng.random() < 0.6:
                axis = rng.normal(size=3)
                motions.append({"type": "rotation", "axis": (axis / np.linalg.norm(axis)).round(4).tolist(),
                                "rpm": _log_uniform(rng, 30.0, 6000.0) * float(rng.choice([-1, 1])),
                                "center": center.round(4).tolist()})
            if not motions or rng.random() < 0.6:
                d = np.array([rng.normal(), rng.normal() * 0.3, rng.normal() * 0.5])
                motions.append({"type": "translation", "direction": (d / np.linalg.norm(d)).round(4).tolist(),
                                "speed_mps": _log_uniform(rng, 0.2, 20.0)})
        if motions:
            objects.append({"targets": [oid], "motions": motions})
    camera_motion, camera_record = _camera_motion(rng, eye, fov, w, readout_period_s)
    if camera_motion is not None:
        objects.append(camera_motion)
    xml = scene_xml(f"RLLR natural scene, seed {seed}: built by scenes/natural_scene.py; lights in lights.json,\n"
                    "     texture sources and licences in content.json.", fov,
                    f"{eye[0]}, {eye[1]:.4f}, {eye[2]}", "0, 0, 1", w, h, shapes)
    (folder / "scene.xml").write_text(xml)
    motion = {"version": 1, "description": f"natural random scene, seed {seed}", "start_time_s": 0.0,
              "objects": objects}
    (folder / "motion.json").write_text(json.dumps(motion, indent=1))
    lights = random_lamps(rng, lo_lux, hi_lux)
    lights["normal"]["reference"] = (f"log-uniform {lo_lux:g}-{hi_lux:g} lx at the subject, up to past the "
                                     "saturation of bright surfaces (scenes/natural_scene.py)")
    (folder / "lights.json").write_text(json.dumps(lights, indent=1))
    content = {"generator": "scenes/natural_scene.py", "version": NATURAL_GENERATOR_VERSION, "seed": int(seed),
               "camera": {"fov_deg": fov, "distance_m": distance, "motion": camera_record}, "textures": textures}
    (folder / "content.json").write_text(json.dumps(content, indent=1))
    return folder / "scene.xml", folder / "motion.json", folder / "lights.json", "normal"


__all__ = ["build_natural_scene", "NATURAL_LAMPS_LUX", "NATURAL_GENERATOR_VERSION", "CAMERA_PX_PER_STEP"]
