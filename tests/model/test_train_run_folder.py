"""A run owns its folder: one run at a time (a lock), and `spikesim train --resume` continues a
run's own plan across a process restart: a run cut by a signal and resumed with no flags ends at the step it planned, with the weights of a run never cut."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[2]
CONFIG = {"name": "resumecli",
          "model": {"num_features": 4, "num_blocks": 1, "deform_groups": 1, "window": 7,
                    "interval_transform": "inverse"},
          "train": {"num_windows": 2, "crop": 8, "batch_size": 1, "epochs": 1000, "samples_per_epoch": 2,
                    "lr": 1e-3, "lr_schedule": "cosine", "ckpt_every_steps": 1, "val_fraction": 0.0,
                    "precision": "fp32"}}


def _train(args, **kw) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "pipelines.cli", "train", *map(str, args), "--threads", "1",
                           "--quiet", "--device", "cpu"], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=300, **kw)


def _weights(run: Path) -> dict:
    return torch.load(run / "last.pt", weights_only=True)["model_state"]


def test_a_cut_run_resumed_without_flags_keeps_its_plan_and_ends_as_an_uncut_one(dataset, tmp_path):
    cfg = tmp_path / "resumecli.json"
    cfg.write_text(json.dumps(CONFIG))
    steps = 80
    straight = _train(["--config", cfg, "--data", dataset, "--max-steps", steps, "-o", tmp_path / "a"])
    assert straight.returncode == 0, straight.stderr
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    cut = subprocess.Popen([sys.executable, "-m", "pipelines.cli", "train", "--config", str(cfg), "--data",
                            str(dataset), "--max-steps", str(steps), "-o", str(tmp_path / "b"), "--threads", "1",
                            "--quiet", "--device", "cpu"], cwd=REPO, env=env, stderr=subprocess.PIPE, text=True)
    log = tmp_path / "b" / "train_log.csv"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and cut.poll() is None:
        if log.exists() and len(log.read_text().splitlines()) > 4:  # a few steps in
            cut.send_signal(signal.SIGINT)
            break
        time.sleep(0.05)
    err = cut.communicate(timeout=240)[1]
    if cut.returncode == 0:
        pytest.skip("the run finished before the signal reached it: nothing was cut")
    assert cut.returncode == 130, err
    assert "--resume" in err and "stopped by" in err  # says where it stopped and how to go on
    at = torch.load(tmp_path / "b" / "last.pt", weights_only=True)["step"]
    assert 0 < at < steps
    resumed = _train(["--resume", "--data", dataset, "-o", tmp_path / "b"])  # no --config, no --max-steps
    assert resumed.returncode == 0, resumed.stderr
    assert f"resuming {tmp_path / 'b' / 'last.pt'} at step {at} of {steps}" in resumed.stderr
    assert torch.load(tmp_path / "b" / "last.pt", weights_only=True)["step"] == steps
    a, b = _weights(tmp_path / "a"), _weights(tmp_path / "b")
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_resume_refuses_a_config_that_is_not_the_runs(dataset, tmp_path):
    cfg = tmp_path / "resumecli.json"
    cfg.write_text(json.dumps(CONFIG))
    assert _train(["--config", cfg, "--data", dataset, "--max-steps", 2, "-o", tmp_path / "r"]).returncode == 0
    other = _train(["--resume", "--config", "tiny", "--data", dataset, "-o", tmp_path / "r"])
    assert other.returncode != 0 and "resumecli" in other.stderr and "Traceback" not in other.stderr


def test_a_second_run_into_a_folder_being_trained_is_refused_naming_the_holder(dataset, tmp_path):
    """Two `train --resume -o R` at once both finished, logging steps twice."""
    from model.config import ExperimentConfig
    from model.data import open_scenes
    from model.training import run_training
    from spikesim.generation.lock import OutputLockedError, output_lock
    exp = ExperimentConfig.from_dict({**CONFIG, "train": {**CONFIG["train"], "max_steps": 1}})
    (tmp_path / "r").mkdir()
    with output_lock(tmp_path / "r", "train resumecli (pid 12345)", what="train run"):
        with pytest.raises(OutputLockedError, match="another train run .*pid 12345"):
            run_training(exp, open_scenes(dataset), [], tmp_path / "r", device="cpu", progress=False)
    assert run_training(exp, open_scenes(dataset), [], tmp_path / "r", device="cpu", progress=False)["steps"] == 1
    assert not any(p.name.endswith(".lock") for p in (tmp_path / "r").iterdir())  # removed when the run ends
