"""Checkpoints are data, never code: a crafted `.pt` cannot run its pickle payload through any
command that loads checkpoints, and a foreign, corrupt or empty one is a one-line error naming
the file. Files are written with the user's umask."""
from __future__ import annotations

import json
import os
import stat

import pytest
import torch

from model.arch import build_model
from model.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint
from model.config import ExperimentConfig, ModelConfig, TrainConfig
from modeltest_fakes import make_scene
from cli_testing import run_cli

TINY = ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2)


def tiny_experiment() -> ExperimentConfig:
    return ExperimentConfig("tinysafe", model=TINY,
                            train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=1, lr_milestones=(5,),
                                              samples_per_epoch=1, val_fraction=0.0, max_steps=1))


class Payload:
    """Unpickling this creates `marker`: what a hostile checkpoint would do instead."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def hostile_checkpoint(path, marker):
    exp = tiny_experiment()
    torch.save({"format_version": 1, "experiment": exp.to_dict(), "model_state": Payload(str(marker))}, path)
    return path


@pytest.fixture(scope="module")
def dat(tmp_path_factory):
    from spikesim.stream import SpikeStream, write_dat
    sc = make_scene("r", 12, 16, 7 * 3, brightness=0.3)
    return write_dat(tmp_path_factory.mktemp("dat") / "s.dat", SpikeStream.from_bool(sc.spike_array))


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("cfg") / "tinysafe.json"
    p.write_text(json.dumps(tiny_experiment().to_dict()))
    return p




def assert_one_line(err: str, *words: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], (w, lines[0])


def commands(kind, path, dat, dataset, config_file, tmp_path):
    """The three ways a checkpoint reaches the loader: reconstruct --method, evaluate --methods,
    train --resume (reads <out>/last.pt)."""
    if kind == "reconstruct":
        return ["reconstruct", dat, "--height", 12, "--width", 16, "--out", tmp_path / "rec", "--method", path,
                "--device", "cpu", "--quiet", "--no-mp4"]
    if kind == "evaluate":
        return ["evaluate", "--data", dataset, "--methods", path, "--window", 7, "--out", tmp_path / "ev",
                "--device", "cpu", "--quiet"]
    run = tmp_path / "run"
    run.mkdir(exist_ok=True)
    os.replace(path, run / "last.pt")
    return ["train", "--config", config_file, "--data", dataset, "--out", run, "--resume", "--device", "cpu",
            "--quiet"]


COMMANDS = ["reconstruct", "evaluate", "train"]


@pytest.mark.parametrize("kind", COMMANDS)
def test_a_pickle_payload_never_runs(kind, tmp_path, capsys, dat, dataset, config_file):
    marker = tmp_path / "pwned"
    evil = hostile_checkpoint(tmp_path / "evil.pt", marker)
    rc, err = run_cli(commands(kind, evil, dat, dataset, config_file, tmp_path), capsys)
    assert not marker.exists(), "the checkpoint's pickle payload ran"
    assert rc == 2
    assert_one_line(err, ".pt", "not a checkpoint of this project")


def test_load_checkpoint_refuses_code_directly(tmp_path):
    marker = tmp_path / "pwned"
    with pytest.raises(ValueError, match=r"evil.pt"):
        load_checkpoint(hostile_checkpoint(tmp_path / "evil.pt", marker))
    assert not marker.exists()


def _real_checkpoint(path):
    torch.manual_seed(0)
    save_checkpoint(path, build_model(TINY), tiny_experiment())
    return path


def _bad_files(tmp_path):
    real = _real_checkpoint(tmp_path / "real.pt").read_bytes()
    files = {
        "empty.pt": b"",
        "truncated.pt": real[: len(real) // 2],
        # torch's zip reader fails on these cuts with "[Errno 22] Invalid argument" (an OSError), naming no file
        "cut_5000.pt": real[:5000],
        "cut_eighth.pt": real[: len(real) // 8],
        "garbage.pt": os.urandom(4096),
        "text.pt": b'{"not": "a checkpoint"}\n',
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    torch.save({"weights": torch.zeros(3)}, tmp_path / "foreign.pt")  # a valid torch file, not ours
    exp = tiny_experiment().to_dict()
    exp["model"]["num_features"] = 16  # weights that do not fit the network the config describes
    torch.save({"format_version": 1, "experiment": exp, "model_state": build_model(TINY).state_dict()},
               tmp_path / "mismatch.pt")
    torch.save({"format_version": 1, "experiment": [1, 2], "model_state": {}}, tmp_path / "badconfig.pt")
    return [*files, "foreign.pt", "mismatch.pt", "badconfig.pt"]


@pytest.mark.parametrize("kind", COMMANDS)
def test_corrupt_empty_or_foreign_checkpoints_are_one_line_errors(kind, tmp_path, capsys, dat, dataset,
                                                                  config_file):
    for name in _bad_files(tmp_path):
        rc, err = run_cli(commands(kind, tmp_path / name, dat, dataset, config_file, tmp_path), capsys)
        assert rc == 2, (name, err)
        assert_one_line(err, name if kind != "train" else "last.pt")


def test_bad_checkpoints_raise_value_errors_naming_the_file(tmp_path):
    for name in _bad_files(tmp_path):
        with pytest.raises(ValueError, match=name.replace(".", r"\.")):
            model_from_checkpoint(tmp_path / name)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        load_checkpoint(tmp_path / "missing.pt")
    (tmp_path / "dir.pt").mkdir()
    with pytest.raises(IsADirectoryError, match="dir.pt"):
        load_checkpoint(tmp_path / "dir.pt")


def test_everything_the_trainer_stores_loads_weights_only(tmp_path):
    """Checkpoints written before this change hold the same plain types (tensors, numbers,
    strings, the scheduler's Counter), so they still load, with weights_only=True."""
    exp = tiny_experiment()
    model = build_model(TINY)
    opt = torch.optim.Adam(model.parameters())
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=[3, 5])
    scaler = torch.amp.GradScaler("cuda", enabled=False)
    save_checkpoint(tmp_path / "full.pt", model, exp, opt, sched, scaler, epoch=2, step=9,
                    extra={"batch_in_epoch": 1, "best_val_psnr": float("-inf")})
    torch.load(tmp_path / "full.pt", weights_only=True)  # nothing outside torch's allow-list
    state = load_checkpoint(tmp_path / "full.pt")
    assert state["epoch"] == 2 and state["scheduler_state"]["milestones"] == {3: 1, 5: 1}
    again, exp2 = model_from_checkpoint(tmp_path / "full.pt")
    assert exp2 == exp


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o077, 0o600)])
def test_checkpoint_mode_follows_the_umask(tmp_path, mask, mode):
    old = os.umask(mask)
    try:
        _real_checkpoint(tmp_path / "c.pt")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "c.pt").stat().st_mode) == mode
    assert [p.name for p in tmp_path.iterdir()] == ["c.pt"]


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the machine without a GPU")
@pytest.mark.parametrize("kind", COMMANDS)
def test_device_cuda_without_a_gpu_is_one_line(kind, tmp_path, capsys, dat, dataset, config_file):
    argv = {"reconstruct": ["reconstruct", dat, "--height", 12, "--width", 16, "--out", tmp_path / "o"],
            "evaluate": ["evaluate", "--data", dataset, "--window", 7, "--out", tmp_path / "o"],
            "train": ["train", "--config", config_file, "--data", dataset, "--out", tmp_path / "o"]}[kind]
    rc, err = run_cli(argv + ["--device", "cuda"], capsys)
    assert rc == 2
    assert_one_line(err, "--device cuda", "no CUDA")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("kind", COMMANDS)
@pytest.mark.parametrize("device", ["gpu", "cuda:x", "meta"])
def test_unknown_device_is_one_line(kind, device, tmp_path, capsys, dat, dataset, config_file):
    argv = {"reconstruct": ["reconstruct", dat, "--height", 12, "--width", 16, "--out", tmp_path / "o"],
            "evaluate": ["evaluate", "--data", dataset, "--window", 7, "--out", tmp_path / "o"],
            "train": ["train", "--config", config_file, "--data", dataset, "--out", tmp_path / "o"]}[kind]
    rc, err = run_cli(argv + ["--device", device], capsys)
    assert rc == 2
    assert_one_line(err, "--device")
