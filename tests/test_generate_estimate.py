"""`generate` says what it will do before it starts: the renders it plans (as the jobs count them)
and, for a large plan, a time from a calibration on one of its own scenes."""
from __future__ import annotations

import dataclasses

import pytest

from spikesim.generation.estimate import (ESTIMATE_MIN_RENDERS, Calibration, estimate, planned_work,
                                          share_out)
from spikesim.generation.plan import PRESETS, plan_llr, plan_rllr
from spikesim.keyframes import keyframe_count


def test_planned_renders_are_the_jobs_keyframes_and_ground_truth():
    preset = PRESETS["small"]
    for job in plan_llr(preset, scenes=["fan"]) + plan_rllr(preset, count=1):
        work = planned_work(job)
        assert work.frame_renders == keyframe_count(job.num_steps, job.keyframe_every)
        assert work.gt_renders == len(job.gt_steps) and work.steps == job.num_steps
        assert work.pixels == job.camera["height"] * job.camera["width"]
        assert (work.spp, work.gt_spp) == (preset.render.spp, preset.render.gt_spp)
    wide = dataclasses.replace(job, keyframe_every=4)
    assert planned_work(wide).frame_renders == keyframe_count(job.num_steps, 4)


def test_jobs_are_shared_out_over_the_workers_largest_first():
    assert share_out([3.0, 2.0, 2.0, 1.0], 2) == 4.0  # {3, 1} and {2, 2}
    assert share_out([5.0, 1.0], 4) == 5.0 and share_out([1.0] * 6, 1) == 6.0 and share_out([], 2) == 0.0


def test_the_time_is_the_renders_and_pixel_steps_at_the_calibrated_rates():
    job = plan_llr(PRESETS["small"], scenes=["fan"], lights=("low",))[0]
    work = planned_work(job)
    cal = Calibration("x", work.pixels, startup_s=2.0, fixed_s=0.03, per_sample_pixel_s=1e-7,
                      sensor_per_pixel_step_s=1e-8)
    want = (2.0 + work.frame_renders * (0.03 + 1e-7 * work.spp * work.pixels)
            + work.gt_renders * (0.03 + 1e-7 * work.gt_spp * work.pixels) + work.steps * work.pixels * 1e-8)
    assert work.seconds(cal) == pytest.approx(want)
    one = estimate([job], 1, calibration=cal)
    assert one.seconds == pytest.approx(want) and "estimate" in one.summary() and "calibrated on x" in one.summary()


def test_a_small_plan_starts_without_a_calibration_and_a_large_one_is_calibrated_on_its_own_scene():
    jobs = plan_llr(PRESETS["small"], scenes=["fan"])
    small = estimate(jobs, 2)
    assert small.calibration is None and small.renders + small.gt_renders < ESTIMATE_MIN_RENDERS
    assert "no time estimate for a plan this small" in small.summary()
    forced = estimate(jobs[:1], 1, calibrate_at=0)  # a few seconds: load the scene, render, run the sensor
    c = forced.calibration
    assert c is not None and c.scene == jobs[0].name and c.startup_s > 0 and c.fixed_s >= 0
    assert c.per_sample_pixel_s >= 0 and c.sensor_per_pixel_step_s > 0 and forced.seconds > c.startup_s


def test_generate_logs_the_plan_before_it_starts(tmp_path, caplog):
    from spikesim.generation.run import generate
    job = plan_llr(PRESETS["small"], scenes=["fan"], lights=("low",))[0]
    with caplog.at_level("INFO", logger="spikesim.generate"):
        generate([job], tmp_path / "ds", workers=1, show_progress=False, estimate_time=True)
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("plan:")]
    assert len(lines) == 1 and "estimate" in lines[0] and f"calibrated on {job.name}" in lines[0]
    caplog.clear()
    with caplog.at_level("INFO", logger="spikesim.generate"):
        generate([dataclasses.replace(job, name="again")], tmp_path / "ds2", workers=1, show_progress=False,
                 estimate_time=False)
    assert not [r for r in caplog.records if r.getMessage().startswith("plan:")]



class _FakeRenderer:
    """motion_px and substeps_for as SceneRenderer has them: `moving` steps move 0.2 px, the others
    stand still; a step moving more than `blur_px` takes two sub-steps."""

    def __init__(self, moving: set[int], blur_px: float = 1.0, px: float = 0.2):
        self.moving, self.blur_px, self.px = moving, blur_px, px

    def motion_px(self, step: int) -> float:
        return self.px if step in self.moving else 0.0

    def substeps_for(self, step: int) -> int:
        return 2 if self.motion_px(step) > self.blur_px else 1


def test_adaptive_jobs_count_the_renders_their_motion_plan_makes():
    from spikesim.generation.estimate import adaptive_policy, frame_render_count
    from spikesim.render.adaptive import motion_plan
    job = plan_llr(PRESETS["small"], scenes=["fan"], lights=("low",), quality="balanced")[0]
    policy = adaptive_policy(job)
    assert policy is not None
    still = _FakeRenderer(set())
    assert frame_render_count(still, job) == 1  # a static scene: one render, reused
    half = _FakeRenderer(set(range(job.num_steps // 2)))
    plan = motion_plan(half, 0, job.num_steps - 1, policy)
    want = 1 + sum(1 for _, changed in plan[1:] if changed)
    assert frame_render_count(half, job) == want and 1 < want < job.num_steps
    fast = _FakeRenderer(set(range(job.num_steps)), blur_px=0.1)  # every step blurred: two renders each
    assert frame_render_count(fast, job) == 2 * (1 + sum(1 for _, c in motion_plan(fast, 0, job.num_steps - 1,
                                                                                  policy)[1:] if c))
    fixed = dataclasses.replace(job, quality=None, keyframe_every=4)
    assert adaptive_policy(fixed) is None
    assert frame_render_count(still, fixed) == keyframe_count(job.num_steps, 4)


def test_the_estimate_reads_each_scenes_motion_once_and_gives_the_rest_the_mean(monkeypatch):
    import spikesim.generation.estimate as est
    jobs = plan_llr(PRESETS["small"], scenes=["ball", "fan"], quality="balanced")  # 2 scenes x 2 lights
    works = [planned_work(j) for j in jobs]
    loaded = []

    def load(job):
        loaded.append(job.source["scene"])
        return _FakeRenderer(set() if job.source["scene"] == "ball" else set(range(job.num_steps)))
    out, n = est.with_motion_plans(jobs, works, load=load)
    assert n == 2 and sorted(loaded) == ["ball", "fan"]  # both lights of a scene share its motion
    by_scene = {j.source["scene"]: w.frame_renders for j, w in zip(jobs, out)}
    assert by_scene["ball"] == 1 and 1 < by_scene["fan"] <= works[0].frame_renders
    monkeypatch.setattr(est, "MOTION_SAMPLE_SCENES", 1)  # only ball read: fan gets ball's ratio
    out, n = est.with_motion_plans(jobs, works, load=load)
    assert n == 1 and all(w.frame_renders == 1 for w in out)
    cal = Calibration("x", works[0].pixels, startup_s=1.0, fixed_s=0.03, per_sample_pixel_s=1e-7,
                      sensor_per_pixel_step_s=1e-8)
    e = est.estimate(jobs, 2, calibration=cal, motion_loader=load)
    assert e.renders == len(jobs) and e.motion_scenes == 1 and "read from the motion and render speed of 1 scene" in e.summary()
    plain = est.estimate([dataclasses.replace(j, quality=None) for j in jobs], 2, calibration=cal, motion_loader=load)
    assert plain.renders == sum(w.frame_renders for w in works)  # still scenes: keyframes every k steps, once each


def test_a_scene_that_renders_slower_is_estimated_slower():
    # Each read scene renders once (after a warm-up) at its samples; its render time over the first
    # job's scales its renders, and scenes not read get the mean scale.
    import time as _time
    import spikesim.generation.estimate as est

    class Timed(_FakeRenderer):
        def __init__(self, seconds):
            super().__init__(set())
            self.seconds = seconds

        def render_step(self, step, spp=None):
            _time.sleep(self.seconds)

    jobs = plan_llr(PRESETS["small"], scenes=["ball", "fan"], lights=("low",), quality="balanced")
    works = [planned_work(j) for j in jobs]
    out, n = est.with_motion_plans(jobs, works, load=lambda j: Timed(0.02 if j.source["scene"] == "ball" else 0.1))
    scale = {j.source["scene"]: w.render_scale for j, w in zip(jobs, out)}
    assert n == 2 and scale["ball"] == 1.0 and scale["fan"] > 2.0
    cal = Calibration("x", works[0].pixels, startup_s=0.0, fixed_s=0.03, per_sample_pixel_s=0.0,
                      sensor_per_pixel_step_s=0.0)
    assert out[1].seconds(cal) == pytest.approx(scale["fan"] * out[0].seconds(cal) * out[1].frame_renders
                                                / out[0].frame_renders)


def test_a_moving_scene_is_timed_per_render_not_per_step():
    # render_step renders each motion-blur sub-step of its step, and the plan counts those renders
    # already: a scene whose renders each cost what a still scene's do is as fast, however many
    # sub-steps its steps take. Timing whole steps counted them twice (+24 % on the paper RLLR).
    import time as _time
    import spikesim.generation.estimate as est

    class Timed(_FakeRenderer):
        def render_step(self, step, spp=None):
            _time.sleep(0.05 * self.substeps_for(step))

    jobs = plan_llr(PRESETS["small"], scenes=["ball", "fan"], lights=("low",), quality="balanced")
    works = [planned_work(j) for j in jobs]
    fast = Timed(set(range(jobs[1].num_steps)), blur_px=0.1)  # every step: 2 sub-steps
    out, n = est.with_motion_plans(jobs, works, load=lambda j: fast if j.source["scene"] == "fan" else Timed(set()))
    scale = {j.source["scene"]: w.render_scale for j, w in zip(jobs, out)}
    assert n == 2 and scale["ball"] == 1.0 and 0.7 < scale["fan"] < 1.4
    assert est.one_render_s(fast, 1, 1) == pytest.approx(0.05, rel=0.4)


def test_estimate_only_prints_the_plan_and_writes_nothing(tmp_path, capsys):
    # `generate --estimate-only`: the renders and the time `generate` would print, with a quality's
    # per-scene samples read from every scene asked for, and no output folder made.
    import json

    from pipelines.cli import main
    out = tmp_path / "never"
    args = ["generate", "llr", "--preset", "small", "--scenes", "ball", "--windows", "1", "--height", "16",
            "--width", "24", "--quality", "fast", "--workers", "1", "--estimate-only", "-o", str(out)]
    assert main([*args, "--estimate-scenes", "2", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    e = doc["estimate"]
    assert e["renders"] == 2 * 41 and e["gt_renders"] == 2 and e["seconds"] > 0 and e["scenes_read"] == 2
    assert sum(n for _, n in e["samples"]) == 2 and all(1 <= spp <= 16 for spp, _ in e["samples"])
    assert not out.exists()
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "plan: 82 frame renders and 2 ground-truth renders" in text and "samples per step:" in text
    assert not out.exists()


def test_ground_truth_renders_count_their_motion_blur_substeps():
    # A ground-truth step that moves past the blur threshold renders as several sub-steps, as a
    # frame does; the estimate counted one render per ground-truth step (at 128 spp, the largest
    # renders of a fast RLLR scene).
    import spikesim.generation.estimate as est
    jobs = plan_llr(PRESETS["small"], scenes=["ball", "fan"], lights=("low",), quality="fast")
    works = [est.planned_work(j) for j in jobs]
    fast = _FakeRenderer(set(range(jobs[1].num_steps)), blur_px=0.1)   # every step: 2 sub-steps
    assert est.gt_render_count(fast, jobs[1]) == 2 * len(jobs[1].gt_steps)
    out, n = est.with_motion_plans(jobs, works, load=lambda j: fast if j.source["scene"] == "fan"
                                   else _FakeRenderer(set()), sample_scenes=2)
    by_scene = {j.source["scene"]: w for j, w in zip(jobs, out)}
    assert n == 2
    assert by_scene["fan"].gt_renders == 2 * len(jobs[1].gt_steps)
    assert by_scene["ball"].gt_renders == len(jobs[0].gt_steps)
    assert by_scene["fan"].frame_renders == 2 * works[1].frame_renders
    # A ground-truth image's samples are spread over its sub-steps: its second render adds the
    # fixed cost of a render, not another gt_spp samples.
    cal = est.Calibration("x", 100, startup_s=0.0, fixed_s=0.01, per_sample_pixel_s=1e-6, sensor_per_pixel_step_s=0.0)
    gt_only = dataclasses.replace(by_scene["fan"], frame_renders=0, spp=0)
    images = len(jobs[1].gt_steps)
    want = 2 * images * cal.fixed_s + images * cal.per_sample_pixel_s * gt_only.gt_spp * gt_only.pixels
    assert gt_only.seconds(cal) == pytest.approx(want * gt_only.render_scale, rel=1e-12)


def test_an_adaptive_plan_says_its_uncounted_renders_are_not_the_runs_and_the_read_count_is(tmp_path):
    """Issue 40: the plan line counted a frame at every step (773) where the run rendered another
    number (861). Unread, it now says so; read (--estimate), it equals the renders the run makes,
    probes, motion-blur sub-steps and ground truth included."""
    from spikesim.generation.run import generate
    job = plan_llr(PRESETS["small"], scenes=["fan"], lights=("low",), quality="balanced")[0]
    job = dataclasses.replace(job, num_steps=82, gt_steps=(20, 61), windows=job.windows[:2])
    unread = estimate([job], 1)
    assert unread.calibration is None and unread.adaptive_jobs == 1
    assert "counted as a frame at every step" in unread.summary() and "--estimate reads" in unread.summary()
    cal = Calibration("x", 1, startup_s=1.0, fixed_s=0.01, per_sample_pixel_s=1e-8, sensor_per_pixel_step_s=1e-9)
    read = estimate([job], 1, calibration=cal)
    assert read.motion_scenes == 1 and read.renders < unread.renders
    report = generate([job], tmp_path / "ds", workers=1, show_progress=False, estimate_time=False)
    assert report["generated"][0]["renders"] == read.renders + read.gt_renders
