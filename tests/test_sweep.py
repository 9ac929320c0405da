"""`spikesim sweep`: light levels, linear scaling of one render, the saturation edge, the outputs."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from pipelines.sweep import (RenderedScene, light_levels, losing_levels, render_scene, simulate_level, summary,
                             sweep)
from spikesim.camera import SpikeCamera

from sensor_testing import requires_drjit

pytestmark = requires_drjit


def test_light_levels_are_log_spaced_and_checked():
    lv = light_levels(0.1, 1000.0, 5)
    assert np.allclose(lv, [0.1, 1.0, 10.0, 100.0, 1000.0])
    for lo, hi, n in ((1.0, 0.5, 3), (0.0, 1.0, 3), (0.1, float("inf"), 3), (0.1, 1.0, 1)):
        with pytest.raises(ValueError):
            light_levels(lo, hi, n)


def _toy(subject_lux=10.0) -> RenderedScene:
    rng = np.random.default_rng(0)
    frames = rng.uniform(0.0, 0.2, (82, 12, 16)).astype(np.float32)
    gt = {20: frames[:41].mean(0), 61: frames[41:].mean(0)}
    return RenderedScene("toy", frames, gt, subject_lux)


def test_saturation_edge_is_where_p99_of_y_reaches_one():
    sc = _toy()
    p99 = np.percentile(np.concatenate([g.ravel() for g in sc.ground_truth.values()]), 99)
    assert sc.saturation_lux == pytest.approx(10.0 / p99)
    level = simulate_level(sc, sc.saturation_lux, SpikeCamera.noiseless(height=12, width=16), seed=0, backend="numpy")
    assert np.percentile(np.concatenate([g.ravel() for g in level.gt.values()]), 99) == pytest.approx(1.0, rel=1e-5)


def test_a_level_scales_frames_and_truth_linearly():
    """Light transport is linear: at k times the subject's lux, the stream is the camera's at k y."""
    sc = _toy()
    cam = SpikeCamera.noiseless(height=12, width=16)
    level = simulate_level(sc, 30.0, cam, seed=0, backend="numpy")
    from spikesim.simulate import Simulator
    direct = Simulator(cam, backend="numpy", seed=0).run(sc.frames * np.float32(3.0)).unpack()
    assert np.array_equal(level.spikes_all, direct)
    assert np.allclose(level.gt[20], sc.ground_truth[20] * 3.0)


def test_sweep_rows_and_losing_levels():
    from model.methods import method_from_spec

    sc = _toy()
    cam = SpikeCamera.realistic(height=12, width=16)
    methods = [method_from_spec(s) for s in ("tfp", "black")]
    rows = sweep([sc], [1.0, 10.0, 100.0], methods, cam, seed=1, backend="numpy")
    assert len(rows) == 3 * 2 and {r["method"] for r in rows} == {"TFP", "black"}
    table = summary(rows, "psnr_aligned")
    assert set(table["TFP"]) == {1.0, 10.0, 100.0}
    # TFP beats a black image once there is light; where it does not, the level is named
    assert table["TFP"][100.0] > table["black"][100.0]
    assert 100.0 not in losing_levels(rows, "TFP", sc.saturation_lux)
    assert losing_levels(rows, "black", 1e9) != []


def test_render_scene_meters_the_subject():
    cam = SpikeCamera.realistic(height=16, width=24)
    sc = render_scene("fan", "normal", cam, num_windows=1, spp=1, gt_spp=2, seed=0)
    assert sc.frames.shape == (41, 16, 24) and list(sc.ground_truth) == [20]
    assert sc.subject_lux == pytest.approx(110.0, rel=0.05)  # the Fan scene's normal light (docs/scenes.md)


def test_a_scene_lit_by_bounced_light_is_swept_at_its_metered_illuminance():
    """A plain scene whose view centre gets no direct light: the sweep takes the metered total
    (direct and indirect) as its light, where it used to refuse the scene for want of a subject."""
    cam = SpikeCamera.realistic(height=8, width=12)
    sc = render_scene("tests/data/bounce_scene/scene.xml", "normal", cam, num_windows=1, spp=1, gt_spp=2, seed=0)
    assert sc.subject_lux_kind.startswith("total") and 10 < sc.subject_lux < 1000


def test_sweep_command_writes_its_tables(tmp_path):
    out = tmp_path / "sw"
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "sweep", "--scenes", "fan", "--levels", "2",
                        "--windows", "1", "--height", "16", "--width", "24", "--spp", "1", "--gt-spp", "2",
                        "--methods", "tfp", "mean", "--threads", "1", "--quiet", "-o", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "aligned PSNR" in (out / "sweep.md").read_text()
    rec = json.loads((out / "sweep.json").read_text())
    assert len(rec["levels_lux"]) == 2 and rec["scenes"]["fan"]["saturation_lux"] > 0
    assert (out / "sweep.csv").read_text().count("\n") == 1 + 2 * 2
    assert (out / "sweep.png").stat().st_size > 1000


def test_sweep_of_a_users_scene_keeps_its_film_and_samples_and_a_camera_files_size(tmp_path):
    """--xml: the scene's film (40 x 25) and sampler (16 spp) unless a flag says otherwise, as the
    README says a scene keeps them; a camera file's height and width are used, not ignored."""
    base = [sys.executable, "-m", "pipelines.cli", "sweep", "--xml", "tests/data/plain_scene/scene.xml", "--levels",
            "2", "--windows", "1", "--gt-spp", "2", "--methods", "tfp", "--threads", "1", "--no-plot"]
    r = subprocess.run(base + ["--spp", "1", "-o", str(tmp_path / "a")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "height 25 (scene file scene.xml), width 40 (scene file scene.xml), spp 1 (--spp)" in r.stderr
    cam = json.loads((tmp_path / "a" / "sweep.json").read_text())["camera"]
    assert (cam["height"], cam["width"]) == (25, 40)
    camera_file = tmp_path / "cam.json"
    camera_file.write_text(json.dumps({**SpikeCamera.realistic().to_dict(), "height": 12, "width": 20}))
    r = subprocess.run(base + ["--camera", str(camera_file), "--spp", "1", "-o", str(tmp_path / "b")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    cam = json.loads((tmp_path / "b" / "sweep.json").read_text())["camera"]
    assert (cam["height"], cam["width"]) == (12, 20) and "height 12 (--camera cam.json)" in r.stderr


def test_a_sweep_into_a_folder_in_use_is_refused_before_it_renders(tmp_path):
    """Two sweeps into one -o both finished with rc 0 and left one run's tables (issue 40, round 5)."""
    from pipelines.sweep import run_sweep
    from spikesim.generation.lock import OutputLockedError, output_lock
    out = tmp_path / "sw"
    out.mkdir()
    with output_lock(out, "sweep other (pid 4242)", what="sweep run"):
        with pytest.raises(OutputLockedError, match="another sweep run.*4242"):
            run_sweep(["fan"], ["tfp"], [1.0, 10.0], camera=SpikeCamera.realistic(height=12, width=16), windows=1,
                      spp=1, gt_spp=2, out=out)
    assert list(out.iterdir()) == []


def test_a_black_truth_is_refused_and_a_constant_one_has_no_scores(tmp_path):
    """A floor turned away from the camera (black truth) and a level where every pixel saturates
    (one value) scored inf dB and SSIM 1 for every method, in bold (round six)."""
    from pipelines.sweep import markdown, run_sweep
    from spikesim.render.errors import SceneError
    cam = SpikeCamera.realistic(height=12, width=16)
    with pytest.raises(ValueError, match="at least 11 x 11"):
        run_sweep(["fan"], ["tfp"], [1.0, 10.0], camera=SpikeCamera.realistic(height=8, width=12), windows=1)
    text = open("tests/data/plain_scene/scene.xml").read().replace(
        '<shape type="rectangle" id="floor">',
        '<shape type="rectangle" id="floor"><transform name="to_world"><rotate x="1" angle="180"/></transform>')
    (tmp_path / "back").mkdir()
    (tmp_path / "back" / "scene.xml").write_text(text)
    with pytest.raises(SceneError, match="ground truth is black"):
        render_scene(str(tmp_path / "back" / "scene.xml"), "normal", cam, num_windows=1, spp=1, gt_spp=2, seed=0)
    result = run_sweep(["tests/data/plain_scene/scene.xml"], ["tfp", "mean"], [1.0, 1e6], camera=cam, windows=1,
                       spp=1, gt_spp=2)
    bright = [r for r in result.rows if r["lux"] == 1e6]
    assert bright and all(r["ground_truth_constant"] and np.isnan(r["psnr_aligned"]) for r in bright)
    dim = [r for r in result.rows if r["lux"] == 1.0]
    assert all(not r["ground_truth_constant"] and np.isfinite(r["psnr_aligned"]) for r in dim)
    assert "| n/a | n/a |" in result.markdown and "inf" not in result.markdown


def test_render_scene_refuses_frames_beyond_memory():
    with pytest.raises(ValueError, match="GiB of memory"):
        render_scene("fan", "normal", SpikeCamera.realistic(height=2000, width=4000), num_windows=100, spp=1,
                     gt_spp=1, seed=0)


def test_sweep_command_refuses_bad_input(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "sweep", "--lux-min", "10", "--lux-max", "1",
                        "-o", str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--lux-min" in r.stderr
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "sweep", "--scenes", "fan", "--methods", "tfp", "tfp",
                        "-o", str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "unique" in r.stderr


@pytest.mark.parametrize("lo, hi, n", [(1e-300, 1.0, 3), (1e-42, 1.0, 3), (0.1, 1e300, 3), (0.1, 10.0, 1_000_000_000)])
def test_light_levels_outside_what_float32_frames_hold_are_refused(lo, hi, n):
    """--lux-min 1e-42 gave all-zero frames scored 'inf' dB; --levels 1e9 tried to allocate 7.45 GiB."""
    from pipelines.sweep import light_levels
    with pytest.raises(ValueError, match="lux|levels"):
        light_levels(lo, hi, n)


def test_a_script_runs_a_sweep_without_the_command_line(tmp_path):
    """run_sweep is the job as a library function: the same rows and record the command writes,
    in memory, with or without an output folder; a scene given twice is refused, not scored twice."""
    from pipelines.sweep import run_sweep
    camera = SpikeCamera.realistic(height=16, width=24)
    result = run_sweep(["fan"], ["tfp", "mean"], levels=[1.0, 100.0], camera=camera, windows=1, spp=1, gt_spp=2)
    assert len(result.rows) == 2 * 2 and result.record["scenes"]["fan"]["saturation_lux"] > 0
    assert {r["method"] for r in result.rows} == {"TFP", "mean"} and "aligned SSIM" in result.markdown
    assert all(r["ssim_aligned"] == pytest.approx(0.0, abs=1e-9) for r in result.rows if r["method"] == "mean")
    with pytest.raises(ValueError, match="fan given twice"):
        run_sweep(["fan", "fan"], ["tfp"], levels=[1.0, 100.0], camera=camera, windows=1, spp=1, gt_spp=2)


@pytest.mark.parametrize("kwargs, says", [
    ({"scenes": []}, "scenes: expected a non-empty list"),
    ({"scenes": "ball"}, "scenes: expected a non-empty list"),
    ({"methods": []}, "methods: expected a non-empty list"),
    ({"levels": []}, "at least one level"),
    ({"levels": [-1.0]}, "each in"),
    ({"levels": [float("nan")]}, "each in"),
    ({"levels": "10"}, "expected lux values"),
    ({"camera": "realistic"}, "expected a SpikeCamera"),
])
def test_run_sweep_checks_its_arguments_before_rendering(kwargs, says):
    from pipelines.sweep import run_sweep
    args = {"scenes": ["fan"], "methods": ["tfp"], "levels": [1.0, 10.0], **kwargs}
    with pytest.raises((ValueError, TypeError), match=says):
        run_sweep(args.pop("scenes"), args.pop("methods"), args.pop("levels"), **args)
