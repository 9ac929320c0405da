"""Scene snippets shared by the rendering tests (a module of its own, so that test files import
it by a unique name rather than from a conftest)."""
from __future__ import annotations

CAMERA = """
  <sensor type="perspective" id="camera">
    <float name="fov" value="{fov}"/><string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/></film>
  </sensor>"""

#: A large grey Lambertian plane at z = 0 facing +z, seen from straight above.
PLANE = """
  <shape type="rectangle" id="plane"><transform name="to_world"><scale value="50"/></transform>
    <bsdf type="diffuse"><spectrum name="reflectance" value="{reflectance}"/></bsdf></shape>"""

#: A small white sphere (radius 0.1 m) at the origin, for motion tests on a black background.
BALL = """
  <shape type="sphere" id="ball"><transform name="to_world"><scale value="0.1"/></transform>
    <bsdf type="diffuse"><spectrum name="reflectance" value="0.9"/></bsdf></shape>"""

SUN = {"id": "sun", "type": "directional", "spectrum": "D65", "direction": [0, 0, -1],
       "power": {"illuminance_lux": 100}}
