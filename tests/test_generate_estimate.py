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

