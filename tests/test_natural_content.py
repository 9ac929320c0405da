"""RLLR's natural content: dead-leaves textures, package photographs, natural scenes, their plan."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from scenes.natural_textures import (PHOTOS, dead_leaves, package_photo, photo_folder, power_law_radii,
                                     power_spectrum_slope)
from spikesim.generation.plan import PRESETS, plan_rllr, scaled_size


def test_power_law_radii_follow_the_analytic_cdf():
    """p(r) ~ r^-3 on [r_min, r_max]: P(R > x) = (x^-2 - r_max^-2) / (r_min^-2 - r_max^-2)."""
    r = power_law_radii(np.random.default_rng(0), 200_000, 2.0, 100.0)
    assert r.min() >= 2.0 and r.max() <= 100.0
    for x in (2.5, 4.0, 10.0, 40.0):
        expected = (x ** -2 - 100.0 ** -2) / (2.0 ** -2 - 100.0 ** -2)
        # binomial standard error of an empirical fraction over 200k draws, at 5 sigma
        assert abs((r > x).mean() - expected) < 5 * math.sqrt(expected * (1 - expected) / r.size)


def test_power_law_radii_refuse_a_bad_range():
    with pytest.raises(ValueError, match="r_min < r_max"):
        power_law_radii(np.random.default_rng(0), 4, 5.0, 5.0)


@pytest.mark.parametrize("colour", [False, True])
def test_dead_leaves_spectrum_slope(colour):
    """Measured over 12 seeds at 256 px: slope -1.89 +- 0.165 per image (grey and colour alike);
    the mean of 4 images has a spread of 0.08, so +-0.3 is about 3.5 of it. White noise gives 0,
    the value noise of the procedural content -2.7 to -2.9 (docs/scenes.md)."""
    slopes = [power_spectrum_slope(dead_leaves(np.random.default_rng(s), 256, colour=colour)) for s in range(4)]
    assert -2.2 < float(np.mean(slopes)) < -1.6


def test_dead_leaves_is_reproducible_covered_and_in_range():
    a = dead_leaves(np.random.default_rng(3), 128)
    b = dead_leaves(np.random.default_rng(3), 128)
    c = dead_leaves(np.random.default_rng(4), 128)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert a.shape == (128, 128, 3) and a.min() >= 0.0 and a.max() <= 1.0
    grey = dead_leaves(np.random.default_rng(3), 128, colour=False)
    assert np.array_equal(grey[..., 0], grey[..., 1]) and np.array_equal(grey[..., 1], grey[..., 2])
    # many leaves of many sizes: far more distinct values than a handful of uniform shapes
    assert np.unique(grey[..., 0]).size > 500


def test_dead_leaves_refuses_a_tiny_canvas():
    with pytest.raises(ValueError, match="at least 8"):
        dead_leaves(np.random.default_rng(0), 4)


def test_package_photos_ship_with_their_licences():
    for name, photo in PHOTOS.items():
        assert (photo_folder() / photo.filename).is_file(), name
        assert photo.licence and photo.source.startswith("skimage.data.")
    img, rec = package_photo(np.random.default_rng(1), 64)
    img2, rec2 = package_photo(np.random.default_rng(1), 64)
    assert np.array_equal(img, img2) and rec == rec2
    assert img.shape == (64, 64, 3) and 0 <= img.min() and img.max() <= 1
    assert rec["licence"] == PHOTOS[rec["name"]].licence and rec["package"].startswith("scikit-image ")
    with pytest.raises(ValueError, match="unknown package photo"):
        package_photo(np.random.default_rng(1), 64, name="nope")


def test_natural_scene_is_reproducible_and_records_its_content(tmp_path):
    from scenes.natural_scene import build_natural_scene
    from spikesim.render.motion import load_motion

    a = build_natural_scene(7, tmp_path / "a", (62, 100))
    build_natural_scene(7, tmp_path / "b", (62, 100))
    for name in ("scene.xml", "motion.json", "lights.json", "content.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    for tex in (tmp_path / "a" / "textures").iterdir():
        assert tex.read_bytes() == (tmp_path / "b" / "textures" / tex.name).read_bytes()
    content = json.loads((tmp_path / "a" / "content.json").read_text())
    assert content["textures"] and all(t["licence"] for t in content["textures"])
    assert all((tmp_path / "a" / t["file"]).is_file() for t in content["textures"])
    load_motion(a[1])  # a valid motion file
    assert 'width" value="100"' in a[0].read_text()


def test_natural_scenes_move_the_camera_sometimes():
    """Over 12 seeds the camera is still, panned and shaken; a moving camera is an object of the
    motion file whose target is the sensor."""
    from scenes.natural_scene import _camera_motion

    kinds = set()
    for seed in range(12):
        entry, rec = _camera_motion(np.random.default_rng(seed), np.array([0.0, -2.0, 1.0]), 40.0, 400, 25e-6)
        kinds.add(rec["kind"])
        if entry is not None:
            assert entry["targets"] == ["camera"] and 0.02 <= rec["px_per_step"] <= 1.5
    assert kinds == {"still", "pan", "shake"}


def test_pan_speed_matches_the_requested_image_speed():
    """A pan of omega rad/s moves the centre pixel by omega T W / (2 tan(fov/2)) pixels per step."""
    from scenes.natural_scene import _camera_motion

    for seed in range(30):
        entry, rec = _camera_motion(np.random.default_rng(seed), np.array([0.0, -2.0, 1.0]), 40.0, 400, 25e-6)
        if rec["kind"] == "pan":
            omega = abs(rec["rpm"]) * 2 * math.pi / 60
            px = omega * 25e-6 * 400 / (2 * math.tan(math.radians(20)))
            assert px == pytest.approx(rec["px_per_step"], rel=1e-9)
            return
    pytest.fail("no pan in 30 seeds")


def test_plan_natural_scales_and_lamps():
    preset = PRESETS["paper"]
    jobs = plan_rllr(preset, count=12, content="natural", scales=(1.0, 0.5, 0.25), lamps_lux=(1.0, 2.0))
    sizes = {(j.camera["height"], j.camera["width"]) for j in jobs}
    assert sizes == {(250, 400), (125, 200), (62, 100)}
    assert all(j.source["content"] == "natural" and j.source["lamps_lux"] == [1.0, 2.0] for j in jobs)
    assert all(j.render["resolution"] == [j.camera["height"], j.camera["width"]] for j in jobs)
    assert "scenes/natural_scene.py" in jobs[0].inputs


def test_plan_procedural_is_unchanged_by_the_new_options(monkeypatch):
    """The default plan (content procedural, one scale, the realistic camera) keeps every job's
    identity: these digests were computed by the code before natural content, scales and the
    measured camera terms existed (data version 1), so datasets made then were not reported stale.
    Data version 2 (the per-step normals drawn by counter) changes every digest on purpose."""
    import spikesim.generation.inputs as inputs
    now = [j.digest for j in plan_rllr(PRESETS["paper"], count=2)]
    monkeypatch.setattr(inputs, "DATA_VERSION", 1)
    assert not set(now) & {j.digest for j in plan_rllr(PRESETS["paper"], count=2)}
    assert [j.digest for j in plan_rllr(PRESETS["small"], count=3, darkening="log-uniform")] == [
        "f84abbdebd84467d", "c247873c6f4c6b10", "e377058f59507cd0"]
    assert [j.digest for j in plan_rllr(PRESETS["paper"], count=2)] == ["60c4df987bfb6450", "b41d4d1ce6fe1c4e"]


@pytest.mark.parametrize("kwargs, message", [
    ({"content": "photos"}, "content="),
    ({"scales": (0.0,)}, "pixel scale"),
    ({"scales": (1.5,)}, "pixel scale"),
    ({"scales": (0.1,)}, "below 32"),
    ({"scales": ()}, "at least one"),
    ({"lamps_lux": (5.0, 1.0)}, "lamps_lux"),
    ({"lamps_lux": (0.0, 1.0)}, "lamps_lux"),
    ({"source": "pattern", "content": "natural"}, "random scenes"),
])
def test_plan_refuses_bad_options(kwargs, message):
    with pytest.raises(ValueError, match=message):
        plan_rllr(PRESETS["paper"], count=2, **kwargs)


def test_scaled_size():
    assert scaled_size(250, 400, 1.0) == (250, 400)
    assert scaled_size(250, 400, 0.25) == (62, 100)


def test_generate_natural_records_licences_and_scales(tmp_path):
    """`generate rllr --content natural`: the scene's meta.json carries its textures' sources and
    licences, and a scene drawn at scale 0.5 has half the preset's pixels a side."""
    import subprocess
    import sys

    out = tmp_path / "nat"
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "generate", "rllr", "--preset", "small", "--content",
                        "natural", "--count", "2", "--scales", "1", "0.5", "--steps", "82", "--gt-stride", "41",
                        "--camera", "measured", "--workers", "1", "--quiet", "-o", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    metas = [json.loads((out / f"rllr_{i:04d}" / "meta.json").read_text()) for i in range(2)]
    sizes = {(m["height"], m["width"]) for m in metas}
    assert sizes <= {(64, 100), (32, 50)}
    for m in metas:
        content = m["source"]["content"]
        assert content["generator"] == "scenes/natural_scene.py" and content["textures"]
        assert all(t["licence"] for t in content["textures"])
        assert m["camera"]["row_gain_spread"] == 0.015
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "generate", "llr", "--content", "natural", "-o",
                        str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--content applies to generate rllr" in r.stderr


def test_a_still_share_stops_the_camera_and_leaves_other_scenes_as_they_were():
    """`generate --still-share`: LLR's static backgrounds (where TFP over 205 steps wins) in photo
    scenes; drawn from a stream of its own, so a scene with 0 is bit for bit the scene it was."""
    import numpy as np

    from scenes.photo_pan import PhotoPan
    moving = PhotoPan(height=24, width=32, num_steps=200, seed=9)
    same = PhotoPan(height=24, width=32, num_steps=200, seed=9, still_share=0.0)
    np.testing.assert_array_equal(moving.frame(150), same.frame(150))
    still = PhotoPan(height=24, width=32, num_steps=200, seed=9, still_share=1.0)
    assert still.camera_offset(0) == still.camera_offset(199)  # the backdrop does not move
    assert still.describe()["photo_scene"]["camera"]["kind"] == "still"
    assert moving.camera_offset(0) != moving.camera_offset(199)
    from spikesim.generation import PRESETS, plan_rllr
    preset = PRESETS["small"].replace(rllr_steps=82, rllr_gt_stride=41)
    plain = plan_rllr(preset, seed=3, count=2, content="photo")
    assert plain == plan_rllr(preset, seed=3, count=2, content="photo", still_share=0.0)
    assert all("still_share" not in j.source for j in plain)
    with pytest.raises(ValueError, match="photo"):
        plan_rllr(preset, seed=3, count=1, content="natural", still_share=0.5)
