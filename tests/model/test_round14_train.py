"""Round fourteen (docs/robustness.md): `train --resume` puts back a config.json damaged or edited
since the run started, so the folder's record says what the run goes on with."""
from __future__ import annotations

import json

import pytest

from model.config import ExperimentConfig, ModelConfig, TrainConfig
from modeltest_fakes import make_scene
from pipelines.train import run_training


def _experiment(**train) -> ExperimentConfig:
    base = dict(num_windows=3, crop=16, batch_size=2, epochs=1000, lr=3e-3, lr_milestones=(999,),
                samples_per_epoch=4, val_crop=16, val_max_samples=1, val_every=1000, seed=0)
    base.update(train)
    return ExperimentConfig("test", model=ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2),
                            train=TrainConfig(**base))


@pytest.mark.parametrize("damage", ["garbage", json.dumps({"name": "other"}), None])
def test_resume_rewrites_a_damaged_config_record(tmp_path, capsys, damage):
    scenes = [make_scene(f"s{i}", 16, 20, 7 * 6, brightness=0.3, velocity=0.2, seed=i) for i in range(2)]
    out = tmp_path / "run"
    run_training(_experiment(max_steps=1), scenes[:1], scenes[1:], out, device="cpu", progress=False)
    want = json.loads((out / "config.json").read_text())
    if damage is None:
        (out / "config.json").unlink()
    else:
        (out / "config.json").write_text(damage)
    capsys.readouterr()
    run_training(_experiment(max_steps=1), scenes[:1], scenes[1:], out, device="cpu", progress=False, resume=True)
    assert json.loads((out / "config.json").read_text()) == want
    why = "missing" if damage is None else "unreadable" if damage == "garbage" else "not the config the run goes on with"
    assert f"{out / 'config.json'}: {why}; rewritten" in capsys.readouterr().err


def test_resume_leaves_an_intact_config_record_alone(tmp_path, capsys):
    scenes = [make_scene(f"s{i}", 16, 20, 7 * 6, brightness=0.3, velocity=0.2, seed=i) for i in range(2)]
    out = tmp_path / "run"
    run_training(_experiment(max_steps=1), scenes[:1], scenes[1:], out, device="cpu", progress=False)
    stamp = (out / "config.json").stat().st_mtime_ns
    run_training(_experiment(max_steps=1), scenes[:1], scenes[1:], out, device="cpu", progress=False, resume=True)
    assert (out / "config.json").stat().st_mtime_ns == stamp
    assert "rewritten" not in capsys.readouterr().err
