"""The `fast` quality is the rule of spikesim.preset_rule applied to the shipped 400 x 250 study,
and the light rule chooses each scene's samples where generation and its estimate run."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from spikesim.generation import PRESETS as SIZES, plan_llr
from spikesim.generation.estimate import Calibration, planned_work, with_motion_plans
from spikesim.preset_rule import (FAST_TOLERANCE_DB, STUDY_CSV, cheapest_spp, choose_fast, gt_spp_needed,
                                  light_split, load_study)
from spikesim.quality import PRESETS, LowLight, QualitySettings, light_level


# ---- the preset is the rule applied to the shipped study -----------------------------------------
def test_fast_preset_is_the_rule_applied_to_the_shipped_study():
    rows = load_study()
    choice = choose_fast(rows)
    fast = PRESETS["fast"]
    assert fast.low_light == LowLight(y_max=choice.low_light_y, spp=choice.low_light_spp,
                                      gt_spp=choice.low_light_gt_spp)
    assert (fast.spp, fast.gt_spp) == (choice.spp, choice.gt_spp)
    assert choice.tolerance_db == FAST_TOLERANCE_DB
    # what the study shows (docs/tradeoff.md section 7): dark scenes need fewer samples per step
    assert choice.low_light_spp < choice.spp
    assert fast.keyframe_policy == "every" and fast.noise == "all"


def test_the_shipped_study_covers_both_lights_and_every_scene_it_names():
    rows = load_study(STUDY_CSV)
    pairs = {(r["scene"], r["light"]) for r in rows if r["knob"] != "gt"}
    scenes = {s for s, _ in pairs}
    assert pairs == {(s, l) for s in scenes for l in ("low", "normal")}
    from scenes import SCENES
    assert scenes == set(SCENES)  # every LLR scene, both lights
    for r in rows:
        if r["knob"] != "gt":
            assert r["ref_y_median"] > 0 and math.isfinite(r["net_gt_floor"])


# ---- the rule on made-up studies -----------------------------------------------------------------
def _block(scene, light, y, losses, floor=0.02, ref_psnr=25.0):
    """Run rows of one scene-light: the reference and `spp=N` runs with the given loss (dB, both axes)."""
    base = {"scene": scene, "light": light, "ref_y_median": y, "tfp_gt_floor": floor, "net_gt_floor": floor,
            "gt_spp": math.nan, "gt_self_err": math.nan, "gt_self_psnr": math.nan}
    rows = [{**base, "run": "reference", "knob": "reference", "tfp_gt_dpsnr": 0.0, "net_gt_dpsnr": 0.0,
             "tfp_gt_psnr": ref_psnr - 5, "net_gt_psnr": ref_psnr}]
    rows += [{**base, "run": f"spp={s}", "knob": "spp", "tfp_gt_dpsnr": -loss, "net_gt_dpsnr": -loss / 2,
              "tfp_gt_psnr": math.nan, "net_gt_psnr": math.nan} for s, loss in losses.items()]
    return rows


def _gt_rows(scene, light, e1, ref_spp=128, measured=(16, 64)):
    """Ground-truth error rows whose single-sample error is e1 (aligned-PSNR units)."""
    rows = [{"scene": scene, "light": light, "run": f"gt spp={ref_spp}", "knob": "gt", "gt_spp": ref_spp,
             "gt_self_err": 0.0, "gt_self_psnr": math.inf}]
    for s in measured:
        e_self = e1 * (1 / s + 1 / ref_spp)
        rows.append({"scene": scene, "light": light, "run": f"gt spp={s}", "knob": "gt", "gt_spp": s,
                     "gt_self_err": 0.1, "gt_self_psnr": -10 * math.log10(e_self)})
    return rows


def test_cheapest_spp_is_the_fewest_samples_within_the_floor_or_tolerance_in_every_scene():
    rows = (_block("a", "normal", 0.08, {1: 0.5, 2: 0.09, 4: 0.01}) +
            _block("b", "normal", 0.06, {1: 0.3, 2: 0.3, 4: 0.05}))
    assert cheapest_spp(rows, "normal", 0.1)[0] == 4  # spp 2 fails in b
    assert cheapest_spp(rows, "normal", 0.5)[0] == 1
    wide_floor = (_block("a", "normal", 0.08, {1: 0.5, 2: 0.09}, floor=0.4) +
                  _block("b", "normal", 0.06, {1: 0.3, 2: 0.3}, floor=0.4))
    assert cheapest_spp(wide_floor, "normal", 0.1)[0] == 2  # within a floor wider than the tolerance
    missing = _block("a", "normal", 0.08, {1: 0.0, 2: 0.0}) + _block("b", "normal", 0.06, {2: 0.0})
    assert cheapest_spp(missing, "normal", 0.1)[0] == 2  # spp 1 unmeasured in b: not vouched for
    with pytest.raises(ValueError, match="no measured spp keeps normal light within 0.1 dB"):
        cheapest_spp(_block("a", "normal", 0.08, {1: 1.0, 4: 0.5}), "normal", 0.1)
    with pytest.raises(ValueError, match="no 'low' light"):
        cheapest_spp(rows, "low", 0.1)


def test_a_nan_score_is_never_within_the_tolerance():
    rows = _block("a", "low", 1e-3, {1: 0.0, 2: 0.0})
    rows[1]["net_gt_dpsnr"] = math.nan  # spp=1 not scored by the network
    assert cheapest_spp(rows, "low", 0.1)[0] == 2


def test_light_split_is_the_geometric_mean_between_the_classes_and_refuses_overlap():
    rows = _block("a", "low", 1e-3, {}) + _block("b", "low", 4e-3, {}) + _block("a", "normal", 0.064, {})
    assert light_split(rows) == pytest.approx(math.sqrt(4e-3 * 0.064))
    with pytest.raises(ValueError, match="overlap"):
        light_split(_block("a", "low", 0.1, {}) + _block("a", "normal", 0.05, {}))
    with pytest.raises(ValueError, match="both lights"):
        light_split(_block("a", "low", 0.1, {}))


def test_ground_truth_samples_follow_the_error_budget_and_stop_at_the_reference():
    # e1 = 0.01, best score 30 dB (e_R = 1e-3), tol 0.1 dB: spp >= 0.01 / (1e-3 (10^0.01 - 1)) = 429
    rows = _block("a", "normal", 0.08, {}, ref_psnr=30.0) + _gt_rows("a", "normal", 0.01, ref_spp=1024)
    spp, ev = gt_spp_needed(rows, "normal", 0.1)
    assert ev["a_normal"]["spp_needed"] == pytest.approx(0.01 / (1e-3 * (10 ** 0.01 - 1)), rel=1e-3)
    assert spp == 512
    capped = _block("a", "normal", 0.08, {}, ref_psnr=30.0) + _gt_rows("a", "normal", 0.01, ref_spp=128)
    assert gt_spp_needed(capped, "normal", 0.1)[0] == 128  # no better than the study's own
    # a lower score tolerates a noisier ground truth: 20 dB needs a tenth of that
    dark = _block("a", "low", 1e-3, {}, ref_psnr=20.0) + _gt_rows("a", "low", 0.01, ref_spp=1024)
    assert gt_spp_needed(dark, "low", 0.1)[0] == 64
    with pytest.raises(ValueError, match="no ground-truth error rows"):
        gt_spp_needed(_block("a", "low", 1e-3, {}), "low", 0.1)


def test_a_study_without_the_light_level_is_refused(tmp_path):
    p = tmp_path / "old.csv"
    p.write_text("scene,light,run,knob\nball,low,reference,reference\n")
    with pytest.raises(ValueError, match="ref_y_median"):
        load_study(p)
    with pytest.raises(FileNotFoundError, match="not found"):
        load_study(tmp_path / "none.csv")
    with pytest.raises(ValueError, match="tol_db"):
        choose_fast(load_study(), tol_db=0.0)


# ---- the light rule in QualitySettings -----------------------------------------------------------
def test_for_light_switches_the_render_knobs_at_the_split_and_records_them():
    q = QualitySettings.of("t", keyframe_policy="every", spp=8, gt_spp=64, low_light=LowLight(0.01, 1, 16))
    dark, bright = q.for_light(0.01), q.for_light(0.0101)
    assert (dark.spp, dark.gt_spp) == (1, 16) and (bright.spp, bright.gt_spp) == (8, 64)
    assert dark.low_light is None and bright.low_light is None  # what rendered, not the rule
    assert json.loads(json.dumps(q.record()))["settings"]["low_light"] == {"y_max": 0.01, "spp": 1, "gt_spp": 16}
    assert PRESETS["balanced"].for_light(0.0) is PRESETS["balanced"]  # no rule: unchanged
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="light level"):
            q.for_light(bad)


@pytest.mark.parametrize("kwargs,field", [(dict(y_max=0.0, spp=1, gt_spp=1), "y_max"),
                                          (dict(y_max=math.nan, spp=1, gt_spp=1), "y_max"),
                                          (dict(y_max=True, spp=1, gt_spp=1), "y_max"),
                                          (dict(y_max=0.01, spp=0, gt_spp=1), "spp"),
                                          (dict(y_max=0.01, spp=1, gt_spp=True), "gt_spp")])
def test_low_light_knobs_are_validated(kwargs, field):
    with pytest.raises(ValueError, match=field):
        LowLight(**kwargs)


def test_light_level_is_the_median_and_refuses_bad_frames():
    assert light_level(np.array([[0.0, 1.0, 3.0]])) == 1.0
    with pytest.raises(ValueError, match="light level"):
        light_level(np.array([np.nan]))
    with pytest.raises(ValueError, match="light level"):
        light_level(np.zeros(0))


# ---- where it runs: the estimate and run_job -----------------------------------------------------
class _Lit:
    """A renderer stand-in whose frames are at light level y everywhere and that never moves."""

    def __init__(self, y):
        self.y = y

    def render_step(self, step, spp=None):
        return np.full((4, 4), self.y, np.float32)

    def motion_px(self, step):
        return 0.0

    def substeps_for(self, step):
        return 1


def test_the_estimate_takes_each_lights_samples_from_its_probe_frame():
    jobs = plan_llr(SIZES["small"], scenes=["ball", "fan"], quality="fast")  # 2 scenes x 2 lights
    works = [planned_work(j) for j in jobs]
    assert {w.spp for w in works} == {PRESETS["fast"].spp}  # planned at the quality's own knobs
    low = PRESETS["fast"].low_light
    out, n = with_motion_plans(jobs, works, load=lambda j: _Lit(low.y_max / 10 if j.source["light"] == "low" else 1.0))
    assert n == 4  # with a light rule each light is read
    for j, w in zip(jobs, out):
        want = (low.spp, low.gt_spp) if j.source["light"] == "low" else (PRESETS["fast"].spp, PRESETS["fast"].gt_spp)
        assert (w.spp, w.gt_spp) == want
    cal = Calibration("x", works[0].pixels, startup_s=0.0, fixed_s=0.0, per_sample_pixel_s=1e-7,
                      sensor_per_pixel_step_s=0.0)
    ball = {j.source["light"]: dataclasses.replace(w, render_scale=1.0) for j, w in zip(jobs, out)
            if j.source["scene"] == "ball"}
    assert ball["normal"].seconds(cal) > ball["low"].seconds(cal)


def test_an_unread_job_gets_the_mean_samples_of_its_light(monkeypatch):
    import spikesim.generation.estimate as est
    monkeypatch.setattr(est, "MOTION_SAMPLE_SCENES", 2)
    jobs = plan_llr(SIZES["small"], scenes=["ball", "fan"], quality="fast")
    works = [planned_work(j) for j in jobs]
    low = PRESETS["fast"].low_light
    out, n = with_motion_plans(jobs, works, load=lambda j: _Lit(0.0 if j.source["light"] == "low" else 1.0))
    assert n == 2
    for j, w in zip(jobs, out):
        assert w.spp == (low.spp if j.source["light"] == "low" else PRESETS["fast"].spp)


def test_generate_with_the_light_rule_renders_and_records_each_lights_samples(tmp_path):
    pytest.importorskip("mitsuba")
    from spikesim.dataset import open_dataset
    from spikesim.generation import generate
    preset = SIZES["small"].replace(height=16, width=24, llr_windows=1)
    jobs = plan_llr(preset, scenes=["ball"], quality="fast")
    generate(jobs, tmp_path, workers=1, show_progress=False)
    by_light = {s.name.rsplit("_", 1)[1]: s.meta["quality"] for s in open_dataset(tmp_path)}
    low, normal = by_light["low"], by_light["normal"]
    rule = PRESETS["fast"].low_light
    assert low["light_rule"]["low"] and low["light_rule"]["y_level"] <= rule.y_max
    assert (low["settings"]["spp"], low["settings"]["gt_spp"]) == (rule.spp, rule.gt_spp)
    assert not normal["light_rule"]["low"] and normal["light_rule"]["y_level"] > rule.y_max
    assert normal["settings"]["spp"] == PRESETS["fast"].spp
    assert dataclasses.asdict(rule) == low["light_rule"]["low_light"]
