"""Bad input: each error names the file and says what is wrong."""
from __future__ import annotations

import json

import pytest

from render_testing import BALL, PLANE, SUN
from spikesim.render import LightError, SceneError, load_lights


def _renderer(xml, **kw):
    from spikesim.render import SceneRenderer
    return SceneRenderer(xml, **kw)


def test_xml_mitsuba_rejects(make_scene):
    xml = make_scene('<shape type="spheer" id="x"/>')
    with pytest.raises(SceneError, match="Mitsuba rejected") as info:
        _renderer(xml)
    assert str(xml) in str(info.value) and "spheer" in str(info.value)


def test_malformed_xml(make_scene):
    xml = make_scene("<shape type='sphere'>")
    with pytest.raises(SceneError, match="not well-formed") as info:
        _renderer(xml)
    assert str(info.value).startswith(str(xml))


def test_missing_texture_names_the_texture(make_scene):
    shapes = ('<shape type="sphere" id="s"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
              '<string name="filename" value="textures/nope.png"/></texture></bsdf></shape>')
    xml = make_scene(shapes)
    with pytest.raises(SceneError, match="textures/nope.png") as info:
        _renderer(xml)
    assert str(info.value).startswith(str(xml)) and "does not exist" in str(info.value)


def test_light_file_replaces_an_emitter_it_does_not_list(make_scene):
    """Emitters in the XML were refused before; now a light file's condition replaces them
    (test_render_scene_emitters.py has the rest)."""
    xml = make_scene(BALL + '<emitter type="point" id="lamp"><point name="position" value="0,0,1"/></emitter>')
    r = _renderer(xml, spp=1)
    assert [e.id for e in r.lighting.emitters] == ["sun"]


def test_missing_light_condition(make_scene):
    xml = make_scene(BALL)
    with pytest.raises(LightError, match="has no lighting 'dusk'") as info:
        _renderer(xml, light="dusk")
    assert "lights.json" in str(info.value)


def test_missing_scene_file(tmp_path):
    with pytest.raises(SceneError, match="does not exist"):
        _renderer(tmp_path / "nothing.xml")
    with pytest.raises(SceneError, match="bundled scene"):
        _renderer("no_such_scene")


def _write_lights(tmp_path, emitter):
    path = tmp_path / "lights.json"
    path.write_text(json.dumps({"normal": {"emitters": [emitter]}}))
    return path


@pytest.mark.parametrize("power, message", [
    ({"illuminance_lux": -5}, "must be positive"),
    ({"illuminance_lux": 0}, "must be positive"),
    ({"illuminance_lux": 5e6}, "absurd"),
    ({"luminous_flux_lm": float("nan")}, "finite"),
    ({"luminous_flux_lm": 1e9}, "absurd"),
    ({"electrical_power_w": 60}, "lamp"),
    ({"electrical_power_w": 60, "lamp": "incandescent_100w_120v", "luminous_flux_lm": 800}, "exactly one"),
    ({}, "exactly one"),
    ({"luminance_cd_m2": 100}, "not defined for a point"),
])
def test_bad_light_power(tmp_path, power, message):
    path = _write_lights(tmp_path, {"id": "bulb", "type": "point", "spectrum": "A", "position": [0, 0, 2], "power": power})
    with pytest.raises(LightError, match=message) as info:
        load_lights(path)
    assert str(info.value).startswith(str(path))


@pytest.mark.parametrize("emitter, message", [
    ({**SUN, "spectrum": "sodium"}, "not a known light spectrum"),
    ({**SUN, "type": "laser"}, "expected one of"),
    ({**SUN, "direction": [0, 0]}, "list of 3"),
    ({**SUN, "colour": "red"}, "unknown key"),
    ({"id": "p", "type": "point", "spectrum": "A", "position": [0, 0, 2],
      "power": {"illuminance_lux": 10, "at": [0, 0, 0], "normal": [0, 0, -1]}}, "does not illuminate"),
    ({"id": "r", "type": "rectangle", "spectrum": "A", "position": [0, 0, 2], "target": [0, 0, 2], "size": [1, 1],
      "power": {"luminous_flux_lm": 100}}, "target must differ"),
])
def test_bad_emitters(tmp_path, emitter, message):
    path = _write_lights(tmp_path, emitter)
    with pytest.raises(LightError, match=message):
        load_lights(path)


def test_photometric_conversions(tmp_path):
    import math

    lights = load_lights(_write_lights(tmp_path, {"id": "bulb", "type": "point", "spectrum": "A", "position": [0, 0, 2],
                                                  "power": {"electrical_power_w": 100, "lamp": "incandescent_100w_120v"}}))
    bulb = lights["normal"].emitters[0]
    assert bulb.luminous_flux_lm() == pytest.approx(1750.0)                   # 100 W x 17.5 lm/W
    assert bulb.photometric == pytest.approx(1750.0 / (4 * math.pi))          # cd
    assert bulb.illuminance_at([0, 0, 0], [0, 0, 1]) == pytest.approx(1750.0 / (4 * math.pi) / 4)
    panel = load_lights(_write_lights(tmp_path, {"id": "p", "type": "rectangle", "spectrum": "FL2", "position": [0, 0, 2],
                                                 "target": [0, 0, 0], "size": [1.2, 0.5], "power": {"luminous_flux_lm": 3000}}))
    assert panel["normal"].emitters[0].photometric == pytest.approx(3000 / (math.pi * 0.6))  # L = F / (pi A)


def test_bad_motion_file_is_reported_with_its_path(make_scene):
    from spikesim.render import MotionError

    xml = make_scene(BALL, motion={"objects": [{"targets": ["ball"], "motions": [{"type": "spin"}]}]})
    with pytest.raises(MotionError) as info:
        _renderer(xml)
    assert "motion.json" in str(info.value) and "objects[0].motions[0]" in str(info.value)


def test_invalid_render_settings(make_scene):
    xml = make_scene(PLANE.format(reflectance=0.5))
    for kw, message in (({"spp": 0}, "spp"), ({"variant": "hdr"}, "variant"), ({"resolution": (0, 3)}, "resolution"),
                        ({"substeps": "many"}, "substeps"), ({"seed": -1}, "seed")):
        with pytest.raises(ValueError, match=message):
            _renderer(xml, **kw)
