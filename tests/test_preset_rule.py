"""The `fast` quality is the rule of spikesim.preset_rule applied to the shipped 400 x 250 study,
and its sample rule chooses each scene's samples from probe renders where generation and its
estimate run."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from spikesim.generation import PRESETS as SIZES, plan_llr
from spikesim.generation.estimate import Calibration, planned_work, with_motion_plans
from spikesim.preset_rule import (CHECK_CSV, FAST_TOLERANCE_DB, STUDY_CSV, choose_fast, gt_spp_needed, load_study,
                                  loss_per_ratio)
from spikesim.quality import PRESETS, QualitySettings, SampleRule, monte_carlo_ratio


# ---- the preset is the rule applied to the shipped study -----------------------------------------
def test_fast_preset_is_the_rule_applied_to_the_shipped_study():
    choice = choose_fast(load_study())
    fast = PRESETS["fast"]
    assert fast.sample_rule == SampleRule(loss_db_per_ratio=choice.loss_db_per_ratio, tolerance_db=FAST_TOLERANCE_DB,
                                          max_spp=choice.max_spp)
    assert fast.gt_spp == choice.gt_spp
    assert fast.spp == choice.max_spp  # where no probe reads a scene, the most the study vouches for
    assert choice.tolerance_db == FAST_TOLERANCE_DB
    assert fast.keyframe_policy == "every" and fast.noise == "all"


def _study_blocks():
    out = {}
    for r in load_study() + load_study(CHECK_CSV):
        if r["knob"] != "gt":
            out.setdefault((r["scene"], r["light"]), []).append(r)
    return out


def test_the_rule_keeps_every_study_scene_within_the_tolerance_at_the_samples_it_chooses():
    # The rule's own evidence: at the samples it gives each scene-light of the study and of the
    # check set, and at every measured count above, each loss is within the larger of the noise
    # floor and the tolerance; the study's dark ones get 1 spp; the prediction is never below what
    # was lost at 1 spp where the loss was beyond the tolerance.
    rule = PRESETS["fast"].sample_rule
    for (scene, light), block in _study_blocks().items():
        rho = block[0]["ref_mc_ratio"]
        spp = rule.spp_for(rho)
        runs = {int(r["run"][4:]): r for r in block if r["run"].startswith("spp=")}
        assert any(s >= spp for s in runs) or block[0]["ref_spp"] >= spp, (scene, light, spp)  # measured there
        for s, row in runs.items():
            for axis in ("tfp", "net"):
                loss, floor = -row[f"{axis}_gt_dpsnr"], row[f"{axis}_gt_floor"]
                if s >= spp:  # at the samples chosen and above: within the tolerance
                    assert loss <= max(floor, rule.tolerance_db), (scene, light, s, axis)
                if s == 1 and loss > max(floor, rule.tolerance_db):  # the prediction covers what was lost
                    assert rule.predicted_loss_db(rho, 1) >= loss / (1 - 1 / block[0]["ref_spp"]) - floor
        if light == "low":
            assert spp == 1
    assert {light for _, light in _study_blocks()} == {"low", "normal", "rllr"}


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
            assert r["ref_mc_ratio"] >= 0 and r["ref_spp"] == 32


# ---- the rule on made-up studies -----------------------------------------------------------------
def _block(scene, light, rho, losses, floor=0.02, ref_psnr=25.0, ref_spp=32):
    """Run rows of one scene-light: the reference and `spp=N` runs with the given loss (dB, TFP;
    the network loses half as much)."""
    base = {"scene": scene, "light": light, "ref_y_median": 0.01, "ref_mc_ratio": rho, "ref_spp": ref_spp,
            "tfp_gt_floor": floor, "net_gt_floor": floor, "gt_spp": math.nan, "gt_self_err": math.nan,
            "gt_self_psnr": math.nan}
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


def test_loss_per_ratio_is_the_worst_scene_above_its_floor():
    # a: 0.63 / (1 - 1/32) / 10 = 0.06503 -> 0.066 (scene b); scene a's 1-spp loss is inside its floor, so its
    # large ratio-to-loss does not count; c is dark (ratio 0.5) and loses nothing.
    rows = (_block("a", "normal", 100.0, {1: 0.3, 4: 0.1}, floor=0.4) + _block("b", "normal", 10.0, {1: 0.63, 4: 0.2})
            + _block("c", "low", 0.5, {1: 0.0, 4: 0.0}))
    a, ev = loss_per_ratio(rows, 0.2)
    assert a == 0.066  # rounded up, never below the measured worst
    assert ev["b_normal"] == {"mc_ratio": 10.0, "loss_1spp_db": round(0.63 / (1 - 1 / 32), 3), "counts": True}
    assert ev["c_low"]["loss_1spp_db"] == 0.0 and not ev["c_low"]["counts"] and not ev["a_normal"]["counts"]
    gt = _gt_rows("a", "normal", 1e-4) + _gt_rows("b", "normal", 1e-4) + _gt_rows("c", "low", 1e-4)
    choice = choose_fast(rows + gt, check=[])
    assert choice.loss_db_per_ratio == 0.066 and choice.max_spp == 4
    # a check set's scene that loses more per unit of ratio sets the slope; the cap and the ground
    # truth stay the study's
    check = [r for r in _block("r", "rllr", 10.0, {1: 1.0}) if r["knob"] == "spp"]
    both = choose_fast(rows + gt, check=check)
    assert both.loss_db_per_ratio == math.ceil(1.0 / (1 - 1 / 32) / 10 * 1000) / 1000 and both.max_spp == 4


def test_loss_per_ratio_refuses_a_study_that_cannot_measure_it():
    with pytest.raises(ValueError, match="cannot measure"):
        loss_per_ratio(_block("a", "low", 0.5, {1: 0.0, 2: 0.0}), 0.2)
    with pytest.raises(ValueError, match="no spp=1 run"):
        loss_per_ratio(_block("a", "normal", 5.0, {2: 0.3}), 0.2)
    with pytest.raises(ValueError, match="ref_mc_ratio"):
        loss_per_ratio(_block("a", "normal", math.nan, {1: 0.3}), 0.2)


def test_a_nan_score_does_not_count_as_a_loss():
    rows = _block("a", "normal", 10.0, {1: 0.5})
    rows[1]["net_gt_dpsnr"] = math.nan  # spp=1 not scored by the network: TFP's loss decides
    assert loss_per_ratio(rows, 0.2)[0] == math.ceil(0.5 / (1 - 1 / 32) / 10 * 1000) / 1000


def test_ground_truth_samples_follow_the_error_budget_and_stop_at_the_reference():
    # e1 = 0.01, best score 30 dB (e_R = 1e-3), tol 0.1 dB: spp >= 0.01 / (1e-3 (10^0.01 - 1)) = 429
    rows = _block("a", "normal", 5.0, {}, ref_psnr=30.0) + _gt_rows("a", "normal", 0.01, ref_spp=1024)
    spp, ev = gt_spp_needed(rows, 0.1)
    assert ev["a_normal"]["spp_needed"] == pytest.approx(0.01 / (1e-3 * (10 ** 0.01 - 1)), rel=1e-3)
    assert spp == 512
    capped = _block("a", "normal", 5.0, {}, ref_psnr=30.0) + _gt_rows("a", "normal", 0.01, ref_spp=128)
    assert gt_spp_needed(capped, 0.1)[0] == 128  # no better than the study's own
    # a lower score tolerates a noisier ground truth: 20 dB needs a tenth of that
    dark = _block("a", "low", 0.1, {}, ref_psnr=20.0) + _gt_rows("a", "low", 0.01, ref_spp=1024)
    assert gt_spp_needed(dark, 0.1)[0] == 64
    assert gt_spp_needed(rows + dark, 0.1, light="low")[0] == 64
    with pytest.raises(ValueError, match="no ground-truth error rows"):
        gt_spp_needed(_block("a", "low", 0.1, {}), 0.1)


def test_a_study_without_the_monte_carlo_ratio_is_refused(tmp_path):
    p = tmp_path / "old.csv"
    p.write_text("scene,light,run,knob,ref_y_median\nball,low,reference,reference,0.001\n")
    with pytest.raises(ValueError, match="ref_mc_ratio, ref_spp"):
        load_study(p)
    with pytest.raises(FileNotFoundError, match="not found"):
        load_study(tmp_path / "none.csv")
    with pytest.raises(ValueError, match="tol_db"):
        choose_fast(_block("a", "normal", 10.0, {1: 0.5}), check=[], tol_db=0.0)


# ---- the sample rule and the Monte Carlo ratio ---------------------------------------------------
def test_spp_for_is_the_fewest_samples_within_the_tolerance_up_to_the_cap():
    rule = SampleRule(loss_db_per_ratio=0.05, tolerance_db=0.2, max_spp=16)
    # predicted loss 0.05 rho / spp <= 0.2  <=>  spp >= rho / 4
    assert [rule.spp_for(r) for r in (0.0, 4.0, 4.01, 8.0, 10.0, 30.0, 64.0, 1e6)] == [1, 1, 2, 2, 3, 8, 16, 16]
    assert rule.predicted_loss_db(30.0, 8) == pytest.approx(0.1875)
    for bad in (-1.0, math.nan, math.inf, True):
        with pytest.raises(ValueError, match="Monte Carlo ratio"):
            rule.spp_for(bad)


@pytest.mark.parametrize("kwargs,field", [(dict(loss_db_per_ratio=0.0, tolerance_db=0.2, max_spp=4), "loss_db_per_ratio"),
                                          (dict(loss_db_per_ratio=math.nan, tolerance_db=0.2, max_spp=4), "loss_db_per_ratio"),
                                          (dict(loss_db_per_ratio=0.1, tolerance_db=True, max_spp=4), "tolerance_db"),
                                          (dict(loss_db_per_ratio=0.1, tolerance_db=0.2, max_spp=0), "max_spp"),
                                          (dict(loss_db_per_ratio=0.1, tolerance_db=0.2, max_spp=4, probes=1), "probes")])
def test_sample_rule_knobs_are_validated(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SampleRule(**kwargs)


def test_for_scene_sets_the_samples_and_records_what_rendered():
    rule = SampleRule(loss_db_per_ratio=0.05, tolerance_db=0.2, max_spp=16)
    q = QualitySettings.of("t", keyframe_policy="every", spp=16, gt_spp=64, sample_rule=rule)
    dark, noisy = q.for_scene(1.0), q.for_scene(30.0)
    assert (dark.spp, dark.gt_spp) == (1, 64) and (noisy.spp, noisy.gt_spp) == (8, 64)
    assert dark.sample_rule is None and noisy.sample_rule is None  # what rendered, not the rule
    assert json.loads(json.dumps(q.record()))["settings"]["sample_rule"] == dataclasses.asdict(rule)
    assert "sample_rule" not in PRESETS["balanced"].to_dict()  # no rule: the study's cache keys unchanged
    assert PRESETS["balanced"].for_scene(100.0) is PRESETS["balanced"]


def test_monte_carlo_ratio_is_monte_carlo_over_shot_noise_variance():
    # Probes of a flat y = 0.01 with Monte Carlo noise of variance 1e-6: N_e var / y = 1000 * 1e-6 /
    # 0.01 = 0.1; two probes give the pair's (a - b)^2 / 2 exactly.
    rng = np.random.default_rng(0)
    probes = 0.01 + rng.normal(0, 1e-3, (8, 64, 64))
    assert monte_carlo_ratio(probes, 1000.0) == pytest.approx(0.1, rel=0.02)
    assert monte_carlo_ratio(probes, 100.0) == pytest.approx(0.01, rel=0.02)
    pair = np.array([[[0.2, 0.0]], [[0.0, 0.0]]])
    assert monte_carlo_ratio(pair, 1000.0) == pytest.approx(1000 * (0.02 / 2) / 0.05)
    assert monte_carlo_ratio(np.zeros((2, 3, 3)), 1000.0) == 0.0  # black: nothing to render
    for bad, match in ((np.ones((1, 3, 3)), "n >= 2"), (np.ones((2, 3)), "n >= 2"),
                       (np.full((2, 3, 3), np.nan), "finite"), (-np.ones((2, 3, 3)), "finite")):
        with pytest.raises(ValueError, match=match):
            monte_carlo_ratio(bad, 1000.0)
    with pytest.raises(ValueError, match="threshold_electrons"):
        monte_carlo_ratio(np.ones((2, 3, 3)), 0.0)


# ---- where it runs: the estimate and run_job -----------------------------------------------------
class _Noisy:
    """A renderer stand-in: frames at y everywhere with Monte Carlo noise of standard deviation sd
    per 1-spp render, and no motion."""

    def __init__(self, y, sd):
        self.y, self.sd = y, sd

    def render_step(self, step, spp=None):
        return np.full((16, 16), self.y, np.float32)

    def probe_frames(self, step, count, spp=1):
        rng = np.random.default_rng(step)
        return np.abs(self.y + self.sd * rng.standard_normal((count, 16, 16))).astype(np.float32)

    def motion_px(self, step):
        return 0.0

    def substeps_for(self, step):
        return 1


def test_the_estimate_takes_each_scenes_samples_from_its_probe_renders():
    jobs = plan_llr(SIZES["small"], scenes=["ball", "fan"], quality="fast")  # 2 scenes x 2 lights
    works = [planned_work(j) for j in jobs]
    assert {w.spp for w in works} == {PRESETS["fast"].spp}  # planned at the quality's own knobs
    # ratio = 1000 sd^2 / y: 0.001 in the low light (1 spp), of order 1000 * 0.01 / 0.1 in normal
    out, n = with_motion_plans(jobs, works, load=lambda j: _Noisy(0.001, 1e-3) if j.source["light"] == "low"
                               else _Noisy(0.1, 0.1))
    assert n == 4  # with a sample rule each light is read
    rule = PRESETS["fast"].sample_rule
    bright = rule.spp_for(monte_carlo_ratio(_Noisy(0.1, 0.1).probe_frames(0, rule.probes), 1000.0))
    assert bright > 8  # ratio about 60 (the stand-in folds its negative values)
    for j, w in zip(jobs, out):
        assert w.spp == (1 if j.source["light"] == "low" else bright) and w.gt_spp == PRESETS["fast"].gt_spp
    cal = Calibration("x", works[0].pixels, startup_s=0.0, fixed_s=0.0, per_sample_pixel_s=1e-7,
                      sensor_per_pixel_step_s=0.0)
    ball = {j.source["light"]: dataclasses.replace(w, render_scale=1.0) for j, w in zip(jobs, out)
            if j.source["scene"] == "ball"}
    assert ball["normal"].seconds(cal) > ball["low"].seconds(cal)


def test_an_unread_job_gets_the_mean_samples_of_its_light():
    jobs = plan_llr(SIZES["small"], scenes=["ball", "fan"], quality="fast")
    works = [planned_work(j) for j in jobs]
    out, n = with_motion_plans(jobs, works, load=lambda j: _Noisy(0.001, 0.0) if j.source["light"] == "low"
                               else _Noisy(0.1, 0.1), sample_scenes=2)
    assert n == 2
    rule = PRESETS["fast"].sample_rule
    bright = rule.spp_for(monte_carlo_ratio(_Noisy(0.1, 0.1).probe_frames(0, rule.probes), 1000.0))
    for j, w in zip(jobs, out):
        assert w.spp == (1 if j.source["light"] == "low" else bright)


def test_with_a_sample_rule_the_estimate_reads_every_scene_and_says_the_spread_of_the_rest():
    # A scene's samples set its cost over a 16x range: a mean over 6 scenes estimated the paper
    # RLLR at 127 min, 40 scenes at 173. So every scene is read by default, more than
    # MOTION_SAMPLE_SCENES; where fewer are asked for, the estimate says its spread.
    import spikesim.generation.estimate as est
    jobs = plan_llr(SIZES["small"], scenes=["ball", "car", "cook", "fan", "rotate"], quality="fast")  # 10 jobs
    assert len(jobs) > est.MOTION_SAMPLE_SCENES
    works = [planned_work(j) for j in jobs]

    def load(j):  # dim low light at 1 spp; the normal light's noise differs per scene
        return _Noisy(0.001, 1e-3) if j.source["light"] == "low" else _Noisy(0.1, 0.02 + 0.02 * len(j.source["scene"]))
    out, n = with_motion_plans(jobs, works, load=load)
    assert n == len(jobs) and all(w.read for w in out)
    cal = Calibration("x", works[0].pixels, startup_s=0.0, fixed_s=0.01, per_sample_pixel_s=1e-7,
                      sensor_per_pixel_step_s=0.0)
    every = est.estimate(jobs, 2, calibration=cal, motion_loader=load)
    assert every.spread_s == 0 and "+-" not in every.summary()
    few = est.estimate(jobs, 2, calibration=cal, motion_loader=load, sample_scenes=3)
    assert few.motion_scenes == 3 and few.unread == 7 and few.spread_s > 0
    assert f"+- {few.spread_s / 60:.1f} min (7 job(s) not read" in few.summary()


def test_generate_with_the_sample_rule_renders_and_records_each_scenes_samples(tmp_path):
    pytest.importorskip("mitsuba")
    from spikesim.dataset import open_dataset
    from spikesim.generation import generate
    preset = SIZES["small"].replace(height=16, width=24, llr_windows=1)
    jobs = plan_llr(preset, scenes=["ball"], quality="fast")
    generate(jobs, tmp_path, workers=1, show_progress=False)
    rule = PRESETS["fast"].sample_rule
    for scene in open_dataset(tmp_path):
        q = scene.meta["quality"]
        chosen = q["sample_rule"]
        assert chosen["rule"] == dataclasses.asdict(rule) and chosen["mc_ratio"] >= 0
        assert q["settings"]["spp"] == chosen["spp"] == rule.spp_for(chosen["mc_ratio"])
        assert chosen["predicted_loss_db"] <= rule.tolerance_db or chosen["spp"] == rule.max_spp
        assert q["settings"]["gt_spp"] == PRESETS["fast"].gt_spp
