"""Round eleven (issue 40): outputs inside a dataset are refused by every command and by the
training API, but only a spikesim dataset's manifest counts; demo scores and draws only the scenes
asked for and drops its own stale previews; SIGTERM to sweep cleans up; a recorded readout period
outside any camera's range is refused."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cli_testing import one_line, run_cli

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def dataset_root(tmp_path):
    ds = tmp_path / "ds"
    (ds / "fan_low").mkdir(parents=True)
    (ds / "manifest.json").write_text(json.dumps({"scenes": {}}))
    return ds


@pytest.mark.parametrize("argv", [
    lambda ds: ["golden", "--write", "--seeds", "1", "-o", ds / "golden.json"],
    lambda ds: ["camera", "--write", ds / "mine.toml"],
    lambda ds: ["simulate", "--steps", "50", "--height", "8", "--width", "8", "--backend", "numpy", "--quiet",
                "-o", ds / "fan_low" / "extra.dat"],
    lambda ds: ["sweep", "--scenes", "fan", "--methods", "tfp", "--levels", "2", "--height", "16", "--width", "24",
                "--windows", "1", "--spp", "1", "--gt-spp", "1", "--quiet", "-o", ds / "sw"],
    lambda ds: ["tradeoff", "--scenes", "fan", "--light", "low", "--height", "16", "--width", "24", "-o", ds / "t",
                "--quiet"],
], ids=["golden", "camera", "simulate", "sweep", "tradeoff"])
def test_commands_refuse_an_output_inside_a_dataset(dataset_root, capsys, argv):
    before = sorted(p.name for p in dataset_root.rglob("*"))
    code, err = run_cli(argv(dataset_root), capsys)
    assert code == 2 and "inside the dataset" in err, err
    assert sorted(p.name for p in dataset_root.rglob("*")) == before


def test_reconstruct_refuses_an_output_inside_a_dataset(dataset_root, tmp_path, capsys):
    import numpy as np
    from spikesim.stream import SpikeStream, write_dat
    dat = write_dat(tmp_path / "s.dat", SpikeStream.from_bool(np.ones((41, 8, 8), bool)))
    code, err = run_cli(["reconstruct", dat, "--height", 8, "--width", 8, "-o", dataset_root / "fan_low" / "rec",
                         "--no-mp4", "--quiet"], capsys)
    assert code == 2 and "inside the dataset" in err, err
    assert not (dataset_root / "fan_low" / "rec").exists()


def test_the_training_api_refuses_a_run_inside_a_dataset(dataset_root):
    from model.config import load_config
    from model.training import run_training
    with pytest.raises(ValueError, match="out_dir .*inside the dataset"):
        run_training(load_config("tiny"), [], [], dataset_root / "apirun", device="cpu", progress=False)
    assert not (dataset_root / "apirun").exists()


def test_only_a_spikesim_manifest_makes_a_dataset(tmp_path):
    """A web app's manifest.json above an output blocked every output below it."""
    from spikesim.dataset import check_outside_datasets
    app = tmp_path / "webapp"
    app.mkdir()
    (app / "manifest.json").write_text(json.dumps({"name": "my web app", "start_url": "/"}))
    check_outside_datasets(app / "results")  # no error
    (app / "manifest.json").write_text(json.dumps({"scenes": {}}))
    with pytest.raises(ValueError, match="inside the dataset"):
        check_outside_datasets(app / "results")


def test_a_recorded_period_outside_every_cameras_range_is_refused(tmp_path, capsys):
    import numpy as np
    from spikesim.stream import SpikeStream, write_dat
    scene = tmp_path / "sc"
    scene.mkdir()
    write_dat(scene / "spikes.dat", SpikeStream.from_bool(np.zeros((41, 8, 8), bool)))
    (scene / "meta.json").write_text(json.dumps({"height": 8, "width": 8, "num_steps": 41,
                                                 "camera": {"readout_period_s": 1e-300}}))
    code, err = run_cli(["inspect", scene / "spikes.dat"], capsys)
    assert code == 2 and "readout_period_s 1e-300 s is outside" in err and "meta.json" in err, err


def test_demo_scores_and_draws_only_the_scenes_asked_for(tmp_path, capsys, monkeypatch):
    """-o/llr kept an earlier demo's fan: a demo of ball scored fan too and redrew its previews
    over the user's edit. A rerun's results record drops its own stale previews."""
    from spikesim.outputs import _results_record
    out = tmp_path / "d"
    seen = []
    import model.evaluation as evaluation
    original = evaluation.evaluate

    def spy(scenes, methods, *a, **k):
        seen.append(sorted(sc.name for sc in scenes))
        return original(scenes, methods, *a, **k)

    monkeypatch.setattr(evaluation, "evaluate", spy)
    argv = ["demo", "--windows", "1", "--no-model", "--workers", "1", "-o", out, "--quiet"]
    assert run_cli([*argv, "--scenes", "fan"], capsys)[0] == 0
    edited = out / "previews" / "fan_low_gt_p99.png"
    edited.write_bytes(b"the user's edit")
    assert run_cli([*argv, "--scenes", "ball"], capsys)[0] == 0
    assert seen[-1] == ["ball_low", "ball_normal"], seen
    assert edited.read_bytes() == b"the user's edit"
    listed = _results_record(out)
    assert "previews/fan_low_gt_p99.png" not in listed  # the user's now, no longer the demo's
    assert not (out / "previews" / "fan_normal_gt_p99.png").exists()  # the demo's own stale preview: removed
    assert "previews/ball_low_gt_p99.png" in listed


def test_sigterm_to_sweep_leaves_no_lock_and_no_temporary_folder(tmp_path):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "TMPDIR": str(tmp_path / "tmp")}
    (tmp_path / "tmp").mkdir()
    out = tmp_path / "sw"
    proc = subprocess.Popen([sys.executable, "-m", "pipelines.cli", "sweep", "--scenes", "fan", "--methods", "tfp",
                             "--levels", "9", "--height", "16", "--width", "24", "--windows", "3", "--spp", "1",
                             "--gt-spp", "4", "--quiet", "-o", str(out)], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (out / ".spikesim.lock").exists():
        time.sleep(0.05)
    assert (out / ".spikesim.lock").exists(), proc.communicate()
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode in (130, 143), (proc.returncode, err.decode())  # stopped, not finished before the signal
    assert not (out / ".spikesim.lock").exists(), err.decode()
    assert list((tmp_path / "tmp").iterdir()) == [], err.decode()


def test_a_ground_truth_scale_that_overflows_is_named_not_the_image(tmp_path):
    import numpy as np
    from spikesim.imageio import read_image_y
    np.save(tmp_path / "gt.npy", np.full((4, 4), 0.5, np.float32))
    for scale in (1e300, 1e39):
        with pytest.raises(ValueError, match="--gt-scale"):
            read_image_y(tmp_path / "gt.npy", scale)
    assert read_image_y(tmp_path / "gt.npy", 2.0).max() == 1.0


def test_an_output_inside_an_input_that_is_no_dataset_is_not_called_a_dataset(tmp_path, capsys):
    """`export FOLDER -o FOLDER/x` where FOLDER held no dataset said "inside the dataset FOLDER, whose
    files a manifest lists": there was no manifest. The check names no manifest where there is none,
    and export says first that its input is no dataset (or does not exist)."""
    from spikesim.dataset import check_outside_datasets
    plain = tmp_path / "plain"
    plain.mkdir()
    with pytest.raises(ValueError, match="inside the dataset .*plain, which this command reads") as err:
        check_outside_datasets(plain / "out", [plain])
    assert "manifest" not in str(err.value)
    code, err_text = run_cli(["export", plain, "--format", "spikezoo", "-o", plain / "x"], capsys)
    assert code == 2 and "holds no scene folders" in one_line(err_text)
    code, err_text = run_cli(["export", tmp_path / "nothere", "--format", "spikezoo", "-o", tmp_path / "nothere" / "x"],
                             capsys)
    assert code == 2 and "does not exist" in one_line(err_text)
