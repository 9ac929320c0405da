"""Dataset generation: layout, manifest, verify, resume, determinism, parallel workers.
These use the built-in pattern as the irradiance source (no renderer), so they are fast."""
import json
import shutil

import numpy as np
import pytest

from spikesim.generation import PRESETS, SceneJob, generate, job_status, llr_windows, plan_rllr
from spikesim.dataset import open_dataset, verify


def tiny_jobs(n=2, steps=82):
    preset = PRESETS["small"].replace(height=12, width=32, rllr_steps=steps, rllr_gt_stride=41)
    return plan_rllr(preset, seed=1, count=n, source="pattern")


def test_windows_and_centres():
    wins, centres = llr_windows(21)
    assert wins[0] == (0, 41) and wins[-1] == (820, 861) and centres[:2] == (20, 61)


def test_generate_verify_and_read_back(tmp_path):
    jobs = tiny_jobs()
    report = generate(jobs, tmp_path, workers=1, show_progress=False)
    assert len(report["generated"]) == 2 and verify(tmp_path) == []
    scenes = open_dataset(tmp_path)
    assert [s.name for s in scenes] == ["rllr_0000", "rllr_0001"]
    s = scenes[0]
    assert s.num_steps == 82 and s.gt_steps == [20, 61] and s.spikes(0, 41).shape == (41, 12, 32)
    meta = s.meta
    # RLLR darkening: a factor in (0, 1) recorded, and applied to the ground truth
    f = meta["light_power_factor"]
    assert 0 < f < 1
    from spikesim.patterns import MovingPattern
    p = MovingPattern(height=12, width=32, peak_y=0.3, seed=meta["job"]["source"]["pattern_seed"])
    assert np.allclose(s.ground_truth(61), p.frame(61) * np.float32(f))
    # the stream's mean rate follows the darkened light
    assert s.spikes().mean() == pytest.approx(p.frame(61).mean() * f, rel=0.25, abs=0.01)


def test_verify_names_altered_and_missing_files(tmp_path):
    generate(tiny_jobs(), tmp_path, workers=1, show_progress=False)
    dat = tmp_path / "rllr_0000" / "spikes.dat"
    data = bytearray(dat.read_bytes())
    data[10] ^= 0xFF
    dat.write_bytes(bytes(data))
    (tmp_path / "rllr_0001" / "gt" / "step_000061.exr").unlink()
    with open(tmp_path / "rllr_0001" / "spikes.dat", "ab") as f:
        f.write(b"\x00")
    problems = verify(tmp_path)
    assert any("rllr_0000/spikes.dat" in p and "checksum" in p for p in problems)
    assert any("step_000061.exr: missing" in p for p in problems)
    assert any("rllr_0001/spikes.dat" in p and "bytes" in p for p in problems)


def test_resume_regenerates_only_what_is_missing_and_reproduces_bytes(tmp_path):
    jobs = tiny_jobs()
    generate(jobs, tmp_path, workers=1, show_progress=False)
    before = (tmp_path / "rllr_0001" / "spikes.dat").read_bytes()
    shutil.rmtree(tmp_path / "rllr_0001")
    (tmp_path / ".rllr_0001.part").mkdir()  # debris of an interrupted run
    report = generate(jobs, tmp_path, workers=1, show_progress=False)
    assert [r["name"] for r in report["generated"]] == ["rllr_0001"] and report["skipped"] == 1
    assert (tmp_path / "rllr_0001" / "spikes.dat").read_bytes() == before
    assert verify(tmp_path) == []


def test_changed_parameters_are_not_silently_mixed(tmp_path):
    jobs = tiny_jobs(1)
    generate(jobs, tmp_path, workers=1, show_progress=False)
    changed = [SceneJob(**{**jobs[0].__dict__, "seed": 99})]
    assert job_status(changed[0], tmp_path) == "stale"
    with pytest.raises(FileExistsError, match="other parameters"):
        generate(changed, tmp_path, workers=1, show_progress=False)
    generate(changed, tmp_path, workers=1, show_progress=False, overwrite_stale=True)
    assert json.loads((tmp_path / "rllr_0000" / "meta.json").read_text())["seed"] == 99


def test_an_interrupted_job_leaves_no_complete_looking_folder(tmp_path, monkeypatch):
    import spikesim.generation.job as g
    jobs = tiny_jobs(1)

    def boom(self, step):
        raise KeyboardInterrupt

    monkeypatch.setattr(g._FrameSource, "ground_truth", boom)
    with pytest.raises(KeyboardInterrupt):
        generate(jobs, tmp_path, workers=1, show_progress=False)
    assert not (tmp_path / "rllr_0000").exists()
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == []


def test_parallel_workers_give_the_same_bytes(tmp_path):
    jobs = tiny_jobs(2)
    generate(jobs, tmp_path / "a", workers=1, show_progress=False)
    generate(jobs, tmp_path / "b", workers=2, show_progress=False)
    for name in ("rllr_0000", "rllr_0001"):
        assert (tmp_path / "a" / name / "spikes.dat").read_bytes() == (tmp_path / "b" / name / "spikes.dat").read_bytes()


# Ray runs in a child process: ray.shutdown() leaves Ray's native threads (its GCS client and gRPC
# threads, 7 counted) in the process that called ray.init, clients of a cluster that is gone; the
# test session need not carry them through the rest of the suite.
RAY_CHILD = """
import json, sys
from pathlib import Path
import ray
from spikesim.generation import PRESETS, generate, plan_rllr
root, repo = Path(sys.argv[1]), sys.argv[2]
preset = PRESETS["small"].replace(height=12, width=32, rllr_steps=82, rllr_gt_stride=41)
jobs = plan_rllr(preset, seed=1, count=2, source="pattern")
ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False,
         runtime_env={"env_vars": {"PYTHONPATH": repo}})
try:
    first = generate(jobs, root, ray_address="local", show_progress=False)
    again = generate(jobs, root, ray_address="local", show_progress=False)
finally:
    ray.shutdown()
print(json.dumps({"generated": first["generated"], "again_generated": again["generated"],
                  "again_skipped": again["skipped"]}))
"""


def test_ray_generation_matches_local(tmp_path):
    # One Ray task per scene on a local Ray instance started in a child process; same bytes and
    # manifest behaviour as the process pool. (Point --ray at a cluster address to scale out.)
    import importlib.util
    import os
    import subprocess
    import sys
    from pathlib import Path
    if importlib.util.find_spec("ray") is None:
        pytest.skip("Ray is an optional extra: pip install 'spikesim[cluster]'")
    repo = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [repo, os.environ.get("PYTHONPATH")]))}
    child = subprocess.run([sys.executable, "-c", RAY_CHILD, str(tmp_path / "ray"), repo], cwd=repo, env=env,
                           capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stderr[-3000:]
    report = json.loads(child.stdout.strip().splitlines()[-1])
    assert len(report["generated"]) == 2
    assert report["again_skipped"] == 2 and report["again_generated"] == []
    jobs = tiny_jobs(2)
    generate(jobs, tmp_path / "local", workers=1, show_progress=False)
    assert verify(tmp_path / "ray") == []
    for name in ("rllr_0000", "rllr_0001"):
        assert (tmp_path / "ray" / name / "spikes.dat").read_bytes() == (tmp_path / "local" / name / "spikes.dat").read_bytes()


def test_rllr_random_scene_end_to_end(tmp_path):
    # A random 3D scene (objects, textures, motions, lights) rendered and simulated: tiny size.
    pytest.importorskip("mitsuba")
    preset = PRESETS["small"].replace(height=20, width=32, rllr_steps=42, rllr_gt_stride=41, spp=1, gt_spp=4)
    jobs = plan_rllr(preset, seed=3, count=1)
    generate(jobs, tmp_path, workers=1, show_progress=False)
    (s,) = open_dataset(tmp_path)
    assert s.num_steps == 42 and s.gt_steps == [20]
    gt = s.ground_truth(20)
    assert gt.shape == (20, 32) and np.isfinite(gt).all() and gt.max() > 0
    assert s.meta["source"]["scene"] and 0 < s.meta["light_power_factor"] < 1
    assert verify(tmp_path) == []
    # the random scene's temporary folder does not leak into meta.json: same job, same bytes
    generate(jobs, tmp_path / "again", workers=1, show_progress=False)
    for f in ("meta.json", "spikes.dat", "gt/step_000020.exr"):
        assert (tmp_path / "rllr_0000" / f).read_bytes() == (tmp_path / "again" / "rllr_0000" / f).read_bytes(), f


def test_random_scenes_are_reproducible(tmp_path):
    from scenes.random_scene import build_random_scene
    a = build_random_scene(5, tmp_path / "a", resolution=(20, 32))
    b = build_random_scene(5, tmp_path / "b", resolution=(20, 32))
    for x, y in zip(a[:3], b[:3]):
        assert x.read_text() == y.read_text()
    assert build_random_scene(6, tmp_path / "c")[0].read_text() != a[0].read_text()


@pytest.mark.timeout(300)
def test_process_pool_renders_scenes(tmp_path):
    # Two rendered scenes in two worker processes: guards against the Dr.Jit one-thread-pool
    # deadlock (a worker with dr.set_thread_count(1) never finished a Mitsuba render).
    pytest.importorskip("mitsuba")
    preset = PRESETS["small"].replace(height=16, width=24, rllr_steps=10, rllr_gt_stride=9, spp=1, gt_spp=2)
    jobs = plan_rllr(preset, seed=4, count=2)
    report = generate(jobs, tmp_path, workers=2, show_progress=False)
    assert len(report["generated"]) == 2 and verify(tmp_path) == []


def test_quality_preset_is_applied_and_recorded(tmp_path):
    pytest.importorskip("mitsuba")
    preset = PRESETS["small"].replace(height=16, width=24, llr_windows=1)
    from spikesim.generation import plan_llr
    jobs = plan_llr(preset, scenes=["rotate"], lights=("low",), quality="draft")
    assert jobs[0].digest != plan_llr(preset, scenes=["rotate"], lights=("low",))[0].digest
    generate(jobs, tmp_path, workers=1, show_progress=False)
    (s,) = open_dataset(tmp_path)
    q = s.meta["quality"]
    assert q["quality"] == "draft" and q["settings"]["keyframe_policy"] == "adaptive"
    assert {d["term"] for d in q["noise_decisions"]} and s.num_steps == 41
    assert s.meta["simulator"]["camera"]["precision"] == "float32"
    with pytest.raises(ValueError, match="unknown quality"):
        SceneJob(**{**jobs[0].__dict__, "quality": "ultra"})


@pytest.mark.parametrize("change,field", [({"keyframe_every": 0}, "keyframe_every"),
                                          ({"render": {"spp": 0}}, "spp"),
                                          ({"render": {"variant": "fast"}}, "variant")])
def test_a_job_checks_its_render_knobs_where_every_render_setting_is_checked(change, field):
    """A job's render knobs get RenderSettings' checks when the job is made, not a failure deep in
    a worker after the output folder is locked."""
    from spikesim.camera import SpikeCamera
    base = dict(name="j", source={"type": "pattern", "peak_y": 0.3},
                camera=SpikeCamera.realistic(height=4, width=8).to_dict(), render={}, num_steps=4, gt_steps=(0,))
    with pytest.raises(ValueError, match=rf"job j: .*{field}"):
        SceneJob(**{**base, **change})
