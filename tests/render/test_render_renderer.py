"""SceneRenderer: seeds, streaming, kernel reuse, flat memory, sub-steps, describe()."""
from __future__ import annotations

import json

import numpy as np
import pytest

from render_testing import BALL, PLANE, SUN

MOVING = {"objects": [{"targets": ["ball"], "motions": [{"type": "translation", "velocity_mps": [200.0, 0, 0]}]}]}
# a ball in front of a lit plane, lit from the side so that every pixel has Monte Carlo noise
SHAPES = BALL + PLANE.format(reflectance=0.5).replace("<scale value=\"50\"/>", "<scale value=\"50\"/><translate z=\"-0.5\"/>")
SIDE_LIGHT = {"normal": {"emitters": [SUN, {"id": "lamp", "type": "rectangle", "spectrum": "A", "position": [1, 1, 2],
                                             "target": [0, 0, 0], "size": [0.5, 0.5], "power": {"luminous_flux_lm": 500}}]}}


@pytest.fixture
def moving_scene(make_scene):
    return make_scene(SHAPES, lights=SIDE_LIGHT, motion=MOVING, integrator="path")


def test_same_seed_same_frames_other_seed_other_frames(moving_scene):
    from spikesim.render import SceneRenderer

    a = list(SceneRenderer(moving_scene, spp=1, seed=7).frames(0, 3))
    b = list(SceneRenderer(moving_scene, spp=1, seed=7).frames(0, 3))
    c = list(SceneRenderer(moving_scene, spp=1, seed=8).frames(0, 3))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[0], c[0])
    assert not np.array_equal(a[0], a[1])          # every step draws new samples


def test_a_step_renders_the_same_wherever_the_stream_starts(moving_scene):
    from spikesim.render import SceneRenderer

    r = SceneRenderer(moving_scene, spp=1, seed=3)
    streamed = list(r.frames(0, 5))
    np.testing.assert_array_equal(r.render_step(4), streamed[4])
    np.testing.assert_array_equal(list(r.frames(3, 2))[1], streamed[4])


def test_frames_types_shapes_and_keyframes(moving_scene):
    from spikesim.render import SceneRenderer

    r = SceneRenderer(moving_scene, spp=1)
    frames = list(r.frames(10, 9, keyframe_every=4))           # steps 10, 14, 18
    assert len(frames) == 3
    assert all(f.dtype == np.float32 and f.shape == (25, 40) and f.min() >= 0 for f in frames)
    np.testing.assert_array_equal(frames[2], r.render_step(18))
    assert len(list(r.frames(0, 10, keyframe_every=4))) == 4    # 0, 4, 8, 12 (12 >= 9: covers the end)
    assert len(list(r.frames(0, 1, keyframe_every=4))) == 1
    with pytest.raises(ValueError, match="keyframe_every"):
        next(r.frames(0, 4, keyframe_every=0))
    with pytest.raises(ValueError, match="step"):
        r.render_step(-1)


def test_ground_truth_is_the_low_noise_version_of_the_frame(moving_scene):
    from spikesim.render import SceneRenderer

    r = SceneRenderer(moving_scene, spp=2, gt_spp=256, seed=1)
    gt = r.ground_truth(5)
    frames = np.mean([SceneRenderer(moving_scene, spp=2, seed=s).render_step(5) for s in range(8)], axis=0)
    assert abs(frames.mean() / gt.mean() - 1) < 0.05
    assert np.abs(frames - gt).mean() < np.abs(r.render_step(5) - gt).mean()


def _new_kernel(entry: dict) -> bool:
    """A kernel this process had not compiled before: built now, or loaded from the disk cache
    (a kernel compiled in an earlier run counts as new here, or a rerun would hide a recompile)."""
    return not entry.get("cache_hit") or bool(entry.get("cache_disk"))


def test_no_recompilation_from_frame_to_frame(moving_scene, make_scene, tmp_path):
    """After the first frames, new poses (sphere transform) and new seeds reuse the compiled kernels."""
    import trimesh

    from spikesim.render import SceneRenderer
    from spikesim.render.backend import dr

    cube = ('<shape type="ply" id="cube"><string name="filename" value="cube.ply"/>'
            '<bsdf type="diffuse"><spectrum name="reflectance" value="0.9"/></bsdf></shape>')
    mesh_motion = {"objects": [{"targets": ["cube"], "motions": [{"type": "rotation", "axis": [0, 0, 1], "rpm": 3000}]}]}
    mesh_scene = make_scene(cube, motion=mesh_motion, name="mesh")
    trimesh.creation.box(extents=[0.2, 0.2, 0.2]).export(mesh_scene.parent / "cube.ply")
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for xml in (moving_scene, mesh_scene):
            r = SceneRenderer(xml, spp=2)
            frames = r.frames(0, 12)
            for _ in range(3):
                next(frames)
            dr.kernel_history()  # clears the history
            for _ in frames:
                pass
            jit = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
            assert jit, "no kernels were recorded: the test would be vacuous"
            missed = [k for k in jit if _new_kernel(k)]
            assert not missed, f"{len(missed)} of {len(jit)} kernels were compiled again for new frames"
        # control: the check does see recompilation, e.g. a per-frame Python scalar baked in as a literal
        from spikesim.render.backend import mi
        dr.kernel_history()
        for i in range(3):
            dr.eval(mi.Float(np.arange(8, dtype=np.float32)) * (1.2345 + i))
        assert sum(_new_kernel(k) for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT) >= 2
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def _memory_growth_mb(xml, warmup: int, frames: int) -> float:
    from spikesim.render import SceneRenderer

    r = SceneRenderer(xml, spp=1)
    stream = r.frames(0, warmup + frames)
    for _ in range(warmup):
        next(stream)
    before = _rss_mb()
    for y in stream:
        assert y.shape == (25, 40)
    assert r.stats["frames"] == warmup + frames
    return _rss_mb() - before


def test_memory_stays_flat_over_many_frames(moving_scene):
    growth = _memory_growth_mb(moving_scene, warmup=60, frames=240)
    assert growth < 20.0, f"resident memory grew by {growth:.1f} MB over 240 frames"


@pytest.mark.slow
def test_memory_stays_flat_over_thousands_of_frames(moving_scene):
    growth = _memory_growth_mb(moving_scene, warmup=100, frames=3000)
    assert growth < 20.0, f"resident memory grew by {growth:.1f} MB over 3000 frames"


def test_auto_substeps_blur_fast_motion_and_conserve_light(make_scene):
    """A ball moving ~6 px per step is rendered as the mean of sub-step renders: the streak is
    longer than the ball, and the light it reflects is the same as when it stands still."""
    from types import SimpleNamespace

    from spikesim.render import SceneRenderer

    slow_camera = SimpleNamespace(height=50, width=80, readout_period_s=1e-3, threshold_electrons=1000.0)
    fast = {"objects": [{"targets": ["ball"], "motions": [{"type": "translation", "velocity_mps": [250.0, 0, 0]}]}]}
    xml = make_scene(BALL, motion=fast, fov=40, width=80, height=50)
    r = SceneRenderer(xml, spp=256, camera=slow_camera)
    px = r.motion_px(0)
    assert 4 < px < 10
    assert r.substeps_for(0) == int(np.ceil(px))
    blurred = r.render_step(0)
    still = SceneRenderer(xml, spp=256, substeps=1, camera=slow_camera).render_step(0)
    assert blurred.sum() == pytest.approx(still.sum(), rel=0.03)
    width = lambda y: int((y.max(axis=0) > 0.02 * y.max()).sum())  # noqa: E731
    assert width(blurred) >= width(still) + int(px) - 1
    static = make_scene(BALL, name="static")
    assert SceneRenderer(static).substeps_for(0) == 1


def test_describe_is_complete_and_json(moving_scene):
    from spikesim.render import SceneRenderer

    d = SceneRenderer(moving_scene, spp=3, seed=11, variant="mono").describe()
    json.dumps(d)
    assert d["render"]["spp"] == 3 and d["render"]["seed"] == 11 and d["render"]["variant"] == "mono"
    assert d["render"]["height"] == 25 and d["render"]["width"] == 40
    assert set(d["sha256"]) == {"xml", "motion", "lights"}
    assert d["exposure"]["threshold_electrons"] == 1000.0
    assert d["light"]["emitters"][1]["luminous_flux_lm"] == pytest.approx(500)


def test_camera_object_sets_resolution_and_exposure(moving_scene):
    from types import SimpleNamespace

    from spikesim.render import SceneRenderer

    cam = SimpleNamespace(height=10, width=16, readout_period_s=50e-6, threshold_electrons=2000.0)
    r = SceneRenderer(moving_scene, camera=cam, spp=1)
    assert r.render_step(0).shape == (10, 16)
    assert r.exposure.readout_period_s == 50e-6 and r.exposure.threshold_electrons == 2000.0
    assert r.time_of(2) == pytest.approx(2.5 * 50e-6)


def test_rgb_is_for_previews_only(moving_scene):
    from spikesim.render import SceneRenderer

    r = SceneRenderer(moving_scene, variant="rgb", spp=1)
    assert r.preview_rgb(0, spp=2).shape == (25, 40, 3)
    with pytest.raises(ValueError, match="preview"):
        r.render_step(0)


def test_ground_truth_spreads_its_samples_over_its_substeps(make_scene, monkeypatch):
    """gt_spp are a ground-truth image's samples in all, ceil(gt_spp / s) in each of its s motion-blur
    renders (a renderer with motion blur of its own spreads them over the shutter); a frame's spp
    are each render's, which the sample rule's probes measure."""
    from spikesim.render import SceneRenderer
    from spikesim.render import renderer as module
    from spikesim.render.renderer import samples_per_substep

    assert [samples_per_substep(128, s) for s in (1, 2, 3, 16)] == [128, 64, 43, 8]
    assert samples_per_substep(1, 3) == 1  # never below one sample a render
    fast = {"objects": [{"targets": ["ball"], "motions": [{"type": "translation", "velocity_mps": [200.0, 0, 0]}]}]}
    xml = make_scene(BALL, motion=fast)
    r = SceneRenderer(xml, spp=2, gt_spp=9, substeps=3)
    asked: list[int] = []
    render = module.mi.render
    monkeypatch.setattr(module.mi, "render", lambda scene, spp, seed: asked.append(spp) or render(scene, spp=spp, seed=seed))
    r.ground_truth(0)
    assert asked == [3, 3, 3]
    asked.clear()
    r.render_step(0)
    assert asked == [2, 2, 2]
    asked.clear()
    r.ground_truth(0, spp=4)
    assert asked == [2, 2, 2]
