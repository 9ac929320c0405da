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
