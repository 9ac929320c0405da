"""A moving camera (a motion file whose targets name the sensor's id): SceneRenderer.motion_px,
which decides the sub-steps of each step and the adaptive keyframes, must estimate the image
motion the renders show. Measured here on tiny renders of the shipped example
(tests/data/camera_pan, docs/scenes.md section 3): the shift of the balls between two steps,
per step, against the estimate."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from spikesim.render import SceneRenderer

EXAMPLE = Path(__file__).resolve().parents[1] / "data" / "camera_pan"


def centroid(y: np.ndarray, around: np.ndarray | None = None, radius: int = 4) -> np.ndarray:
    """(column, row) of the brightness centroid, pixel centres at +0.5 as PinholeCamera.project;
    with `around`, of the window of `radius` pixels about that point only."""
    rows, cols = np.indices(y.shape)
    w = y.astype(np.float64)
    if around is not None:
        w = w * ((np.abs(cols + 0.5 - around[0]) <= radius) & (np.abs(rows + 0.5 - around[1]) <= radius))
    w = w / w.sum()
    return np.array([(w * (cols + 0.5)).sum(), (w * (rows + 0.5)).sum()])


def test_a_camera_pan_is_estimated_as_the_shift_the_renders_show():
    r = SceneRenderer(EXAMPLE / "scene.xml", variant="mono", spp=16)
    steps = 2000  # 3 degrees of the 10 rpm pan: about 3 px at 32 px across 30 degrees
    a, b = r.render_step(0), r.render_step(steps)
    measured = float(np.linalg.norm(centroid(b) - centroid(a))) / steps
    estimate = r.motion_px(0)
    assert 0.5 < estimate / measured < 2.0, (estimate, measured)
    assert r.substeps_for(0) == 1  # 0.0016 px per step: one render


def test_a_camera_translation_is_estimated_from_the_nearest_surface(tmp_path):
    """Sideways and forward at 200 m/s: the near ball (3 m away) moves about 0.1 px per step,
    the far ones less; the estimate is the near ball's, not the camera origin's (the origin
    itself, projected through the camera at rest, gave hundreds of pixels: 16 sub-renders)."""
    folder = tmp_path / "camera_dolly"
    folder.mkdir()
    shutil.copy(EXAMPLE / "scene.xml", folder / "scene.xml")
    (folder / "motion.json").write_text(json.dumps({"objects": [
        {"targets": ["camera"], "motions": [{"type": "translation", "velocity_mps": [160, 0, -120]}]}]}))
    r = SceneRenderer(folder / "scene.xml", variant="mono", spp=16)
    steps = 24
    near = np.array([0.3, 0.4, 2.0])
    start = r.camera_at(r.time_of(0)).project(near)[0]
    end = r.camera_at(r.time_of(steps)).project(near)[0]
    a, b = r.render_step(0), r.render_step(steps)
    measured = float(np.linalg.norm(centroid(b, end) - centroid(a, start))) / steps
    estimate = r.motion_px(0)
    assert 0.05 < measured < 0.2
    assert 0.5 < estimate / measured < 2.0, (estimate, measured)
    assert r.substeps_for(0) == 1


def test_a_fast_pan_is_split_into_sub_steps(tmp_path):
    """The estimate also decides blur: a pan of about 4 px per step renders 4 sub-steps, each
    at its own camera pose (the two halves of such a step differ)."""
    folder = tmp_path / "fast_pan"
    folder.mkdir()
    shutil.copy(EXAMPLE / "scene.xml", folder / "scene.xml")
    # 4 px of 0.94 degrees each per 25 us step: 150000 degrees per second
    (folder / "motion.json").write_text(json.dumps({"objects": [
        {"targets": ["camera"], "motions": [{"type": "rotation", "axis": [0, 1, 0], "rpm": 25000,
                                             "center": [0, 0, 5]}]}]}))
    r = SceneRenderer(folder / "scene.xml", variant="mono", spp=4)
    assert 3.0 < r.motion_px(0) < 6.0
    assert r.substeps_for(0) in (4, 5, 6)


def test_the_camera_at_rest_is_the_xml_pose_and_objects_still_count(make_scene):
    """Without camera motion, camera_at is the rest pose and motion_px the objects' motion."""
    from render_testing import BALL
    xml = make_scene(BALL, motion={"objects": [{"targets": ["ball"], "motions": [
        {"type": "translation", "velocity_mps": [100, 0, 0]}]}]})
    r = SceneRenderer(xml, variant="mono", spp=1)
    assert r.camera_at(1.0) is r.camera_model
    f = 0.5 * r.width / np.tan(np.radians(r.camera_model.x_fov_deg) / 2)
    expected = f * 100 * r.readout_period_s / 5.0  # v T / z, in pixels
    assert r.motion_px(0) == pytest.approx(expected, rel=0.05)
