"""Motion files: the transforms they describe, their validation, and what the renders show."""
from __future__ import annotations

import math

import numpy as np
import pytest

from render_testing import BALL
from spikesim.render import MotionError, parse_motion


def _motion(*motions, targets=("obj",), start=0.0):
    return parse_motion({"version": 1, "start_time_s": start,
                         "objects": [{"targets": list(targets), "motions": list(motions)}]})


def _apply(spec, t, p):
    m = spec.transform("obj", t)
    return m[:3, :3] @ np.asarray(p, float) + m[:3, 3]


def test_rotation_follows_rpm_about_its_centre():
    spec = _motion({"type": "rotation", "axis": [0, 0, 1], "rpm": 1200, "center": [1, 0, 0]})
    t = 0.0125  # a quarter of a revolution at 20 rev/s (period 50 ms)
    np.testing.assert_allclose(_apply(spec, t, [2, 0, 0]), [1, 1, 0], atol=1e-12)
    np.testing.assert_allclose(_apply(spec, t, [1, 0, 5]), [1, 0, 5], atol=1e-12)  # on the axis


def test_translation_in_kmh_and_composition_order():
    spec = _motion({"type": "rotation", "axis": [0, 0, 1], "rpm": 60, "center": [0, 0, 0]},
                   {"type": "translation", "direction": [1, 0, 0], "speed_kmh": 36})
    # after 0.25 s: a quarter turn about the rest centre, then 2.5 m along x
    np.testing.assert_allclose(_apply(spec, 0.25, [1, 0, 0]), [2.5, 1, 0], atol=1e-12)


def test_ballistic_bounce_contact_time_and_rebound_height():
    g, u0, drop, e = 9.81, -4.0, 0.032, 0.82
    spec = _motion({"type": "ballistic", "velocity_mps": [9, 0, u0], "bounce": {"drop_m": drop, "restitution": e}})
    t1 = (u0 + math.sqrt(u0 ** 2 + 2 * g * drop)) / g
    assert _apply(spec, t1, [0, 0, 0])[2] == pytest.approx(-drop, abs=1e-12)        # touches the floor
    impact = u0 - g * t1
    apex_t = t1 + e * -impact / g
    assert _apply(spec, apex_t, [0, 0, 0])[2] == pytest.approx(-drop + (e * impact) ** 2 / (2 * g), abs=1e-9)
    assert _apply(spec, 0.5 * t1, [0, 0, 0])[0] == pytest.approx(9 * 0.5 * t1)     # horizontal speed kept
    zs = [_apply(spec, t, [0, 0, 0])[2] for t in np.linspace(0, 1.0, 2001)]
    assert min(zs) >= -drop - 1e-12                                                  # never below the floor


def test_keyframes_pass_through_keys_and_interpolate():
    keys = [{"t": 0.0, "translate": [0, 0, 0]}, {"t": 1.0, "translate": [1, 0, 0], "rotate_axis": [0, 0, 1], "rotate_deg": 90},
            {"t": 2.0, "translate": [1, 2, 0], "rotate_axis": [0, 0, 1], "rotate_deg": 90}]
    for mode in ("linear", "catmull_rom", "step"):
        spec = _motion({"type": "keyframes", "interpolation": mode, "keys": keys})
        np.testing.assert_allclose(_apply(spec, 1.0, [1, 0, 0]), [1, 1, 0], atol=1e-12)
        np.testing.assert_allclose(_apply(spec, 5.0, [0, 0, 0]), [1, 2, 0], atol=1e-12)  # held after the end
    lin = _motion({"type": "keyframes", "interpolation": "linear", "keys": keys})
    np.testing.assert_allclose(_apply(lin, 0.5, [1, 0, 0]), [0.5 + math.cos(math.pi / 4), math.sin(math.pi / 4), 0], atol=1e-12)
    step = _motion({"type": "keyframes", "interpolation": "step", "keys": keys})
    np.testing.assert_allclose(_apply(step, 0.99, [0, 0, 0]), [0, 0, 0], atol=1e-12)


def test_trajectory_catmull_rom_is_smooth_through_points():
    pts = [[0, 0, 0, 0], [1, 1, 0, 0], [2, 1, 1, 0], [3, 0, 1, 0]]
    spec = _motion({"type": "trajectory", "points": pts})
    for t, x, y, z in pts:
        np.testing.assert_allclose(_apply(spec, t, [0, 0, 0]), [x, y, z], atol=1e-12)
    d = 1e-6  # continuous velocity across a key
    v_before = (_apply(spec, 1.0, [0, 0, 0]) - _apply(spec, 1.0 - d, [0, 0, 0])) / d
    v_after = (_apply(spec, 1.0 + d, [0, 0, 0]) - _apply(spec, 1.0, [0, 0, 0])) / d
    np.testing.assert_allclose(v_before, v_after, atol=1e-4)


@pytest.mark.parametrize("doc, message", [
    ({"objects": [{"targets": ["a"], "motions": [{"type": "teleport"}]}]}, "type must be one of"),
    ({"objects": [{"targets": ["a"], "motions": [{"type": "rotation", "axis": [0, 0, 1]}]}]}, "rpm"),
    ({"objects": [{"targets": ["a"], "motions": [{"type": "rotation", "axis": [0, 0, 0], "rpm": 1}]}]}, "zero vector"),
    ({"objects": [{"targets": ["a"], "motions": [{"type": "translation", "speed_kmh": 50}]}]}, "velocity_mps"),
    ({"objects": [{"targets": ["a"], "motions": [{"type": "translation", "velocity_mps": [1e5, 0, 0]}]}]}, "check the units"),
    ({"objects": [{"targets": ["a"], "motions": [{"type": "keyframes", "keys": [{"t": 1}, {"t": 0}]}]}]}, "strictly increasing"),
    ({"objects": [{"targets": ["a"], "motions": [{"type": "rotation", "axis": [0, 0, 1], "rpm": 1, "speed": 2}]}]}, "unknown key"),
    ({"objects": [{"targets": ["a"], "motions": []}]}, "non-empty"),
    ({"objects": [{"targets": ["a"], "motions": [{"type": "translation", "velocity_mps": [1, 0, 0]}]},
                  {"targets": ["a"], "motions": [{"type": "translation", "velocity_mps": [1, 0, 0]}]}]}, "already move"),
    ({"version": 2, "objects": []}, "version"),
])
def test_bad_motion_documents_name_the_file_and_problem(doc, message):
    with pytest.raises(MotionError, match=message) as info:
        parse_motion(doc, "scenes/x/motion.json")
    assert str(info.value).startswith("scenes/x/motion.json")


def _centroid(y: np.ndarray) -> np.ndarray:
    w = y / y.sum()
    rows, cols = np.mgrid[0:y.shape[0], 0:y.shape[1]] + 0.5
    return np.array([(w * cols).sum(), (w * rows).sum()])


def test_projected_position_at_step_n_matches_the_motion_file(make_scene):
    """A small sphere on a black background: the centroid of its image at step n is where the
    camera model projects the motion file's position of its centre at the middle of step n."""
    from spikesim.render import SceneRenderer

    motion = {"start_time_s": 0.0, "objects": [{"targets": ["ball"], "motions": [
        {"type": "ballistic", "velocity_mps": [600.0, 300.0, 0.0], "gravity_mps2": [0, -2.0e5, 0]}]}]}
    xml = make_scene(BALL, motion=motion, fov=40, width=80, height=50)
    r = SceneRenderer(xml, spp=64, substeps=1)
    spec = r.motion
    for step in (0, 40, 80):
        y = r.render_step(step)
        t = r.time_of(step)
        centre = spec.transform("ball", t)[:3, 3]
        expected, _ = r.camera_model.project(centre[None, :])
        got = _centroid(y)
        assert np.linalg.norm(got - expected[0]) < 0.25, (step, got, expected[0])
    # and it really moved: 600 m/s * 80 steps * 25 us = 1.2 m, ~ 18 px at this distance
    assert np.linalg.norm(_centroid(r.render_step(80)) - _centroid(r.render_step(0))) > 10


def test_mesh_vertices_follow_the_motion(make_scene):
    """Meshes bake their transform into vertex positions; the animator must move the vertices."""
    import trimesh

    from spikesim.render import SceneRenderer

    shapes = ('<shape type="ply" id="cube"><string name="filename" value="cube.ply"/>'
              '<bsdf type="diffuse"><spectrum name="reflectance" value="0.9"/></bsdf></shape>')
    motion = {"objects": [{"targets": ["cube"], "motions": [{"type": "translation", "velocity_mps": [400.0, 0, 0]}]}]}
    xml = make_scene(shapes, motion=motion, fov=40, width=80, height=50)
    trimesh.creation.box(extents=[0.2, 0.2, 0.2]).export(xml.parent / "cube.ply")
    r = SceneRenderer(xml, spp=16, substeps=1)
    for step in (0, 60):
        expected, _ = r.camera_model.project(r.motion.transform("cube", r.time_of(step))[:3, 3][None, :])
        assert np.linalg.norm(_centroid(r.render_step(step)) - expected[0]) < 0.3


def test_motion_naming_a_missing_object_is_an_error(make_scene):
    from spikesim.render import SceneRenderer

    motion = {"objects": [{"targets": ["balll"], "motions": [{"type": "translation", "velocity_mps": [1, 0, 0]}]}]}
    xml = make_scene(BALL, motion=motion)
    with pytest.raises(MotionError, match="balll") as info:
        SceneRenderer(xml)
    assert "motion.json" in str(info.value) and "ball" in str(info.value)
