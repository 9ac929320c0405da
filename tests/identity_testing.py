"""A tiny user scene (XML, lights.json, motion.json and a texture) for the tests of generation's
inputs and checks: 8 x 12 pixels, one 41-step window, one sample per pixel."""
from __future__ import annotations

import json
from pathlib import Path

SUN_LUX = 100

SCENE_XML = """<scene version="3.0.0">
  <integrator type="{integrator}"/>
  <sensor type="perspective" id="camera">
    <float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/></film>
  </sensor>
  <shape type="rectangle" id="floor">
    <bsdf type="diffuse"><texture type="bitmap" name="reflectance">
      <string name="filename" value="textures/floor.png"/></texture></bsdf>
  </shape>
</scene>
"""


def make_user_scene(folder: Path, integrator: str = "direct", fov: str = "30", spp: str = "1", width: str = "12",
                    height: str = "8") -> Path:
    """Write the scene into `folder`; returns its XML."""
    from PIL import Image
    import numpy as np

    folder = Path(folder)
    (folder / "textures").mkdir(parents=True, exist_ok=True)
    (folder / "scene.xml").write_text(SCENE_XML.format(integrator=integrator, fov=fov, spp=spp, width=width,
                                                       height=height))
    sun = {"id": "sun", "type": "directional", "spectrum": "D65", "direction": [0, 0, -1],
           "power": {"illuminance_lux": SUN_LUX}}
    (folder / "lights.json").write_text(json.dumps({"normal": {"emitters": [sun]}}))
    motion = {"version": 1, "objects": [{"targets": ["floor"], "motions": [
        {"type": "rotation", "axis": [0, 0, 1], "rpm": 1300, "center": [0, 0, 0]}]}]}
    (folder / "motion.json").write_text(json.dumps(motion))
    grey = (np.arange(16, dtype=np.uint8).reshape(4, 4) * 8 + 64)
    Image.fromarray(grey).save(folder / "textures" / "floor.png")
    return folder / "scene.xml"


def tiny_preset():
    from spikesim.generation import PRESETS
    return PRESETS["small"].replace(height=8, width=12, llr_windows=1, spp=1, gt_spp=1)
