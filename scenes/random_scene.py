"""Random high-speed scenes for RLLR (paper, "RLLR": random objects, textures, motions, lights).

`build_random_scene(seed, folder)` writes an ordinary scene folder (scene.xml, motion.json,
lights.json, textures/, meshes/) that the renderer loads like the bundled ones, so a random scene
is reproducible from its seed alone and can be inspected or re-rendered by hand.

What is random, and the ranges (chosen to resemble everyday high-speed scenes at 0.5-3 m):
- a textured backdrop and floor (procedural textures: value noise, stripes, checkers, blobs);
- 2-5 objects: Mitsuba's analytic sphere / cube / cylinder with a random texture, or a trimesh
  primitive (torus, capsule, cone, icosahedron, random convex hull) with a random uniform colour;
  diffuse, rough-plastic or rough-conductor material;
- per object a motion: a spin of 300-6000 rpm about a random axis, a translation at 1-25 m/s
  across the view, or both;
- one lighting condition "normal": 1-2 lamps (rectangle panel, point or spot) with a spectrum
  drawn from CIE A (incandescent), D65 (daylight), FL2 / FL11 (fluorescent), LED-B3 (white LED),
  together giving an illuminance at the subject drawn log-uniformly from LAMPS_LUX (30-250 lx:
  dim to ordinary indoor light, up to the LLR normal lights' 110-250 lx).
RLLR's darkening by a random factor in (0, 1) is applied by the dataset job, not here.

Why 30-250 lx and not brighter: above y = 1 spike per step the sensor saturates, and a ground
truth above it is a target no spike stream can show. Measured over the 100 scenes of
`generate rllr --preset paper` (`python -m pipelines.rllr_lighting`, docs/scenes.md section 10):
with 100-1000 lx, 1.3 % of all ground-truth pixels were saturated and 13 scenes had more than 1 %
(one 51 %); with 30-250 lx, 0.02 % and none above 1 %, while 20 % of the scenes (darkened) lie at
or below the LLR low lights' 3.5-10 lx. The bright end is set by the brightest scenes: a bright
surface facing a lamp reaches y = 1 near 250-300 lx at the subject.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

SPECTRA = ("A", "D65", "FL2", "FL11", "LED-B3")
LAMPS_LUX = (30.0, 250.0)
"""Range of the lamps' illuminance at the subject, before RLLR's darkening (log-uniform)."""
LAMPS_LUX_BEFORE_STUDY = (100.0, 1000.0)
"""The range before the saturation study: jobs planned without a range still build with it, so
a scene folder stays reproducible from its recorded job."""
_TEXTURE_SIZE = 256
GENERATOR_VERSION = 1
"""The version of this generator, part of every random scene's identity (spikesim.generation.inputs):
a scene is its seed, its lamps' range and this. Raise it with any change that builds another scene
from the same seed (a new object kind, another draw order), so that datasets built before are
rebuilt rather than mixed with the new scenes."""


def _texture(rng: np.random.Generator, path: Path) -> None:
    """A random procedural texture, saved as an 8-bit PNG (sRGB-encoded, as Mitsuba expects)."""
    from PIL import Image

    n = _TEXTURE_SIZE
    yy, xx = np.mgrid[0:n, 0:n] / n
    kind = rng.integers(4)
    if kind == 0:  # value noise: a few octaves of bilinearly upsampled random grids
        img = np.zeros((n, n))
        for octave in range(4):
            g = 2 ** (octave + 2)
            grid = rng.random((g + 1, g + 1))
            gx, gy = xx * g, yy * g
            x0, y0 = gx.astype(int), gy.astype(int)
            fx, fy = gx - x0, gy - y0
            v = (grid[y0, x0] * (1 - fx) * (1 - fy) + grid[y0, x0 + 1] * fx * (1 - fy)
                 + grid[y0 + 1, x0] * (1 - fx) * fy + grid[y0 + 1, x0 + 1] * fx * fy)
            img += v / 2 ** octave
        img /= img.max()
    elif kind == 1:  # stripes at a random angle and frequency
        a = rng.uniform(0, math.pi)
        f = rng.uniform(3, 20)
        img = 0.5 + 0.5 * np.sign(np.sin(2 * math.pi * f * (xx * math.cos(a) + yy * math.sin(a))))
    elif kind == 2:  # checkers
        f = int(rng.integers(2, 12))
        img = ((np.floor(xx * f) + np.floor(yy * f)) % 2).astype(float)
    else:  # random discs
        img = np.full((n, n), rng.uniform(0.1, 0.4))
        for _ in range(int(rng.integers(5, 30))):
            cx, cy, r = rng.random(), rng.random(), rng.uniform(0.02, 0.15)
            img[(xx - cx) ** 2 + (yy - cy) ** 2 < r * r] = rng.uniform(0.2, 1.0)
    lo, hi = sorted(rng.uniform(0.03, 0.9, 2))
    tint = rng.uniform(0.6, 1.0, 3)
    rgb = (lo + (hi - lo) * img)[..., None] * tint
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * rgb ** (1 / 2.4) - 0.055)
    Image.fromarray(np.round(np.clip(srgb, 0, 1) * 255).astype(np.uint8)).save(path)


def _material(rng: np.random.Generator, reflectance_xml: str) -> str:
    kind = rng.choice(["diffuse", "diffuse", "plastic", "conductor"])
    if kind == "diffuse":
        return f'<bsdf type="diffuse">{reflectance_xml}</bsdf>'
    if kind == "plastic":
        return (f'<bsdf type="roughplastic"><float name="alpha" value="{rng.uniform(0.05, 0.4):.3f}"/>'
                f'{reflectance_xml.replace("reflectance", "diffuse_reflectance")}</bsdf>')
    return (f'<bsdf type="roughconductor"><string name="material" value="{rng.choice(["Al", "Cu", "Au"])}"/>'
            f'<float name="alpha" value="{rng.uniform(0.1, 0.5):.3f}"/></bsdf>')


def _trimesh_object(rng: np.random.Generator, size: float):
    import trimesh

    kind = rng.integers(5)
    if kind == 0:
        return trimesh.creation.torus(major_radius=size, minor_radius=size * rng.uniform(0.15, 0.4))
    if kind == 1:
        return trimesh.creation.capsule(height=size * rng.uniform(0.8, 2.0), radius=size * 0.4)
    if kind == 2:
        return trimesh.creation.cone(radius=size, height=size * rng.uniform(1.0, 2.5))
    if kind == 3:
        return trimesh.creation.icosahedron().apply_scale(size)
    pts = rng.normal(size=(30, 3)) * size * np.array([1.0, rng.uniform(0.4, 1.0), rng.uniform(0.4, 1.0)])
    return trimesh.convex.convex_hull(pts)


def build_random_scene(seed: int, folder: str | Path, resolution: tuple[int, int] = (250, 400),
                       lamps_lux: tuple[float, float] = LAMPS_LUX) -> tuple[Path, Path, Path, str]:
    """Write a random scene into `folder`; returns (xml, motion, lights, light name). The lamps'
    illuminance at the subject is drawn log-uniformly from `lamps_lux` with one random draw, so
    the range changes the level and nothing else of the scene."""
    rng, folder, lo_lux, hi_lux = scene_start(seed, folder, lamps_lux, 1234)
    h, w = resolution
    # Camera 2.5 m in front of a backdrop, looking along +y; z is up (as the bundled scenes).
    eye = np.array([0.0, -2.5, 1.0])
    target = np.array([0.0, 0.0, 1.0])
    fov = float(rng.uniform(35, 50))
    shapes = []
    _texture(rng, folder / "textures" / "backdrop.png")
    _texture(rng, folder / "textures" / "floor.png")
    shapes.append(f'''<shape type="rectangle" id="backdrop"><transform name="to_world"><scale x="4" y="2.5"/>
        <rotate x="1" angle="90"/><translate x="0" y="{rng.uniform(0.8, 1.6):.3f}" z="1.2"/></transform>
        <bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="textures/backdrop.png"/>
        </texture></bsdf></shape>''')
    shapes.append('''<shape type="rectangle" id="floor"><transform name="to_world"><scale x="4" y="3"/>
        <translate x="0" y="0" z="0"/></transform>
        <bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="textures/floor.png"/>
        </texture></bsdf></shape>''')
    objects = []
    n_obj = int(rng.integers(2, 6))
    for i in range(n_obj):
        oid = f"object{i}"
        size = float(rng.uniform(0.08, 0.3))
        center = np.array([rng.uniform(-0.9, 0.9), rng.uniform(-0.6, 0.5), rng.uniform(0.5, 1.6)])
        if rng.random() < 0.5:
            kind = rng.choice(["sphere", "cube", "cylinder"])
            tex = f"textures/{oid}.png"
            _texture(rng, folder / tex)
            refl = f'<texture type="bitmap" name="reflectance"><string name="filename" value="{tex}"/></texture>'
            shapes.append(solid_xml(str(kind), oid, size, center, _material(rng, refl)))
        else:
            shapes.append(mesh_xml(rng, oid, size, center, folder, 0.05))
        motions = []
        if rng.random() < 0.7:
            axis = rng.normal(size=3)
            motions.append({"type": "rotation", "axis": (axis / np.linalg.norm(axis)).round(4).tolist(),
                            "rpm": float(rng.uniform(300, 6000)) * float(rng.choice([-1, 1])),
                            "center": center.round(4).tolist()})
        if not motions or rng.random() < 0.6:
            d = np.array([rng.normal(), rng.normal() * 0.3, rng.normal() * 0.5])
            motions.append({"type": "translation", "direction": (d / np.linalg.norm(d)).round(4).tolist(),
                            "speed_mps": float(rng.uniform(1.0, 25.0))})
        objects.append({"targets": [oid], "motions": motions})
    xml = scene_xml(f"RLLR random scene, seed {seed}: built by scenes/random_scene.py; lights in lights.json.", fov,
                    f"{eye[0]}, {eye[1]}, {eye[2]}", f"{target[0]}, {target[1]}, {target[2]}", w, h, shapes)
    (folder / "scene.xml").write_text(xml)
    (folder / "motion.json").write_text(json.dumps({"version": 1, "description": f"random motions, seed {seed}",
                                                    "start_time_s": 0.0, "objects": objects}, indent=1))
    lights = random_lamps(rng, lo_lux, hi_lux)
    (folder / "lights.json").write_text(json.dumps(lights, indent=1))
    return folder / "scene.xml", folder / "motion.json", folder / "lights.json", "normal"


def solid_xml(kind: str, oid: str, size: float, center: np.ndarray, material: str) -> str:
    """A Mitsuba sphere, cube or cylinder (a cylinder stands 2 size tall, its base size below the
    centre) of half-size `size` at `center`, with `material`."""
    if kind == "cylinder":
        xform = (f'<scale x="{size:.4f}" y="{size:.4f}" z="{2 * size:.4f}"/>'
                 f'<translate x="{center[0]:.4f}" y="{center[1]:.4f}" z="{center[2] - size:.4f}"/>')
    else:
        xform = f'<scale value="{size:.4f}"/><translate x="{center[0]:.4f}" y="{center[1]:.4f}" z="{center[2]:.4f}"/>'
    return f'<shape type="{kind}" id="{oid}"><transform name="to_world">{xform}</transform>{material}</shape>'


def mesh_xml(rng: np.random.Generator, oid: str, size: float, center: np.ndarray, folder: Path,
             darkest: float) -> str:
    """A random trimesh primitive at `center`, written to meshes/<oid>.ply, with a uniform colour
    (each channel U(darkest, 0.9)) and a random material."""
    mesh = _trimesh_object(rng, size)
    mesh.apply_translation(center - mesh.centroid)
    mesh.export(folder / "meshes" / f"{oid}.ply")
    rgb = ", ".join(f"{c:.3f}" for c in rng.uniform(darkest, 0.9, 3))
    material = _material(rng, f'<rgb name="reflectance" value="{rgb}"/>')
    return (f'<shape type="ply" id="{oid}"><string name="filename" value="meshes/{oid}.ply"/>'
            f'<boolean name="face_normals" value="true"/>{material}</shape>')


def scene_start(seed: int, folder: str | Path, lamps_lux: tuple[float, float],
                stream: int) -> tuple[np.random.Generator, Path, float, float]:
    """What every random-scene builder starts with: the lamps' range checked, the scene's random
    generator (the seed and the builder's own `stream` key), and its folder with textures/ and
    meshes/ made."""
    lo_lux, hi_lux = (float(v) for v in lamps_lux)
    if not 0 < lo_lux <= hi_lux:
        raise ValueError(f"lamps_lux={lamps_lux!r}: expected 0 < low <= high (lux)")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), stream]))
    folder = Path(folder)
    (folder / "textures").mkdir(parents=True, exist_ok=True)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    return rng, folder, lo_lux, hi_lux


def scene_xml(comment: str, fov_deg: float, origin: str, target: str, width: int, height: int,
              shapes: list[str]) -> str:
    """A random scene's XML: a path tracer of depth 3, a perspective camera (`origin` and `target`
    as the callers format them, so each builder's scenes keep their bytes), a box-filtered film,
    and the shapes."""
    return f'''<?xml version="1.0" encoding="utf-8"?>
<!-- {comment} -->
<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective" id="camera">
        <float name="fov" value="{fov_deg:.2f}"/><string name="fov_axis" value="x"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/><rfilter type="box"/></film>
    </sensor>
    {chr(10).join("    " + s for s in shapes)}
</scene>
'''


def random_lamps(rng: np.random.Generator, lo_lux: float, hi_lux: float,
                 subject: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> dict:
    """The lights file of a random scene: 1-2 lamps (rectangle panel, point or spot) of random
    spectra (SPECTRA), together giving an illuminance at `subject` drawn log-uniformly from
    [lo_lux, hi_lux] with one draw."""
    subject = [float(v) for v in subject]
    lux = float(np.exp(rng.uniform(np.log(lo_lux), np.log(hi_lux))))
    n_lamps = int(rng.integers(1, 3))
    emitters = []
    for k in range(n_lamps):
        spectrum = str(rng.choice(SPECTRA))
        pos = [float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-2.5, -0.5)), float(rng.uniform(2.0, 3.5))]
        kind = rng.choice(["rectangle", "point", "spot"])
        e = {"id": f"lamp{k}", "type": str(kind), "spectrum": spectrum, "position": pos,
             "power": {"illuminance_lux": lux / n_lamps, "at": subject, "normal": [0, -1, 0]}}
        if kind in ("rectangle", "spot"):
            e["target"] = subject
        if kind == "rectangle":
            e["size"] = [float(rng.uniform(0.3, 1.2)), float(rng.uniform(0.3, 0.8))]
        if kind == "spot":
            e["cutoff_deg"] = 45.0
            e["beam_deg"] = 35.0
        emitters.append(e)
    lights = {"normal": {"description": f"{n_lamps} random lamp(s), {lux:.0f} lx at the subject",
                         "reference": f"log-uniform {lo_lux:g}-{hi_lux:g} lx at the subject (dim to ordinary indoor "
                                      "light, kept below the sensor's saturation: scenes/random_scene.py)",
                         "subject": {"at": subject, "normal": [0, -1, 0]}, "emitters": emitters}}
    return lights


__all__ = ["build_random_scene", "random_lamps", "scene_start", "scene_xml", "SPECTRA", "LAMPS_LUX", "LAMPS_LUX_BEFORE_STUDY", "GENERATOR_VERSION"]
