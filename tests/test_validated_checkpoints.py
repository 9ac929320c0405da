"""Per-scene validation scores, the checkpoints kept at each validation (train.keep_validated) and
`spikesim pick-checkpoint`, which picks a run's network among them by another rule than the mean."""
from __future__ import annotations

import csv

import numpy as np
import pytest
import torch
from test_round20 import _dataset

from model.checkpoint import load_checkpoint
from model.config import ExperimentConfig, ModelConfig, TrainConfig
from model.data import open_scenes
from model.training import VALIDATED_DIR, run_training, validated_name


def _tiny(keep: bool, max_steps: int = 4) -> ExperimentConfig:
    return ExperimentConfig("tiny_kept", model=ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2),
                            train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=10, lr_milestones=(50,),
                                              samples_per_epoch=1, val_fraction=0.0, max_steps=max_steps,
                                              lr=1e-2, seed=3, keep_validated=keep))


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture
def data(tmp_path):
    return _dataset(tmp_path / "train", 0.3), _dataset(tmp_path / "val", 0.05, side=12)


def test_each_validation_logs_every_scene_and_their_mean_is_the_runs_score(tmp_path, data):
    train, val = data
    run = tmp_path / "run"
    run_training(_tiny(keep=True), open_scenes(train), open_scenes(val), run, device="cpu", progress=False)
    means, scenes = _rows(run / "val_log.csv"), _rows(run / "val_scenes.csv")
    assert [int(r["step"]) for r in means] == [1, 2, 3, 4]
    for r in means:
        mine = [s for s in scenes if s["step"] == r["step"]]
        assert sorted(s["scene"] for s in mine) == ["s0", "s1"]
        # one sample of K windows per scene: the mean over frames is the mean over scenes
        assert np.mean([float(s["psnr_aligned"]) for s in mine]) == pytest.approx(float(r["psnr_aligned"]), abs=1e-9)
        assert np.mean([float(s["psnr_aligned_tfp"]) for s in mine]) == pytest.approx(float(r["psnr_aligned_tfp"]),
                                                                                        abs=1e-9)
    kept = sorted(p.name for p in (run / VALIDATED_DIR).iterdir())
    assert kept == [validated_name(s) for s in (1, 2, 3, 4)]
    # best.pt is the kept checkpoint of the best mean: the same weights
    best = load_checkpoint(run / "best.pt")
    twin = load_checkpoint(run / VALIDATED_DIR / validated_name(best["step"]))
    assert all(torch.equal(best["model_state"][k], twin["model_state"][k]) for k in best["model_state"])
    assert max(float(r["psnr_aligned"]) for r in means) == pytest.approx(best["extra"]["best_val_psnr"])


def test_without_keep_validated_no_checkpoint_is_kept_but_the_scenes_are_logged(tmp_path, data):
    train, val = data
    run = tmp_path / "run"
    run_training(_tiny(keep=False, max_steps=2), open_scenes(train), open_scenes(val), run, device="cpu",
                 progress=False)
    assert not (run / VALIDATED_DIR).exists()
    assert len(_rows(run / "val_scenes.csv")) == 2 * 2


def test_a_resumed_run_keeps_one_row_per_scene_and_validation(tmp_path, data):
    """A cut run's rows after its last checkpoint are written again by the resume, not twice."""
    train, val = data
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    run_training(_tiny(keep=True), open_scenes(train), open_scenes(val), whole, device="cpu", progress=False)
    run_training(_tiny(keep=True, max_steps=2), open_scenes(train), open_scenes(val), cut, device="cpu",
                 progress=False)
    # a row the cut run wrote after last.pt (as a kill between validation and checkpoint leaves)
    with open(cut / "val_scenes.csv", "a") as f:
        f.write("0,9,3,s0,1.0,1.0\n")
    run_training(_tiny(keep=True), open_scenes(train), open_scenes(val), cut, device="cpu", resume=True, progress=False)
    got, want = _rows(cut / "val_scenes.csv"), _rows(whole / "val_scenes.csv")
    assert not [r for r in got if r["epoch"] == "9"]  # the stale row is gone
    # a run cut by --max-steps at an epoch's end validates once more on resuming (val_log.csv does
    # too): the same scores at the same step, so each (step, scene) has one score, the whole run's
    scores = {(r["step"], r["scene"]): r["psnr_aligned"] for r in want}
    assert {(r["step"], r["scene"]): r["psnr_aligned"] for r in got} == scores
    assert all(scores[(r["step"], r["scene"])] == r["psnr_aligned"] for r in got)
    assert len(got) == 2 * len(_rows(cut / "val_log.csv"))
    assert sorted(p.name for p in (cut / VALIDATED_DIR).iterdir()) == [validated_name(s) for s in (1, 2, 3, 4)]


def test_overwrite_removes_the_kept_checkpoints_of_the_run_it_replaces(tmp_path, data):
    train, val = data
    run = tmp_path / "run"
    run_training(_tiny(keep=True), open_scenes(train), open_scenes(val), run, device="cpu", progress=False)
    with pytest.raises(FileExistsError, match="validated"):
        run_training(_tiny(keep=False, max_steps=2), open_scenes(train), open_scenes(val), run, device="cpu",
                     progress=False)
    run_training(_tiny(keep=False, max_steps=2), open_scenes(train), open_scenes(val), run, device="cpu",
                 progress=False, overwrite=True)
    assert not (run / VALIDATED_DIR).exists()
    assert {r["step"] for r in _rows(run / "val_scenes.csv")} == {"1", "2"}


# ---- spikesim pick-checkpoint -----------------------------------------------------------------------
def _scene_log(run, rows):
    """A val_scenes.csv of (step, scene, aligned PSNR) rows."""
    run.mkdir(parents=True, exist_ok=True)
    lines = ["time,epoch,step,scene,psnr_aligned,psnr_aligned_tfp"]
    lines += [f"0,{step},{step},{scene},{value},10.0" for step, scene, value in rows]
    (run / "val_scenes.csv").write_text("\n".join(lines) + "\n")


# at step 2 the dark scene drops: the mean still rises, the floor does not
ROWS = [(1, "val_a:dark", 14.0), (1, "val_a:lit", 28.0), (1, "val_b:card", 30.0),
        (2, "val_a:dark", 12.0), (2, "val_a:lit", 29.5), (2, "val_b:card", 31.0),
        (3, "val_a:dark", 14.0), (3, "val_a:lit", 28.5), (3, "val_b:card", 29.0)]


def test_the_rules_rank_validations_by_their_mean_and_by_their_floor(tmp_path):
    from model.selection import rank_validations, read_scene_scores
    _scene_log(tmp_path / "run", ROWS)
    scores = read_scene_scores(tmp_path / "run")
    by_mean = rank_validations(scores, "mean")
    assert [v.step for v in by_mean] == [2, 1, 3]
    assert by_mean[0].score == pytest.approx((12.0 + 29.5 + 31.0) / 3)
    by_floor = rank_validations(scores, "worst")
    # steps 1 and 3 share the floor (14 dB): the earlier wins, as best.pt's strict "better" does
    assert [v.step for v in by_floor] == [1, 3, 2] and by_floor[0].worst_scene == "val_a:dark"
    one_set = rank_validations(scores, "mean", "val_a")
    assert [v.step for v in one_set] == [3, 1, 2] and one_set[0].score == pytest.approx(21.25)
    with pytest.raises(ValueError, match="val_c.*its sets: val_a, val_b"):
        rank_validations(scores, "mean", "val_c")
    with pytest.raises(ValueError, match="rule 'median'"):
        rank_validations(scores, "median")


@pytest.mark.parametrize("text, match", [
    ("time,epoch,step,scene,psnr_aligned,psnr_aligned_tfp\n0,1,one,s0,1.0,1.0\n", "line 2"),
    ("time,epoch,step,scene,psnr_aligned,psnr_aligned_tfp\n0,1,1,s0,nan,1.0\n", "no usable score"),
    ("time,epoch,step,scene,psnr_aligned,psnr_aligned_tfp\n", "no validation yet"),
])
def test_a_damaged_scene_log_is_named(tmp_path, text, match):
    from model.selection import read_scene_scores
    (tmp_path / "val_scenes.csv").write_text(text)
    with pytest.raises(ValueError, match=match):
        read_scene_scores(tmp_path)
    with pytest.raises(FileNotFoundError, match="no per-scene validation log"):
        read_scene_scores(tmp_path / "elsewhere")


@pytest.fixture
def kept_run(tmp_path, data):
    """A 4-step run that validated and kept its checkpoint at every step."""
    train, val = data
    run = tmp_path / "run"
    run_training(_tiny(keep=True), open_scenes(train), open_scenes(val), run, device="cpu", progress=False)
    return run


def test_pick_checkpoint_copies_the_kept_checkpoint_the_rule_chose(kept_run, capsys):
    from pipelines.cli import main
    run = kept_run
    assert main(["pick-checkpoint", str(run), "--rule", "worst"]) == 0
    scenes = _rows(run / "val_scenes.csv")
    floors = {int(s): min(float(r["psnr_aligned"]) for r in scenes if r["step"] == s) for s in {r["step"] for r in scenes}}
    want = min(floors, key=lambda s: (-floors[s], s))
    picked = load_checkpoint(run / "best_worst.pt")
    assert picked["step"] == want
    assert (run / "best_worst.pt").read_bytes() == (run / VALIDATED_DIR / validated_name(want)).read_bytes()
    table = capsys.readouterr().out
    assert table.splitlines()[2].startswith(f"| {want} | {floors[want]:.2f} |")
    # the mean rule over every scene is best.pt's own choice
    assert main(["pick-checkpoint", str(run), "--rule", "mean"]) == 0
    assert load_checkpoint(run / "best_mean.pt")["step"] == load_checkpoint(run / "best.pt")["step"]


def test_pick_checkpoint_refuses_a_run_that_kept_none(tmp_path, data, capsys):
    from pipelines.cli import main
    train, val = data
    run = tmp_path / "run"
    run_training(_tiny(keep=False, max_steps=2), open_scenes(train), open_scenes(val), run, device="cpu",
                 progress=False)
    assert main(["pick-checkpoint", str(run), "--rule", "worst"]) == 2
    assert "--keep-validated" in capsys.readouterr().err
    assert not (run / "best_worst.pt").exists()


def test_average_writes_the_mean_of_the_last_kept_weights(kept_run, capsys):
    from model.methods import method_from_spec
    from pipelines.cli import main
    run = kept_run
    assert main(["pick-checkpoint", str(run), "--average", "3"]) == 0
    got = load_checkpoint(run / "average_last_3.pt")
    assert got["extra"]["averaged_steps"] == [2, 3, 4] and got["optimizer_state"] is None
    states = [load_checkpoint(run / VALIDATED_DIR / validated_name(s))["model_state"] for s in (2, 3, 4)]
    for key, value in got["model_state"].items():
        want = (states[0][key].double() + states[1][key].double() + states[2][key].double()) / 3
        assert value.dtype == states[0][key].dtype
        assert torch.allclose(value.double(), want, rtol=0, atol=1e-6)
    assert any(not torch.equal(states[0][k], states[2][k]) for k in states[0])  # a mean of different weights
    # a network `evaluate` and `reconstruct` take as they take best.pt
    method_from_spec(f"avg={run / 'average_last_3.pt'}", device="cpu")
    assert main(["pick-checkpoint", str(run), "--average", "5"]) == 2
    assert "4 kept checkpoint(s), fewer than the 5" in capsys.readouterr().err
    assert main(["pick-checkpoint", str(run), "--average", "2", "--set", "val"]) == 2
