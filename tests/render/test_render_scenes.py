"""The five bundled LLR scenes: they load, move, and are lit at the documented real-world levels."""
from __future__ import annotations

import numpy as np
import pytest

from scenes import SCENES, scene_path
from spikesim.render import load_lights, load_motion

TINY = (25, 40)


@pytest.mark.parametrize("name", SCENES)
def test_light_levels_are_the_documented_real_world_ones(name):
    lights = load_lights(scene_path(name).parent / "lights.json")
    assert {"normal", "low"} <= set(lights)
    normal, low = (lights[k].subject_illuminance_lux() for k in ("normal", "low"))
    assert 100 <= normal <= 500, normal      # indoor working light to sunset daylight
    assert 1 <= low <= 15, low               # dim indoor / street lighting at night
    for cond in lights.values():
        assert cond.description and cond.reference


@pytest.mark.parametrize("name", SCENES)
def test_scene_renders_under_both_lights(name):
    from spikesim.render import SceneRenderer

    means = {}
    for light in ("normal", "low"):
        r = SceneRenderer(name, light=light, spp=2, resolution=TINY)
        y = r.render_step(430)
        assert y.shape == TINY and np.isfinite(y).all() and y.min() >= 0
        means[light] = float(y.mean())
        assert r.animator.moving and r.motion_px(430) > 0
        # every bundled scene moves less than a pixel per step at 400 x 250 (so one render per step)
        assert r.motion_px(430) * 10 < 1.0
    assert 0.005 < means["normal"] < 0.6
    assert means["low"] < means["normal"] / 8


def test_motion_files_name_real_speeds():
    """The stated speeds: car 70 km/h with rolling wheels, fan 1300 rpm, disc 1200 rpm."""
    car = load_motion(scene_path("car").parent / "motion.json")
    v = car.transform("car_body", 1.0)[:3, 3]
    assert np.linalg.norm(v) == pytest.approx(70 / 3.6)
    # a wheel's contact point is momentarily at rest (rolling without slipping)
    wheel = car.objects[1]
    centre = np.array(wheel.motions[0].params["center"])
    contact = centre - [0, 0, 0.32]
    dt = 1e-7
    p = lambda t: (wheel.transform(t) @ np.append(contact, 1.0))[:3]  # noqa: E731
    assert np.linalg.norm((p(dt) - p(-dt)) / (2 * dt)) < 0.05
    fan = load_motion(scene_path("fan").parent / "motion.json")
    assert fan.objects[0].motions[0].params["rpm"] == 1300


def test_spectral_variant_of_a_bundled_scene():
    from spikesim.render import SceneRenderer

    mono = SceneRenderer("rotate", spp=4, resolution=TINY).ground_truth(0, spp=16)
    spec = SceneRenderer("rotate", variant="spectral", spp=4, resolution=TINY).ground_truth(0, spp=16)
    assert 0.7 < spec.mean() / mono.mean() < 1.4


@pytest.mark.slow
def test_assets_rebuild_byte_for_byte(tmp_path):
    """`python -m scenes.build_assets` reproduces the committed textures and meshes (same library
    versions), whichever subset of scenes is built."""
    from scenes import ROOT
    from scenes.build_assets import build

    build(["rotate", "ball"], root=tmp_path)
    files = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert len(files) > 5
    for rel in files:
        assert (tmp_path / rel).read_bytes() == (ROOT / rel).read_bytes(), rel
