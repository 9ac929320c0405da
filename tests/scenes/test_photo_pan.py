"""scenes/photo_pan.py: the video-like `photo` content and the `reds-like` test pairs."""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("skimage")

from scenes.natural_textures import PHOTOS
from scenes.photo_pan import HELD_OUT_PHOTOS, PAN_PX_PER_STEP, PhotoPan
from spikesim.generation.plan import PRESETS, UNRENDERED_SOURCES, darkening_factor, plan_rllr


def test_a_scene_is_its_seed_and_frames_are_in_range():
    a, b = PhotoPan(40, 64, 50, seed=3), PhotoPan(40, 64, 50, seed=3)
    assert np.array_equal(a.frame(17), b.frame(17))
    assert not np.array_equal(a.frame(17), PhotoPan(40, 64, 50, seed=4).frame(17))
    for step in (0, 25, 49):
        f = a.frame(step)
        assert f.shape == (40, 64) and f.dtype == np.float32
        assert np.isfinite(f).all() and f.min() >= 0 and f.max() <= a.peak_y + 1e-6
    assert a.frame(0).std() > 0  # textured, not flat


def test_the_camera_moves_at_the_drawn_speed_and_stays_on_its_canvas():
    for seed in range(6):
        p = PhotoPan(32, 48, 200, seed=seed)
        cam = p.layout["record"]["camera"]
        assert PAN_PX_PER_STEP[0] <= cam["px_per_step"] <= PAN_PX_PER_STEP[1]
        if cam["kind"] == "pan":  # a straight pan: the offset moves by exactly that speed per step
            (y0, x0), (y1, x1) = p.camera_offset(0), p.camera_offset(100)
            assert math.hypot(y1 - y0, x1 - x0) / 100 == pytest.approx(cam["px_per_step"], rel=1e-9)
        ch, cw = p.layout["canvas"].shape
        for step in range(0, 200, 7):
            oy, ox = p.camera_offset(step)
            assert 0 <= oy and oy + 33 <= ch and 0 <= ox and ox + 49 <= cw
            p.frame(step)  # inside the canvas: no index error, no short slice


def test_held_out_pictures_are_never_training_pictures():
    train = {ph.filename for ph in PHOTOS.values()}
    assert not train & {ph.filename for ph in HELD_OUT_PHOTOS.values()}
    for seed in range(8):
        rec = PhotoPan(32, 48, 20, seed=seed, photo_set="heldout").layout["record"]
        for item in [rec["backdrop"], *rec["objects"]]:
            assert item["kind"] == "photo" and item["file"] not in train


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="photo_set"):
        PhotoPan(8, 8, 4, photo_set="test")
    with pytest.raises(ValueError, match="encoding"):
        PhotoPan(8, 8, 4, encoding="gamma")
    with pytest.raises(ValueError, match="peak_y"):
        PhotoPan(8, 8, 4, peak_y=float("nan"))


def test_plans_of_photo_content_render_nothing_and_reds_like_follows_the_other_simulator():
    small = PRESETS["small"]
    jobs = plan_rllr(small, count=3, content="photo", darkening="log-uniform")
    assert all(j.source["type"] == "photo" and j.source["photo_set"] == "train" for j in jobs)
    assert "photo" in UNRENDERED_SOURCES and all(j.quality is None for j in jobs)
    reds = plan_rllr(small, count=2, content="reds-like", darkening="none")
    assert all(j.light_power_factor == 1.0 for j in reds)
    assert all((j.source["photo_set"], j.source["encoding"], j.source["peak_y"]) == ("heldout", "srgb", 0.6)
               for j in reds)
    assert darkening_factor(np.random.default_rng(0), "none") == 1.0


def test_a_generated_photo_scene_holds_the_exact_frames_as_ground_truth(tmp_path):
    from spikesim.dataset import open_dataset
    from spikesim.generation.run import generate

    jobs = plan_rllr(PRESETS["small"], count=1, content="photo", darkening="log-uniform", seed=5)
    generate(jobs, tmp_path / "ds", workers=1, show_progress=False)
    (scene,) = list(open_dataset(tmp_path / "ds"))
    src = jobs[0].source
    pan = PhotoPan(scene.height, scene.width, scene.num_steps, seed=src["scene_seed"], peak_y=src["peak_y"])
    step = scene.gt_steps[1]
    expected = pan.frame(step) * np.float32(jobs[0].light_power_factor)
    np.testing.assert_allclose(scene.ground_truth(step), expected, rtol=1e-6, atol=1e-9)
    rate = scene.spikes(0, scene.num_steps).mean()
    assert 0 < rate < 1


def test_photo_scenes_are_textured_over_the_frame_and_scale_with_their_white_level():
    """What the content is for (docs/scenes.md section 12): a video-like frame is lit and textured
    over most of its area (the rendered natural scenes: 68 % of 16 x 16 blocks, median of 8), and a
    scene's brightness is its white level times the darkening."""
    from pipelines.content_stats import lit_textured_fraction
    shares = [lit_textured_fraction(PhotoPan(96, 128, 10, seed=s).frame(5)) for s in range(10)]
    assert np.median(shares) >= 0.75
    a, b = PhotoPan(64, 96, 10, seed=2, peak_y=0.8), PhotoPan(64, 96, 10, seed=2, peak_y=2.0)
    np.testing.assert_allclose(b.frame(3), a.frame(3) * 2.5, rtol=1e-5)
    jobs = plan_rllr(PRESETS["small"], count=2, content="photo", peak_y=2.0)
    assert all(j.source["peak_y"] == 2.0 for j in jobs)
    with pytest.raises(ValueError, match="photo content"):
        plan_rllr(PRESETS["small"], count=1, content="natural", peak_y=2.0)
