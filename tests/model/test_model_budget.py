"""The budgeted recipe: a wall-clock budget planned into steps, the cosine schedule, the loss
relative to the light, span TFP, checkpoint content hashes and RLLR's log-uniform darkening."""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest
import torch

from model.checkpoint import load_checkpoint, state_fingerprint
from model.config import ExperimentConfig, TrainConfig, load_config
from model.losses import RELATIVE_LOSS_FLOOR_Y, build_loss
from model.methods import SpanTFPMethod, method_from_spec
from model.streaming import TensorWindows
from model.training import cosine_lr, run_training
from modeltest_fakes import make_scene
from test_model_training import tiny_experiment

def budget_experiment(**train) -> ExperimentConfig:
    """test_model_training's tiny run on the cosine schedule, with a short calibration."""
    return tiny_experiment(**{"lr_schedule": "cosine", "calibration_steps": 2, **train})


@pytest.fixture(scope="module")
def scenes():
    return [make_scene(f"s{i}", 16, 20, 7 * 6, brightness=0.3, velocity=0.2, seed=i) for i in range(2)]


def test_cosine_schedule_runs_from_lr_to_the_final_ratio():
    tc = TrainConfig(lr=1e-3, lr_schedule="cosine", lr_final_ratio=0.01)
    assert cosine_lr(tc, 0, 100) == pytest.approx(1e-3)
    assert cosine_lr(tc, 50, 100) == pytest.approx(1e-5 + (1e-3 - 1e-5) * 0.5)
    assert cosine_lr(tc, 100, 100) == pytest.approx(1e-5)
    assert cosine_lr(tc, 500, 100) == pytest.approx(1e-5)  # past the end: stays at the floor
    rates = [cosine_lr(tc, s, 100) for s in range(101)]
    assert all(a >= b for a, b in zip(rates, rates[1:]))


@pytest.mark.parametrize("bad", [{"lr_schedule": "linear"}, {"lr_final_ratio": 1.5}, {"budget_minutes": 0},
                                 {"budget_minutes": -1}, {"budget_minutes": True}, {"calibration_steps": 0}])
def test_budget_fields_are_checked(bad):
    with pytest.raises(ValueError, match="train\\."):
        TrainConfig(**bad)


def test_a_spent_budget_ends_at_the_calibration_steps(scenes, tmp_path):
    """A budget already used up by the calibration plans no more steps: the run ends there, and
    the plan is in the summary and the checkpoint."""
    summary = run_training(budget_experiment(budget_minutes=1e-6, calibration_steps=3), scenes, [], tmp_path,
                           device="cpu", progress=False)
    assert summary["steps"] == 3 and summary["planned_steps"] == 3
    assert load_checkpoint(tmp_path / "last.pt")["extra"]["budget_planned_steps"] == 3


def test_the_cosine_decay_ends_at_the_planned_step(scenes, tmp_path, capsys):
    """max_steps caps the plan; the logged rate falls along the cosine and reaches the floor at the
    last step's schedule position."""
    summary = run_training(budget_experiment(budget_minutes=10_000, max_steps=6), scenes, [], tmp_path,
                           device="cpu", progress=False)
    assert summary["planned_steps"] == 6 and summary["steps"] == 6
    # the cap is said, not silent (`--budget-minutes 4` with tiny stopped at 300 steps without a word)
    assert "capped at 6 by the config's max_steps or epochs" in capsys.readouterr().err
    lrs = [float(r["lr"]) for r in csv.DictReader((tmp_path / "train_log.csv").open())]
    tc = budget_experiment(max_steps=6).train
    # before the plan is made (calibration), the schedule runs on the cap
    assert lrs == pytest.approx([cosine_lr(tc, s, 6) for s in range(6)])


def test_a_cut_budget_run_resumes_onto_the_same_plan(scenes, tmp_path, monkeypatch):
    from model import training as training_module

    straight = run_training(budget_experiment(budget_minutes=10_000, max_steps=6), scenes, [], tmp_path / "a",
                            device="cpu", progress=False)
    real_step, calls = training_module._train_step, {"n": 0}

    def crash_after_four(*args, **kwargs):
        if calls["n"] == 4:
            raise KeyboardInterrupt
        calls["n"] += 1
        return real_step(*args, **kwargs)

    monkeypatch.setattr(training_module, "_train_step", crash_after_four)
    exp = budget_experiment(budget_minutes=10_000, max_steps=6, ckpt_every_steps=4)
    with pytest.raises(KeyboardInterrupt):
        run_training(exp, scenes, [], tmp_path / "b", device="cpu", progress=False)
    saved = load_checkpoint(tmp_path / "b" / "last.pt")
    assert saved["step"] == 4 and saved["extra"]["budget_planned_steps"] == 6
    assert saved["extra"]["budget_elapsed_s"] > 0
    monkeypatch.setattr(training_module, "_train_step", real_step)
    resumed = run_training(exp, scenes, [], tmp_path / "b", device="cpu", resume=True, progress=False)
    assert resumed["steps"] == 6 and resumed["weights_sha256"] == straight["weights_sha256"]


def test_relative_loss_weighs_every_light_level_alike():
    loss = build_loss("l1_sum_relative")
    g = torch.Generator().manual_seed(0)
    target = torch.rand(3, 2, 8, 8, generator=g) * 0.5 + 0.1
    pred = target + 0.05 * torch.randn(3, 2, 8, 8, generator=g)
    # by hand: each window's mean |error| over the sample's mean light, summed over windows, mean over samples
    level = target.flatten(1).mean(1)
    expected = ((pred - target).abs().flatten(2).mean(2) / level[:, None]).mean(0).sum()
    assert loss(pred, target).item() == pytest.approx(expected.item(), rel=1e-6)
    # a scene 100 times darker with errors 100 times smaller costs the same
    assert loss(pred / 100, target / 100).item() == pytest.approx(loss(pred, target).item(), rel=1e-5)
    # and plain L1 does not: that is the point
    assert build_loss("l1_sum")(pred / 100, target / 100).item() == pytest.approx(
        build_loss("l1_sum")(pred, target).item() / 100, rel=1e-5)
    # a black target divides by the floor, not by zero
    dark = loss(torch.full((1, 2, 4, 4), 1e-3), torch.zeros(1, 2, 4, 4)).item()
    assert math.isfinite(dark) and dark == pytest.approx(2 * 1e-3 / RELATIVE_LOSS_FLOOR_Y)


def test_shot_noise_loss_weighs_light_by_its_square_root():
    """l1_sum_shot lies between plain L1 (power 0) and the relative loss (power 1): each sample's
    error over the square root of its light level, so brightness scales it as sqrt."""
    shot, rel, plain = build_loss("l1_sum_shot"), build_loss("l1_sum_relative"), build_loss("l1_sum")
    g = torch.Generator().manual_seed(3)
    target = torch.rand(4, 3, 8, 8, generator=g) * 0.4 + 0.05
    pred = target + 0.03 * torch.randn(4, 3, 8, 8, generator=g)
    level = target.flatten(1).mean(1)
    expected = ((pred - target).abs().flatten(2).mean(2) / level.sqrt()[:, None]).mean(0).sum()
    assert shot(pred, target).item() == pytest.approx(expected.item(), rel=1e-6)
    # a scene 100 times darker with errors 100 times smaller costs a tenth: sqrt, not 1 or 1/100
    assert shot(pred / 100, target / 100).item() == pytest.approx(shot(pred, target).item() / 10, rel=1e-5)
    # one sample of level l: shot = plain / sqrt(l) = relative * sqrt(l), the geometric middle of the other two
    one_p, one_t = pred[:1], target[:1]
    lv = one_t.mean().item()
    assert shot(one_p, one_t).item() == pytest.approx(plain(one_p, one_t).item() / math.sqrt(lv), rel=1e-5)
    assert shot(one_p, one_t).item() == pytest.approx(rel(one_p, one_t).item() * math.sqrt(lv), rel=1e-5)
    # a black target divides by the floor's square root, not by zero
    dark = shot(torch.full((1, 2, 4, 4), 1e-3), torch.zeros(1, 2, 4, 4)).item()
    assert math.isfinite(dark) and dark == pytest.approx(2 * 1e-3 / math.sqrt(RELATIVE_LOSS_FLOOR_Y))
    # the gradient of one sample's error is sign(error) / (pixels * sqrt(level)): the level is a weight, not learned
    p = one_p.clone().requires_grad_(True)
    shot(p, one_t).backward()
    expected_grad = torch.sign(one_p - one_t) / (one_p[0, 0].numel() * math.sqrt(lv))
    assert torch.allclose(p.grad, expected_grad, rtol=1e-5)


def test_span_tfp_averages_the_windows_around_each_frame():
    g = torch.Generator().manual_seed(1)
    spikes = torch.rand(7, 5, 4, 6, generator=g) < 0.2
    flat = spikes.reshape(-1, 4, 6).float()
    for chunk in (1, 3, 64):
        out = dict(SpanTFPMethod("span", 15, window=5, chunk=chunk).frames(TensorWindows(spikes)))
        assert sorted(out) == list(range(7))
        for i in range(7):
            lo, hi = max(0, i - 1), min(6, i + 1)  # clipped at the ends of the stream
            torch.testing.assert_close(out[i], flat[lo * 5:(hi + 1) * 5].mean(0))
    one = dict(method_from_spec("tfp:5", window=5).frames(TensorWindows(spikes)))
    plain = dict(method_from_spec("tfp", window=5).frames(TensorWindows(spikes)))
    assert all(torch.allclose(one[i], plain[i]) for i in range(7))
    assert method_from_spec("tfp:205").name == "TFP-205" and method_from_spec("x=tfp:123").name == "x"


@pytest.mark.parametrize("spec, message", [("tfp:82", "odd number"), ("tfp:100", "odd number"),
                                           ("tfp:abc", "number of steps"), ("tfp:0", "positive")])
def test_span_tfp_refuses_spans_that_are_not_odd_whole_windows(spec, message):
    with pytest.raises(ValueError, match=message):
        method_from_spec(spec)


def test_a_flipped_bit_in_a_checkpoint_is_refused(scenes, tmp_path):
    run_training(budget_experiment(max_steps=2), scenes, [], tmp_path, device="cpu", progress=False)
    path = tmp_path / "last.pt"
    state = torch.load(path, weights_only=True)
    assert state["weights_sha256"] == state_fingerprint(state["model_state"])
    for part in ("model_state", "optimizer_state"):
        damaged = torch.load(path, weights_only=True)
        tensor = next(v for v in (damaged[part].values() if part == "model_state"
                                  else damaged[part]["state"][0].values()) if isinstance(v, torch.Tensor) and v.numel() > 1)
        bits = tensor.view(torch.int32).reshape(-1)
        bits[0] ^= 1 << 20  # one bit of one weight
        torch.save(damaged, tmp_path / f"{part}.pt")
        with pytest.raises(ValueError, match="damaged"):
            load_checkpoint(tmp_path / f"{part}.pt")
    load_checkpoint(path)  # the untouched file still loads


def test_log_uniform_darkening_fills_every_decade():
    from spikesim.generation import PRESETS
    from spikesim.generation.plan import LOG_DARKENING_MIN, plan_rllr

    jobs = plan_rllr(PRESETS["small"], seed=0, count=300, darkening="log-uniform")
    f = np.array([j.light_power_factor for j in jobs])
    assert f.min() >= LOG_DARKENING_MIN and f.max() < 1
    decades = np.histogram(np.log10(f), bins=[np.log10(LOG_DARKENING_MIN), -2, -1, 0])[0]
    # log10(0.005) .. -2 is 0.3 of a decade: expected 300 * 0.3 / 2.3, 300 / 2.3, 300 / 2.3
    assert decades[0] > 20 and decades[1] > 90 and decades[2] > 90
    uniform = np.array([j.light_power_factor for j in plan_rllr(PRESETS["small"], seed=0, count=300)])
    assert (uniform < 0.1).mean() < 0.2  # the paper's draw: a tenth of the scenes below 0.1
    # the first uniform draws are what they always were (datasets made before keep their identity)
    assert [j.light_power_factor for j in plan_rllr(PRESETS["small"], seed=0, count=3)] == list(uniform[:3])
    with pytest.raises(ValueError, match="darkening"):
        plan_rllr(PRESETS["small"], darkening="gaussian")


@pytest.mark.parametrize("name", ["../../evil", "/tmp/abs", "a/b", "a\\b", "..", ".hidden", ""])
def test_a_config_name_is_a_name_not_a_path(name):
    with pytest.raises(ValueError, match="plain name"):
        ExperimentConfig.from_dict({"name": name})
    with pytest.raises(ValueError, match="plain name"):
        ExperimentConfig(name)


def test_a_trained_model_is_never_replaced_without_being_asked(scenes, tmp_path):
    """A folder holding a run (best.pt alone counts) is refused unless --resume or --overwrite."""
    run_training(budget_experiment(max_steps=1), scenes, [], tmp_path, device="cpu", progress=False)
    (tmp_path / "last.pt").unlink()
    (tmp_path / "best.pt").write_bytes(b"a model someone kept")
    with pytest.raises(FileExistsError, match="best.pt"):
        run_training(budget_experiment(max_steps=1), scenes, [], tmp_path, device="cpu", progress=False)
    assert (tmp_path / "best.pt").read_bytes() == b"a model someone kept"
    run_training(budget_experiment(max_steps=1), scenes, [], tmp_path, device="cpu", progress=False, overwrite=True)
    assert not (tmp_path / "best.pt").exists() and (tmp_path / "last.pt").exists()


def test_overwrite_replaces_the_runs_event_files_and_keeps_the_users_files_in_tb(scenes, tmp_path):
    """`train --overwrite` deleted a user's tb/analysis/plot.txt with the whole tb/, and a bare tb/
    of the user's was called "a run (tb)" (round eight)."""
    pytest.importorskip("tensorboard")
    (tmp_path / "tb" / "analysis").mkdir(parents=True)
    (tmp_path / "tb" / "analysis" / "plot.txt").write_text("mine")
    (tmp_path / "tb" / "notes.md").write_text("mine too")
    run_training(budget_experiment(max_steps=1), scenes, [], tmp_path, device="cpu", progress=False)  # no run here
    first = sorted(p.name for p in (tmp_path / "tb").glob("events.out.tfevents.*"))
    assert first
    with pytest.raises(FileExistsError, match=r"holds a run \(last\.pt, train_log\.csv, val_log\.csv, val_scenes\.csv, config\.json, tb\)"):
        run_training(budget_experiment(max_steps=1), scenes, [], tmp_path, device="cpu", progress=False)
    run_training(budget_experiment(max_steps=1), scenes, [], tmp_path, device="cpu", progress=False, overwrite=True)
    assert (tmp_path / "tb" / "analysis" / "plot.txt").read_text() == "mine"
    assert (tmp_path / "tb" / "notes.md").read_text() == "mine too"
    assert not set(first) & {p.name for p in (tmp_path / "tb").glob("events.out.tfevents.*")}


@pytest.mark.parametrize("lr", [1e300, float("nan"), float("inf"), 0, -1e-3, 2.0])
def test_a_learning_rate_outside_zero_to_one_is_refused(lr):
    with pytest.raises(ValueError, match="train.lr must be a number in"):
        TrainConfig(lr=lr)


def test_a_config_that_is_not_an_object_is_one_line(tmp_path):
    from model.config import load_config
    (tmp_path / "list.json").write_text("[]")
    with pytest.raises(ValueError, match="expected a JSON object, got list"):
        load_config(tmp_path / "list.json")


def test_a_diverging_run_says_so_in_one_line(scenes, tmp_path, monkeypatch):
    from model import training
    from model.training import TrainingDiverged
    monkeypatch.setattr(training, "build_loss", lambda name: lambda pred, gt: (pred - gt).abs().mean() * float("nan"))
    with pytest.raises(TrainingDiverged, match="became nan at step 0 .learning rate 0.003.: lower --lr") as info:
        run_training(budget_experiment(max_steps=5), scenes, [], tmp_path, device="cpu", progress=False)
    assert isinstance(info.value, ValueError)  # the command line's one-line errors


def test_resume_refuses_overrides_it_would_ignore(scenes, tmp_path):
    run_training(budget_experiment(max_steps=2), scenes, [], tmp_path, device="cpu", progress=False)
    with pytest.raises(ValueError, match="batch_size 2 -> 4, lr 0.003 -> 0.5"):
        run_training(budget_experiment(max_steps=3, batch_size=4, lr=0.5), scenes, [], tmp_path, device="cpu",
                     resume=True, progress=False)
    summary = run_training(budget_experiment(max_steps=3), scenes, [], tmp_path, device="cpu", resume=True,
                           progress=False)  # a longer run is the same run
    assert summary["steps"] == 3


def test_knee_loss_is_relative_below_the_knee_and_shot_noise_above_it():
    """l1_sum_knee weighs a sample 1/level below KNEE_LOSS_KNEE_Y and 1/sqrt(level * knee) above it:
    among dark samples the relative loss's balance, among bright ones the shot loss's, and one
    continuous weight between them."""
    from model.losses import KNEE_LOSS_KNEE_Y as K
    knee, shot, rel = build_loss("l1_sum_knee"), build_loss("l1_sum_shot"), build_loss("l1_sum_relative")
    g = torch.Generator().manual_seed(5)
    base = torch.rand(1, 3, 8, 8, generator=g) * 0.5 + 0.75      # mean about 1, so the level is the scale
    err = 0.02 * torch.randn(1, 3, 8, 8, generator=g)
    for scale in (2e-3, 5e-3, 0.5 * K):                                # dark: exactly the relative loss
        t = base * scale / base.mean()
        assert knee(t + err * scale, t).item() == pytest.approx(rel(t + err * scale, t).item(), rel=1e-5)
    for scale in (2 * K, 0.1, 0.3):                                    # bright: the shot loss over sqrt(knee)
        t = base * scale / base.mean()
        assert knee(t + err * scale, t).item() == pytest.approx(shot(t + err * scale, t).item() / math.sqrt(K), rel=1e-5)
    # continuous at the knee: just below and just above weigh alike
    below, above = base * (K * 0.999) / base.mean(), base * (K * 1.001) / base.mean()
    assert knee(below + err, below).item() == pytest.approx(knee(above + err, above).item(), rel=3e-3)
    # the bright-to-dark balance lies between the shot loss's and the relative loss's
    dark, bright = torch.full((1, 2, 4, 4), RELATIVE_LOSS_FLOOR_Y), torch.full((1, 2, 4, 4), 0.3)
    ratio = {name: f(dark + 0.01, dark).item() / f(bright + 0.01, bright).item()
             for name, f in (("knee", knee), ("shot", shot), ("rel", rel))}
    assert ratio["shot"] < ratio["knee"] < ratio["rel"]
    assert ratio["knee"] == pytest.approx(math.sqrt(0.3 * K) / RELATIVE_LOSS_FLOOR_Y, rel=1e-5)
    # a black target weighs as the floor does, finitely
    black = knee(torch.full((1, 2, 4, 4), 1e-3), torch.zeros(1, 2, 4, 4)).item()
    assert math.isfinite(black) and black == pytest.approx(2 * 1e-3 / RELATIVE_LOSS_FLOOR_Y)


def test_a_run_without_validation_says_no_best_pt_will_be_written(scenes, tmp_path, capsys):
    run_training(budget_experiment(max_steps=1), scenes[:1], [], tmp_path, device="cpu", progress=False)
    err = capsys.readouterr().err
    assert "no validation scenes" in err and "best.pt will not be written" in err
    assert not (tmp_path / "best.pt").exists() and (tmp_path / "last.pt").exists()


def test_the_shot_loss_config_is_the_span_config_with_that_loss_alone():
    """lrrep_span_shot, the loss lever's long run (scripts/budget_run.sh CONFIG=...), is one factor
    away from lrrep_span: the same network and recipe, only train.loss differs."""
    span, shot = load_config("lrrep_span"), load_config("lrrep_span_shot")
    assert shot.model == span.model
    a, b = span.train.to_dict(), shot.train.to_dict()
    assert {k for k in a if a[k] != b[k]} == {"loss"} and b["loss"] == "l1_sum_shot"


def test_the_knee_loss_config_is_the_span_config_with_that_loss_alone():
    """lrrep_span_knee (scripts/budget_run.sh CONFIG=...) is one factor away from lrrep_span."""
    span, knee = load_config("lrrep_span"), load_config("lrrep_span_knee")
    assert knee.model == span.model
    a, b = span.train.to_dict(), knee.train.to_dict()
    assert {k for k in a if a[k] != b[k]} == {"loss"} and b["loss"] == "l1_sum_knee"


def test_the_natural_share_config_is_the_shot_config_with_that_share_alone():
    """lrrep_span_shot_nat20 (the budget run with the natural share on top of the shot loss) is one
    factor away from lrrep_span_shot: only train.set_shares differs, and it names the natural set."""
    shot, nat = load_config("lrrep_span_shot"), load_config("lrrep_span_shot_nat20")
    assert nat.model == shot.model
    a, b = shot.train.to_dict(), nat.train.to_dict()
    assert {k for k in a if a[k] != b[k]} == {"set_shares"}
    assert b["set_shares"] == {"rllr_nat8tr": 0.2} and b["loss"] == "l1_sum_shot"
