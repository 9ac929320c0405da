"""A scene's own Mitsuba emitters: read in Mitsuba's radiometric units, converted through the
exposure model, overridden by a lights.json, and refused with a clear error where unsupported."""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from render_testing import CAMERA
from spikesim.render import SceneRenderer
from spikesim.render.errors import LightError, SceneError
from spikesim.render.lights import parse_emitter
from spikesim.render.scene_emitters import luminance_to_photometric

PLAIN = Path(__file__).resolve().parents[1] / "data" / "plain_scene" / "scene.xml"
GREY = '<shape type="rectangle" id="floor"><transform name="to_world"><scale value="50"/></transform>' \
       '<bsdf type="diffuse"><spectrum name="reflectance" value="0.5"/></bsdf></shape>'


def _write(tmp_path: Path, body: str, name: str = "scene") -> Path:
    folder = tmp_path / name
    folder.mkdir(parents=True, exist_ok=True)
    xml = folder / "scene.xml"
    xml.write_text(f'<scene version="3.0.0"><integrator type="direct"/>'
                   + CAMERA.format(fov=30, origin="0, 0, 3", target="0, 0, 0", width=40, height=25)
                   + body + "</scene>")
    return xml


def _centre(r: SceneRenderer) -> float:
    y = next(iter(r.frames(0, 1)))
    return float(y[r.height // 2 - 1:r.height // 2 + 1, r.width // 2 - 1:r.width // 2 + 1].mean())


def test_conversion_factor_is_km_times_integral_of_v() -> None:
    # K_m = 683 lm/W and the CIE photopic V integrates to ~106.9 nm over 360-830 nm
    assert luminance_to_photometric() == pytest.approx(683.0 * 106.86, rel=2e-3)


def test_plain_mitsuba_scene_point_light_gives_the_analytic_y() -> None:
    """The docs-style scene: a point lamp of 0.001 W/sr/nm (flat) 1 m above a 0.5 grey floor. Direct
    light from a point source is exact per sample, so y matches E = I / d^2 through the exposure
    model to Monte Carlo-free precision (film footprint aside)."""
    r = SceneRenderer(PLAIN, spp=4)
    assert r.files.lights is None and r.lighting.name == "scene"
    assert (r.height, r.width) == (25, 40)  # the scene's own film
    lux = luminance_to_photometric() * 0.001
    assert r.lighting.subject_illuminance_lux() == pytest.approx(lux, rel=1e-9)
    assert r.describe()["light"]["subject"]["direct_illuminance_lux"] == pytest.approx(lux, rel=1e-9)
    assert _centre(r) == pytest.approx(r.exposure.white_surface_y(lux, "D65", 0.5), rel=0.01)


def test_doubling_the_xml_intensity_doubles_y(tmp_path: Path) -> None:
    ys = []
    for value in ("0.002", "0.004"):
        xml = _write(tmp_path, GREY + f'<emitter type="point"><point name="position" value="0, 0, 1"/>'
                                       f'<spectrum name="intensity" value="{value}"/></emitter>', name=value)
        ys.append(_centre(SceneRenderer(xml, spp=2)))
    assert ys[1] == pytest.approx(2 * ys[0], rel=1e-5)


def test_rgb_value_counts_by_its_luminance(tmp_path: Path) -> None:
    # an rgb intensity is taken at its linear-sRGB luminance: pure green = 0.7152 of white
    white = _write(tmp_path, GREY + '<emitter type="point"><point name="position" value="0, 0, 1"/>'
                                    '<rgb name="intensity" value="0.01, 0.01, 0.01"/></emitter>', name="w")
    green = _write(tmp_path, GREY + '<emitter type="point"><point name="position" value="0, 0, 1"/>'
                                    '<rgb name="intensity" value="0, 0.01, 0"/></emitter>', name="g")
    lw = SceneRenderer(white, spp=1).lighting.subject_illuminance_lux()
    lg = SceneRenderer(green, spp=1).lighting.subject_illuminance_lux()
    assert lg / lw == pytest.approx(0.7152, rel=1e-6)


def test_area_light_on_a_shape_matches_the_rectangle_formula(tmp_path: Path) -> None:
    """A 0.2 m square area lamp off the camera's axis, aimed at the subject: its illuminance by
    emitter sampling equals the lights.json rectangle's quadrature, and the rendered y agrees
    within Monte Carlo noise."""
    lamp = ('<shape type="rectangle" id="panel"><transform name="to_world"><scale value="0.1"/>'
            '<lookat origin="0.8, 0, 1" target="0, 0, 0" up="0, 0, 1"/></transform>'
            '<emitter type="area"><spectrum name="radiance" value="0.005"/></emitter></shape>')
    r = SceneRenderer(_write(tmp_path, GREY + lamp), spp=256)
    cd_m2 = luminance_to_photometric() * 0.005
    ref = parse_emitter(Path("x"), "ref", {"id": "p", "type": "rectangle", "spectrum": "D65", "position": [0.8, 0, 1],
                                           "target": [0, 0, 0], "size": [0.2, 0.2],
                                           "power": {"luminance_cd_m2": cd_m2}})
    expected = ref.illuminance_at((0, 0, 0), (0, 0, 1))
    assert r.lighting.subject_illuminance_lux() == pytest.approx(expected, rel=0.01)
    assert _centre(r) == pytest.approx(r.exposure.white_surface_y(expected, "D65", 0.5), rel=0.05)


def test_constant_environment_gives_pi_l(tmp_path: Path) -> None:
    r = SceneRenderer(_write(tmp_path, GREY + '<emitter type="constant"><spectrum name="radiance" value="0.0002"/>'
                                              '</emitter>'), spp=64)
    lux = math.pi * luminance_to_photometric() * 0.0002
    assert r.lighting.subject_illuminance_lux() == pytest.approx(lux, rel=1e-9)
    assert _centre(r) == pytest.approx(r.exposure.white_surface_y(lux, "D65", 0.5), rel=0.05)


def test_spectral_variant_agrees_with_mono() -> None:
    mono = _centre(SceneRenderer(PLAIN, spp=4, variant="mono"))
    spectral = _centre(SceneRenderer(PLAIN, spp=64, variant="spectral"))
    assert spectral == pytest.approx(mono, rel=0.03)


def test_lights_json_overrides_the_xml_emitters(tmp_path: Path) -> None:
    folder = tmp_path / "own"
    folder.mkdir()
    shutil.copy(PLAIN, folder / "scene.xml")
    (folder / "lights.json").write_text(json.dumps({"low": {"subject": {"at": [0, 0, 0], "normal": [0, 0, 1]},
        "emitters": [{"id": "sun", "type": "directional", "spectrum": "D65", "direction": [0, 0, -1],
                      "power": {"illuminance_lux": 5}}]}}))
    r = SceneRenderer(folder / "scene.xml", light="low", spp=2)
    assert r.lighting.subject_illuminance_lux() == pytest.approx(5.0)
    # the XML's point lamp (73 lx) is gone: only the 5 lx sun lights the floor
    assert _centre(r) == pytest.approx(r.exposure.white_surface_y(5.0, "D65", 0.5), rel=0.01)
    with pytest.raises(LightError, match="no lighting 'scene'"):
        SceneRenderer(folder / "scene.xml", light="scene")


def test_xml_emitters_with_motion(tmp_path: Path) -> None:
    xml = _write(tmp_path, GREY + '<emitter type="point"><point name="position" value="0, 0, 1"/>'
                                  '<spectrum name="intensity" value="0.001"/></emitter>'
                 + '<shape type="sphere" id="ball"><transform name="to_world"><scale value="0.1"/></transform>'
                   '<bsdf type="diffuse"><spectrum name="reflectance" value="0.9"/></bsdf></shape>')
    (xml.parent / "motion.json").write_text(json.dumps({"objects": [{"targets": ["ball"], "motions": [
        {"type": "translation", "velocity_mps": [200.0, 0, 0]}]}]}))
    r = SceneRenderer(xml, spp=1)
    a, b = (next(iter(r.frames(s, s + 1))) for s in (0, 40))
    assert np.abs(a - b).max() > 0  # the ball moved under the scene's own lamp


@pytest.mark.parametrize("body, match", [
    ("", "no emitter and there is no light file"),
    ('<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>', "envmap"),
    ('<emitter type="point"><point name="position" value="0, 0, 1"/></emitter>', "intensity is not given"),
    ('<emitter type="point"><point name="position" value="0, 0, 1"/><rgb name="intensity" value="1, 2"/></emitter>',
     "needs 3 numbers"),
    ('<emitter type="point"><point name="position" value="0, 0, 1"/><spectrum name="intensity" value="-1"/></emitter>',
     "must be positive"),
    ('<emitter type="point"><point name="position" value="0, 0, 1"/>'
     '<texture name="intensity" type="bitmap"><string name="filename" value="t.png"/></texture></emitter>',
     "only rgb, float or spectrum"),
])
def test_unsupported_or_missing_emitters_name_the_file(tmp_path: Path, body: str, match: str) -> None:
    xml = _write(tmp_path, GREY + body)
    with pytest.raises(SceneError, match=match) as info:
        SceneRenderer(xml, spp=1)
    assert str(xml.parent) in str(info.value)
