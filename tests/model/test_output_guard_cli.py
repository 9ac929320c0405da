"""Every output path stays inside -o, for the model's commands (reconstruct, train, evaluate,
compare, panel): a link planted in the output folder is refused with rc 2 and one line naming it,
the user's files it leads to stay byte-identical and nothing in their folder is deleted. A full
disk is one line naming the file, with no partial file and no new empty folder left. (Before,
`reconstruct` wrote and deleted through `png/`, `train` through `config.json`, the logs and `tb/`,
and a full disk named no file.)"""
from __future__ import annotations

import errno
import json

import numpy as np
import pytest
import torch

from cli_testing import one_line, run_cli
from model.config import ExperimentConfig, ModelConfig, TrainConfig
from modeltest_fakes import make_scene

TINY = ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2)


@pytest.fixture(scope="module")
def dat(tmp_path_factory):
    from spikesim.stream import SpikeStream, write_dat
    sc = make_scene("r", 12, 16, 7 * 3, brightness=0.3)
    return write_dat(tmp_path_factory.mktemp("dat") / "s.dat", SpikeStream.from_bool(sc.spike_array))


@pytest.fixture(scope="module")
def dat16(tmp_path_factory):
    """A stream big enough for panel's no-reference measures (16 x 16 at least)."""
    from spikesim.stream import SpikeStream, write_dat
    sc = make_scene("p", 16, 16, 7 * 3, brightness=0.3)
    return write_dat(tmp_path_factory.mktemp("dat16") / "p.dat", SpikeStream.from_bool(sc.spike_array))


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    exp = ExperimentConfig("tinyguard", model=TINY,
                           train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=1, lr_milestones=(5,),
                                             samples_per_epoch=1, val_fraction=0.0, max_steps=1))
    p = tmp_path_factory.mktemp("cfg") / "tinyguard.json"
    p.write_text(json.dumps(exp.to_dict()))
    return p


@pytest.fixture
def outside(tmp_path):
    """A user's folder outside the output, holding files a link could reach."""
    d = tmp_path / "elsewhere"
    d.mkdir()
    for name in ("step_000003.png", "keep.txt", "config.json", "train_log.csv", "frames.gif"):
        (d / name).write_bytes(b"the user's " + name.encode())
    return d


def snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def reconstruct(dat, out, *extra):
    return ["reconstruct", dat, "--height", 12, "--width", 16, "--window", 7, "--out", out, "--no-mp4", "--quiet",
            "--device", "cpu", *extra]


def train(config_file, dataset, out, *extra):
    return ["train", "--config", config_file, "--data", dataset, "--out", out, "--device", "cpu", "--quiet", *extra]


@pytest.mark.parametrize("link, to", [("png", "."), ("png/step_000003.png", "step_000003.png"),
                                      ("frames.gif", "frames.gif"), ("reconstruct.json", "keep.txt")])
@pytest.mark.parametrize("rerun", [False, True])
def test_reconstruct_refuses_a_link_in_its_output(dat, tmp_path, outside, capsys, link, to, rerun):
    out = tmp_path / "r"
    if rerun:  # a second run also deletes stale frames: it must not delete through the link
        assert run_cli(reconstruct(dat, out), capsys)[0] == 0
        if link == "png":
            import shutil
            shutil.rmtree(out / "png")
        else:
            (out / link).unlink()
    (out / link).parent.mkdir(parents=True, exist_ok=True)
    (out / link).symlink_to(outside / to if to != "." else outside)
    before = snapshot(outside)
    code, err = run_cli(reconstruct(dat, out, "--num-windows", 1), capsys)
    assert code == 2 and link.split("/")[0] in one_line(err), err
    assert snapshot(outside) == before
    assert (out / link).is_symlink()


def test_reconstruct_on_a_full_disk_names_the_file_and_leaves_no_folder(dat, tmp_path, monkeypatch, capsys):
    from PIL import Image

    def full(self, fp, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(Image.Image, "save", full)
    out = tmp_path / "new" / "r"
    code, err = run_cli(reconstruct(dat, out, "--no-gif"), capsys)
    line = one_line(err)
    assert code == 2 and "No space left on device" in line and str(out / "png" / "step_000003.png") in line, line
    assert not (tmp_path / "new").exists()  # the folders this run made are gone again


@pytest.mark.parametrize("link, to", [("config.json", "config.json"), ("tb", "."),
                                      ("train_log.csv", "train_log.csv"), ("last.pt", "keep.txt")])
@pytest.mark.parametrize("mode", [[], ["--overwrite"], ["--resume"]])
def test_train_refuses_a_link_in_its_run_folder(config_file, dataset, tmp_path, outside, capsys, link, to, mode):
    out = tmp_path / "t"
    out.mkdir()
    if mode == ["--resume"]:  # a finished run, continued: it appends to its logs and TensorBoard
        assert run_cli(train(config_file, dataset, out), capsys)[0] == 0
        import shutil
        shutil.rmtree(out / link) if (out / link).is_dir() else (out / link).unlink()
    (out / link).symlink_to(outside / to if to != "." else outside)
    before = snapshot(outside)
    code, err = run_cli(train(config_file, dataset, out, *mode), capsys)
    assert code == 2 and link in one_line(err), err
    assert snapshot(outside) == before and (out / link).is_symlink()


def test_train_refuses_a_dangling_link_where_it_writes(config_file, dataset, tmp_path, capsys):
    out = tmp_path / "t"
    out.mkdir()
    (out / "config.json").symlink_to(tmp_path / "created_outside.json")
    code, err = run_cli(train(config_file, dataset, out), capsys)
    assert code == 2 and "config.json" in one_line(err)
    assert not (tmp_path / "created_outside.json").exists()


def test_train_on_a_full_disk_names_the_checkpoint(config_file, dataset, tmp_path, monkeypatch, capsys):
    def full(obj, f, *a, **k):
        f.write(b"half a checkpoint")
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(torch, "save", full)
    out = tmp_path / "t"
    code, err = run_cli(train(config_file, dataset, out), capsys)
    line = err.strip().splitlines()[-1]  # after train's own notes
    assert code == 2 and "Traceback" not in err and line.startswith("spikesim train: error:"), err
    assert f"{out / 'last.pt'}: No space left on device" in line, line
    assert not (out / "last.pt").exists() and not [p for p in out.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("kind", ["evaluate", "panel"])
def test_a_link_at_a_temporary_file_name_is_not_written_through(dat16, dataset, tmp_path, outside, capsys, kind):
    """The temporary files had fixed names (.metrics.csv.part, .panel.png.part) opened for
    writing: a link planted there led the write outside. They are now made exclusively."""
    out = tmp_path / "o"
    out.mkdir()
    if kind == "evaluate":
        (out / ".metrics.csv.part").symlink_to(outside / "keep.txt")
        argv = ["evaluate", "--data", dataset, "--methods", "tfp", "--window", 7, "--out", out, "--device", "cpu",
                "--quiet"]
    else:
        (out / ".panel.png.part").symlink_to(outside / "keep.txt")
        argv = ["panel", dat16, "--height", 16, "--width", 16, "--window", 7, "--methods", "tfp",
                "-o", out / "panel.png", "--device", "cpu"]
    before = snapshot(outside)
    assert run_cli(argv, capsys)[0] == 0
    assert snapshot(outside) == before


def test_evaluate_refuses_a_link_to_its_results(dataset, tmp_path, outside, capsys):
    out = tmp_path / "ev"
    out.mkdir()
    (out / "metrics.csv").symlink_to(outside / "keep.txt")
    before = snapshot(outside)
    code, err = run_cli(["evaluate", "--data", dataset, "--methods", "tfp", "--window", 7, "--out", out,
                         "--device", "cpu", "--quiet"], capsys)
    assert code == 2 and "metrics.csv" in one_line(err), err
    assert snapshot(outside) == before and (out / "metrics.csv").is_symlink()


def test_evaluate_dat_writes_its_results_under_out(dat, tmp_path, capsys):
    gt = tmp_path / "gt.npy"
    np.save(gt, np.linspace(0.1, 0.5, 12 * 16, dtype=np.float32).reshape(12, 16))  # not constant: refused
    out = tmp_path / "ev"
    code, err = run_cli(["evaluate", "--dat", dat, "--gt", gt, "--center", 10, "--height", 12, "--width", 16,
                         "--methods", "tfp", "--window", 7, "--out", out, "--device", "cpu", "--quiet"], capsys)
    assert code == 0, err
    # the results and the record that says evaluate wrote them (a rerun replaces them, not a user's file)
    assert sorted(p.name for p in out.iterdir()) == [".spikesim-results.json", "metrics.csv", "metrics.md"]
    assert ",TFP," in (out / "metrics.csv").read_text()


def test_panel_refuses_a_link_as_its_output(dat, tmp_path, outside, capsys):
    (tmp_path / "panel.png").symlink_to(outside / "keep.txt")
    before = snapshot(outside)
    code, err = run_cli(["panel", dat, "--height", 12, "--width", 16, "--window", 7, "--methods", "tfp",
                         "-o", tmp_path / "panel.png", "--device", "cpu"], capsys)
    assert code == 2 and "panel.png" in one_line(err), err
    assert snapshot(outside) == before


def test_evaluate_json_alone_only_prints(dataset, tmp_path, capsys, monkeypatch):
    """`evaluate --json` without -o wrote results/evaluate/ into the working folder; it only
    prints now, and -o still writes."""
    import json
    monkeypatch.chdir(tmp_path)
    argv = ["evaluate", "--data", dataset, "--methods", "tfp", "--window", 7, "--device", "cpu", "--json"]
    capsys.readouterr()
    assert run_cli(argv, capsys)[0] == 0
    assert not (tmp_path / "results").exists()
    assert run_cli([*argv, "-o", tmp_path / "ev"], capsys)[0] == 0 and (tmp_path / "ev" / "metrics.csv").exists()
    capsys.readouterr()
    from pipelines.cli import main
    main([str(a) for a in argv])
    assert json.loads(capsys.readouterr().out)["methods"]
