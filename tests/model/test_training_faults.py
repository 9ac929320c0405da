"""The fourth hostile round on training and checkpoints (issue 30's surfaces): a damaged or
non-file log on resume, a checkpoint's config nested far too deep, counts past 64 bits, and a
full disk while a checkpoint is written. Each is a one-line error naming what is wrong (rc 2 in
the commands), never a traceback or a hang."""
from __future__ import annotations

import errno
import os

import pytest
import torch

from model.checkpoint import atomic_torch_save, load_checkpoint
from model.config import ExperimentConfig, TrainConfig
from modeltest_fakes import make_scene
from pipelines.train import run_training
from test_model_training import tiny_experiment


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A two-step run and its scenes."""
    scenes = [make_scene(f"s{i}", 16, 20, 7 * 6, brightness=0.3, velocity=0.2, seed=i) for i in range(3)]
    out = tmp_path_factory.mktemp("run")
    run_training(tiny_experiment(max_steps=2), scenes[:2], scenes[2:], out, device="cpu", progress=False)
    return out, scenes


def _copy(src, dst):
    import shutil
    shutil.copytree(src, dst)
    return dst


@pytest.mark.parametrize("text, msg", [
    ("garbage\nx\n", "its header is"),
    ("time,epoch,step,loss,lr,samples_per_s,data_wait_s\nV,1,abc,1,1,1,1\n", "line 2 has no step number"),
])
def test_a_damaged_log_is_refused_on_resume_naming_it(finished, tmp_path, text, msg):
    src, scenes = finished
    run = _copy(src, tmp_path / "r")
    header = (run / "train_log.csv").read_text().splitlines()[0]
    text = text.replace("time,epoch,step,loss,lr,samples_per_s,data_wait_s", header)
    (run / "train_log.csv").write_text(text)
    with pytest.raises(ValueError, match=f"train_log.csv is damaged: .*{msg}"):
        run_training(tiny_experiment(max_steps=4), scenes[:2], scenes[2:], run, device="cpu", resume=True,
                     progress=False)


def test_a_log_that_is_a_fifo_is_refused_not_waited_on(finished, tmp_path):
    src, scenes = finished
    run = _copy(src, tmp_path / "r")
    (run / "train_log.csv").unlink()
    os.mkfifo(run / "train_log.csv")
    with pytest.raises(ValueError, match="train_log.csv is a FIFO"):
        run_training(tiny_experiment(max_steps=4), scenes[:2], scenes[2:], run, device="cpu", resume=True,
                     progress=False)


def test_a_checkpoint_whose_config_nests_too_deep_is_refused(finished, tmp_path):
    src, _ = finished
    state = load_checkpoint(src / "last.pt")
    deep: list = []
    for _ in range(300):  # past the bound (64); a hostile file nested 20,000 deep hit RecursionError
        deep = [deep]
    state["experiment"]["deep"] = deep
    torch.save(state, tmp_path / "deep.pt")
    from model.checkpoint import model_from_checkpoint
    with pytest.raises(ValueError, match="nested deeper than 64 levels"):
        model_from_checkpoint(tmp_path / "deep.pt")


def test_counts_past_64_bits_are_refused_naming_the_field():
    with pytest.raises(ValueError, match=r"train.samples_per_epoch must be a positive integer \(at most 2\*\*62\)"):
        TrainConfig(samples_per_epoch=10 ** 23)
    assert TrainConfig(samples_per_epoch=10 ** 18).samples_per_epoch == 10 ** 18
    with pytest.raises(ValueError, match="train.epochs"):
        ExperimentConfig.from_dict({"name": "x", "train": {"epochs": 2 ** 70}})


def test_a_full_disk_while_a_checkpoint_is_written_is_an_oserror_naming_it(tmp_path, monkeypatch):
    def short_write(obj, f, *a, **k):  # what torch's zip writer raises when the disk fills
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 64 vs 0")
    monkeypatch.setattr(torch, "save", short_write)
    monkeypatch.setattr(os, "statvfs", lambda p: os.statvfs_result((4096, 4096, 10, 0, 0, 10, 0, 0, 0, 255)))
    with pytest.raises(OSError) as err:
        atomic_torch_save({"a": 1}, tmp_path / "last.pt")
    assert err.value.errno == errno.ENOSPC and str(tmp_path / "last.pt") in str(err.value)
    assert "writing the checkpoint failed" in str(err.value)
    assert not (tmp_path / "last.pt").exists() and not list(tmp_path.glob(".*.part"))


def test_a_log_field_past_the_csv_limit_is_damage_not_a_traceback(finished, tmp_path):
    src, scenes = finished
    run = _copy(src, tmp_path / "r")
    with open(run / "train_log.csv", "a") as f:
        f.write("1,0,1," + "9" * 300_000 + ",0.001,1,0\n")
    with pytest.raises(ValueError, match="train_log.csv is damaged: field larger than field limit"):
        run_training(tiny_experiment(max_steps=4), scenes[:2], scenes[2:], run, device="cpu", resume=True,
                     progress=False)


def test_an_output_name_too_long_is_a_parser_error():
    import argparse

    from pipelines.argtypes import output_dir
    with pytest.raises(argparse.ArgumentTypeError, match="File name too long"):
        output_dir("/tmp/" + "o" * 300)
