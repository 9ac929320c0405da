"""The speed/accuracy study (pipelines/tradeoff_study.py), adaptive keyframes
(spikesim/render/adaptive.py) and the quality presets (spikesim/quality.py), at tiny sizes."""
from __future__ import annotations

import json
from pathlib import Path
import math

import numpy as np
import pytest

from spikesim.camera import NOISE_TERMS, SpikeCamera
from spikesim.quality import PRESETS, QualitySettings, decide_noise_terms, noise_effect
from spikesim.render.adaptive import AdaptiveKeyframes, AdaptivePolicy, motion_plan
from spikesim.simulate import Simulator

from sensor_testing import requires_llvm


class MovingStripes:
    """A fake renderer: sinusoidal stripes (period 10 px) moving sideways with a speed that changes
    by stretch: still for steps < 50, 0.05 px/step up to 100, 0.2 px/step after. Deterministic,
    so interpolation errors are the motion's alone."""

    def __init__(self, height: int = 6, width: int = 40):
        self.x = np.arange(width, dtype=np.float64)[None, :].repeat(height, 0)
        self.renders = 0

    @staticmethod
    def speed(step: float) -> float:
        return 0.0 if step < 50 else (0.05 if step < 100 else 0.2)

    def position(self, t: float) -> float:
        """Displacement at time t (steps): the integral of the speed."""
        return 0.05 * min(max(t - 50, 0), 50) + 0.2 * max(t - 100, 0)

    def motion_px(self, step: int) -> float:
        return self.position(step + 1) - self.position(step)

    def image(self, step: int) -> np.ndarray:
        return (0.5 + 0.4 * np.sin(2 * np.pi * (self.x - self.position(step + 0.5)) / 10)).astype(np.float32)

    def render_step(self, step: int, spp: int | None = None) -> np.ndarray:
        self.renders += 1
        return self.image(step)


def _intervals(steps: list[int], lo: int, hi: int) -> float:
    inside = [b - a for a, b in zip(steps, steps[1:]) if lo <= a and b <= hi]
    return float(np.mean(inside))


# ---- adaptive keyframes ---------------------------------------------------------------------------
def test_static_scene_renders_once():
    r = MovingStripes()
    ak = AdaptiveKeyframes(AdaptivePolicy(max_px_per_keyframe=0.5, max_interval=10_000))
    keys = list(ak.keyframes(r, 0, 50))  # steps 0..49: all still
    assert r.renders == 1 and [s for s, _ in keys] == [0, 49]
    assert keys[1][1] is keys[0][1]
    assert ak.record.to_dict()["renders"] == 1


def test_denser_keyframes_where_the_image_moves_faster():
    r = MovingStripes()
    ak = AdaptiveKeyframes(AdaptivePolicy(max_px_per_keyframe=0.5))
    steps = [s for s, _ in ak.keyframes(r, 0, 200)]
    assert steps[0] == 0 and steps[-1] == 199 and steps == sorted(set(steps))
    slow, fast = _intervals(steps, 50, 100), _intervals(steps, 100, 199)
    assert slow == pytest.approx(10, abs=1) and fast == pytest.approx(2.5, abs=0.6)
    assert not any(0 < s < 50 for s in steps)  # the still stretch costs one render


def test_motion_bound_holds_between_keyframes():
    r = MovingStripes()
    plan = [s for s, _ in motion_plan(r, 0, 199, AdaptivePolicy(max_px_per_keyframe=0.3))]
    for a, b in zip(plan, plan[1:]):
        moved = sum(r.motion_px(s) for s in range(a, b))
        assert moved <= 0.3 + 1e-9 or b == a + 1


@pytest.mark.parametrize("tol", [0.02, 0.005])
def test_brightness_check_bounds_the_interpolation_error(tol):
    # A loose motion bound (4 px) alone interpolates badly; the brightness check refines until the
    # interpolated image at every step is within the tolerance of the rendered one.
    r = MovingStripes()
    policy = AdaptivePolicy(max_px_per_keyframe=4.0, brightness_tolerance=tol, check_block=1)
    keys = dict(AdaptiveKeyframes(policy).keyframes(r, 40, 160))
    steps = sorted(keys)
    worst = 0.0
    for a, b in zip(steps, steps[1:]):
        for s in range(a + 1, b):
            w = (s - a) / (b - a)
            interp = keys[a] * (1 - w) + keys[b] * w
            truth = r.image(s)
            worst = max(worst, float(np.sqrt(np.mean((interp - truth) ** 2)) / truth.mean()))
    assert worst <= tol
    # and without the check the same motion bound is far outside it
    coarse = dict(AdaptiveKeyframes(AdaptivePolicy(max_px_per_keyframe=4.0)).keyframes(MovingStripes(), 40, 160))
    cs = sorted(coarse)
    a, b = cs[-2], cs[-1]
    mid = (a + b) // 2
    err = np.sqrt(np.mean((coarse[a] * 0.5 + coarse[b] * 0.5 - r.image(mid)) ** 2)) / r.image(mid).mean()
    assert b - a > 2 and err > tol


def test_adaptive_keyframes_drive_the_simulator():
    r = MovingStripes()
    ak = AdaptiveKeyframes(AdaptivePolicy(max_px_per_keyframe=0.5))
    sim = Simulator(SpikeCamera.noiseless(height=6, width=40), backend="numpy")
    parts = list(sim.stream_keyframes(ak.keyframes(r, 0, 120)))
    assert sum(p.num_steps for p in parts) == 120
    assert ak.record.renders < 40


@pytest.mark.parametrize("bad", [dict(max_px_per_keyframe=0), dict(max_px_per_keyframe=math.inf),
                                 dict(max_interval=0), dict(brightness_tolerance=-1.0)])
def test_adaptive_policy_rejects_bad_values(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        AdaptivePolicy(**bad)


# ---- quality presets and noise decisions ---------------------------------------------------------
def test_presets_are_valid_and_ordered():
    assert set(PRESETS) == {"draft", "balanced", "reference", "fast"}
    ref, bal, draft = (QualitySettings.from_name(n) for n in ("reference", "balanced", "draft"))
    assert ref.spp >= bal.spp >= draft.spp
    assert ref.keyframe_policy == "every" and ref.variant == "spectral" and ref.noise == "all"
    assert ref.precision == "float64"
    for q in (ref, bal, draft):
        json.dumps(q.record())
        assert set(q.render_kwargs()) == {"spp", "gt_spp", "variant", "keyframe_every"}
    with pytest.raises(ValueError, match="unknown quality 'faster'"):
        QualitySettings.from_name("faster")
    with pytest.raises(ValueError, match="keyframe_policy"):
        ref.replace(keyframe_policy="sometimes")


def test_decide_noise_terms_by_light_level():
    cam = SpikeCamera.realistic()
    bright = {d.term: d for d in decide_noise_terms(cam, [0.3], tolerance=0.01)}
    dark = {d.term: d for d in decide_noise_terms(cam, [0.001], tolerance=0.01)}
    assert set(bright) == set(NOISE_TERMS)
    # shot noise over a 41-step window: 1/sqrt((y + d) 41 1000) -> 0.9 % at y = 0.3, 15 % at 0.001
    assert bright["shot_noise"].effect == pytest.approx(1 / math.sqrt((0.3 + cam.dark_per_step) * 41e3), rel=1e-6)
    assert not bright["shot_noise"].keep and dark["shot_noise"].keep
    assert not bright["dark_current_hz"].keep and dark["dark_current_hz"].keep
    assert bright["gain_spread"].keep and bright["threshold_offset"].keep  # 5.8 %, 4.5 % at any light
    assert not bright["reset_loss"].keep and "tolerance" in bright["reset_loss"].reason
    off = decide_noise_terms(cam.without("shot_noise"), [0.001], 0.01)
    assert next(d for d in off if d.term == "shot_noise").reason == "off in the camera"
    with pytest.raises(ValueError, match="y_levels"):
        decide_noise_terms(cam, [], 0.01)
    with pytest.raises(ValueError, match="y_levels"):
        decide_noise_terms(cam, [np.nan], 0.01)
    with pytest.raises(ValueError, match="unknown noise term"):
        noise_effect(cam, "cosmic_rays", 0.1)


def test_quality_camera_applies_and_records_decisions():
    draft = QualitySettings.from_name("draft").replace(noise="auto", noise_tolerance=0.01)
    cam, decisions = draft.camera(SpikeCamera.realistic(height=4, width=8), y_levels=[0.3, 0.5])
    assert cam.shot_noise == "off" and cam.gain_spread > 0 and cam.precision == draft.precision
    assert {d.term for d in decisions if not d.keep} >= {"shot_noise", "reset_loss"}
    with pytest.raises(ValueError, match="y_levels"):
        draft.camera(SpikeCamera.realistic())
    record = draft.record(decisions)
    assert record["quality"] == "draft" and len(record["noise_decisions"]) == len(NOISE_TERMS)


@pytest.mark.parametrize("policy,k", [("every", 1), ("fixed", 8), ("adaptive", 1)])
def test_quality_simulate_gives_exactly_the_steps_asked(policy, k):
    q = QualitySettings.of("t", spp=1, gt_spp=1, variant="mono", keyframe_policy=policy, keyframe_every=k)
    r = MovingStripes()
    sim = Simulator(SpikeCamera.noiseless(height=6, width=40), backend="numpy")
    parts = list(q.simulate(sim, r, 60, 45))
    assert sum(p.num_steps for p in parts) == 45
    steps = [s for s, _ in q.keyframes(MovingStripes(), 60, 45)]
    # adaptive keyframes end on the last step; fixed ones are k apart, the last at or past it
    assert steps[0] == 60 and steps[-1] == (104 if policy != "fixed" else 108)


# ---- the study machinery ---------------------------------------------------------------------------
def test_pareto_front_on_hand_made_points():
    from pipelines.tradeoff_study import pareto_front

    pts = [(1.0, 0.0), (0.5, 0.1), (0.6, 0.2), (0.2, 0.5), (0.2, 0.6), (0.1, 1.0), (0.5, 0.1), (math.nan, 0.0)]
    assert pareto_front(pts) == [True, True, False, True, False, True, True, False]


def test_study_config_is_validated():
    from pipelines.tradeoff_study import StudyConfig

    with pytest.raises(ValueError, match="resolution"):
        StudyConfig.of(resolution=(5, 40))
    with pytest.raises(ValueError, match="unknown knob"):
        StudyConfig.of(knobs=("spp", "colour"))
    with pytest.raises(ValueError, match="lights"):
        StudyConfig.of(lights=("dim",))
    assert StudyConfig.of(windows=3).centres() == [430 - 41, 430, 430 + 41]


def test_plan_covers_every_knob():
    from pipelines.tradeoff_study import StudyConfig, plan_runs

    runs = plan_runs(StudyConfig.of(spp_values=(1, 4), keyframe_values=(2,), adaptive_px=(0.5,)))
    names = [r.name for r in runs]
    assert names[:3] == ["reference", "floor: sensor seed", "floor: sensor+render seed"]
    assert {"spp=1", "spp=4", "k=2", "adaptive 0.5px", "mono", "float32", "quality=balanced", "quality=draft"} <= set(names)
    assert {f"-{t}" for t in NOISE_TERMS} <= set(names)
    seeds = {(r.sensor_seed, r.render_seed) for r in runs if r.knob != "floor"}
    assert seeds == {(0, 0)}  # every knob run shares the reference's seeds


@requires_llvm
def test_study_rows_and_resume(tmp_path, monkeypatch):
    from pipelines import tradeoff_study as tradeoff

    # the figures as a timed study gives them: on a fast CPU this small reference is under MIN_TIMED_S
    monkeypatch.setattr(tradeoff, "MIN_TIMED_S", 0.0)
    cfg = tradeoff.StudyConfig.of(scenes=("ball",), lights=("low",), resolution=(25, 40), windows=1, ref_spp=2,
                               gt_spp=4, knobs=("spp", "precision", "adaptive"), spp_values=(1,),
                               adaptive_px=(1.0,), repeats=1)
    rows = tradeoff.run_study(cfg, tmp_path, progress=False)
    assert [r["run"] for r in rows] == ["reference", "floor: sensor seed", "floor: sensor+render seed", "spp=1",
                                        "adaptive 1px", "float32"]
    ref = rows[0]
    assert ref["rate_err"] == 0 and ref["time_ratio"] == 1 and ref["tfp_ssim"] == pytest.approx(1)
    floor = rows[1]
    assert floor["rate_err"] > 0 and floor["tfp_psnr"] < ref["tfp_psnr"]
    adaptive = next(r for r in rows if r["run"] == "adaptive 1px")
    assert adaptive["renders"] < 41 and adaptive["render_s"] < ref["render_s"]
    for r in rows:
        assert all(np.isfinite(r[c]) for c in ("render_s", "simulate_s", "rate_err", "gt_err", "tfp_ssim"))
    # the scene-light's light level (the fast preset's rule splits on it): one value, the median
    # of the reference's ground truth, a dim Ball in low light
    assert len({r["ref_y_median"] for r in rows}) == 1 and 0 < ref["ref_y_median"] < 0.0142
    assert not floor["pareto"]  # the noise floor is a yardstick, not a choice
    front = [r for r in rows if r["pareto"]]
    assert front and all(not (o["time_ratio"] <= f["time_ratio"] and o["rate_err"] < f["rate_err"])
                         for f in front for o in rows if o["knob"] != "floor")
    tradeoff.write_report(rows, tmp_path)
    assert (tmp_path / "tradeoff.png").stat().st_size > 1000
    assert (tmp_path / "tradeoff.csv").read_text().count("\n") == len(rows) + 1
    assert "ref_y_median" in (tmp_path / "tradeoff.csv").read_text().splitlines()[0].split(",")
    assert "**ball, low light**" in (tmp_path / "tradeoff.md").read_text()

    # a run from a later process is compared with the reference re-timed there (the probe)
    path = tmp_path / "runs" / "ball_low" / "spp=1.json"
    row = json.loads(path.read_text())
    spp1 = next(r for r in rows if r["run"] == "spp=1")
    path.write_text(json.dumps({**row, "session": "later", "ref_frame_s": 2 * ref["render_s"] / 41}))
    later = next(r for r in tradeoff.collect_rows(cfg, tmp_path) if r["run"] == "spp=1")
    assert not later["same_session"]
    assert later["render_ratio"] == pytest.approx(spp1["render_ratio"] / 2)
    path.write_text(json.dumps(row))

    # resume: every run is cached, so nothing runs again
    def boom(self, spec):
        raise AssertionError(f"{spec.name} ran again")
    monkeypatch.setattr(tradeoff.SceneStudy, "run", boom)
    again = tradeoff.run_study(cfg, tmp_path, progress=False)
    assert [r["run"] for r in again] == [r["run"] for r in rows]
    # a run whose cache is missing (an interrupted study) runs, and only that one
    (tmp_path / "runs" / "ball_low" / "spp=1.json").unlink()
    ran = []
    monkeypatch.setattr(tradeoff.SceneStudy, "run", lambda self, spec: ran.append(spec.name) or boom(self, spec))
    with pytest.raises(AssertionError, match="spp=1 ran again"):
        tradeoff.run_study(cfg, tmp_path, progress=False)
    assert ran == ["spp=1"]


@requires_llvm
def test_static_bundled_scene_renders_once(tmp_path):
    # A real scene with its motion file replaced by a static one: one render for 41 steps.
    from spikesim.render import SceneRenderer

    motion = tmp_path / "motion.json"
    motion.write_text(json.dumps({"version": 1, "objects": []}))
    r = SceneRenderer("ball", light="low", variant="mono", resolution=(25, 40), spp=1, motion=motion)
    keys = list(AdaptiveKeyframes(AdaptivePolicy(max_interval=4096)).keyframes(r, 0, 41))
    assert r.stats["renders"] == 1 and [s for s, _ in keys] == [0, 40]


def test_the_study_runs_on_a_users_scene_xml(tmp_path, capsys):
    """`tradeoff --xml`: the speed/accuracy study of a user's own scene (sweep had --xml, the study
    ran only on the bundled scenes); its folders and rows are named by the scene's folder."""
    import shutil

    from pipelines.cli import main
    scene = tmp_path / "myscene"
    shutil.copytree(Path(__file__).resolve().parents[1] / "scenes" / "ball", scene,
                    ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path / "study"
    assert main(["tradeoff", "--xml", str(scene / "scene.xml"), "--light", "low", "--height", "25", "--width", "40",
                 "--windows", "1", "--ref-spp", "2", "--gt-spp", "4", "--knobs", "precision",
                 "--gt-error-spp", "2", "--repeats", "1", "--quiet", "-o", str(out)]) == 0
    rows = (out / "tradeoff.csv").read_text().splitlines()
    assert (out / "runs" / "myscene_low" / "float32.json").is_file()
    assert all(r.startswith("myscene,low,") for r in rows[1:]) and "**myscene, low light**" in (out / "tradeoff.md").read_text()
    assert main(["tradeoff", "--xml", str(scene / "scene.xml"), "--scenes", "ball", "-o", str(out)]) == 2
    assert "--scenes (bundled scenes) or --xml" in capsys.readouterr().err


def test_a_users_scene_edited_since_the_last_run_is_measured_again(tmp_path):
    """Round sixteen: the cache key held the scene's path only, so a rerun after the scene's lamp
    was changed reported the old scene's figures, rc 0. Its files' content is now in every key."""
    import shutil

    from pipelines.cli import main
    scene = tmp_path / "myscene"
    shutil.copytree(Path(__file__).resolve().parents[1] / "scenes" / "ball", scene,
                    ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path / "study"
    argv = ["tradeoff", "--xml", str(scene / "scene.xml"), "--light", "low", "--height", "25", "--width", "40",
            "--windows", "1", "--ref-spp", "2", "--gt-spp", "4", "--knobs", "precision", "--repeats", "1",
            "--quiet", "-o", str(out)]
    assert main(argv) == 0
    run = out / "runs" / "myscene_low" / "float32.json"
    first = json.loads(run.read_text())
    assert main(argv) == 0
    assert json.loads(run.read_text()) == first  # unchanged scene: cached, not measured again
    lights = scene / "lights.json"
    lights.write_text(lights.read_text() + "\n")  # any change to what the scene is made from
    assert main(argv) == 0
    again = json.loads(run.read_text())
    assert again["key"] != first["key"]  # rewritten under the new key: measured again


@requires_llvm
def test_an_untimed_study_still_plots(tmp_path, monkeypatch):
    """A reference under MIN_TIMED_S gives no time ratios; the plot's log time axis of NaNs failed
    the whole command (rc 2, "Data cannot be log-scaled") once a faster CPU made small studies untimed."""
    from pipelines import tradeoff_study as tradeoff
    from pipelines.cli import main
    monkeypatch.setattr(tradeoff, "MIN_TIMED_S", 1e9)
    out = tmp_path / "study"
    assert main(["tradeoff", "--scenes", "ball", "--light", "low", "--height", "25", "--width", "40", "--windows", "1",
                 "--ref-spp", "2", "--gt-spp", "4", "--knobs", "precision", "--repeats", "1", "--quiet",
                 "-o", str(out)]) == 0
    assert any(p.suffix == ".png" for p in out.iterdir())
