"""`panel --gt`: a simulated stream's ground truth drawn first, and each method's aligned PSNR
against it, the same number `evaluate` gives for that frame."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cli_testing import one_line, run_cli
from model.metrics import psnr_aligned
from pipelines.panel import GT_TILE, panel_frames, with_ground_truth
from spikesim import SpikeCamera
from spikesim.simulate import Simulator

H, W, WINDOWS = 32, 48, 5


def _still_pair(tmp_path: Path) -> tuple[Path, Path, np.ndarray]:
    """A bright square on a dim ground in low light (a few spikes per pixel per window), still, so
    the ground truth of every step is the same image."""
    y = np.full((H, W), 0.004, np.float32)
    y[8:24, 12:36] = 0.03
    cam = dataclasses.replace(SpikeCamera.realistic(), height=H, width=W)
    dat = Simulator(cam, backend="numpy", seed=3).run_to_dat([y] * (WINDOWS * 41), tmp_path / "s.dat", flip=False)
    np.save(tmp_path / "gt.npy", y)
    return dat, tmp_path / "gt.npy", y


def test_the_ground_truth_comes_first_and_each_method_is_scored_against_it(tmp_path, capsys):
    dat, gt_path, y = _still_pair(tmp_path)
    rc, err = run_cli(["panel", dat, "--methods", "tfp", "tfp:205", "--gt", gt_path, "-o", tmp_path / "p.png"],
                      capsys)
    assert rc == 0, err
    frames, _, _ = panel_frames(dat, ["tfp", "tfp:205"], frame=None)
    tiles, aligned = with_ground_truth(frames, y)
    assert list(tiles) == [GT_TILE, "TFP", "TFP-205"]
    # a still scene: the 5-window average is closer to the truth than one window, by several dB
    assert aligned["TFP-205"] > aligned["TFP"] + 3
    for name, frame in frames.items():
        assert aligned[name] == pytest.approx(psnr_aligned(frame, np.clip(y, 0, 1)))
    # three tiles of W columns side by side, with their margins
    assert Image.open(tmp_path / "p.png").width >= 3 * W


def test_the_json_record_holds_the_aligned_psnr_and_the_ground_truth(tmp_path, capsys):
    from pipelines.cli import main

    dat, gt_path, y = _still_pair(tmp_path)
    capsys.readouterr()
    assert main(["panel", str(dat), "--methods", "tfp", "tfp:205", "--gt", str(gt_path), "--gt-scale", "2",
                 "-o", str(tmp_path / "p.png"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["ground_truth"] == {"path": str(gt_path), "scale": 2.0} and "psnr_aligned" in doc["measures"]
    frames, _, _ = panel_frames(dat, ["tfp", "tfp:205"])
    # the aligned PSNR fits a gain, so a ground truth twice as bright scores the same up to its clipping
    _, expected = with_ground_truth(frames, 2 * y)
    for name in ("TFP", "TFP-205"):
        assert doc["scores"][name]["psnr_aligned"] == pytest.approx(expected[name])
    # without --gt the record has no such number and no ground-truth tile
    assert main(["panel", str(dat), "--methods", "tfp", "-o", str(tmp_path / "q.png"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "ground_truth" not in doc and "psnr_aligned" not in doc["scores"]["TFP"]


def test_a_ground_truth_of_another_size_is_refused_before_anything_is_written(tmp_path, capsys):
    dat, _, y = _still_pair(tmp_path)
    np.save(tmp_path / "small.npy", y[:, :40])
    rc, err = run_cli(["panel", dat, "--methods", "tfp", "--gt", tmp_path / "small.npy", "-o", tmp_path / "p.png"],
                      capsys)
    line = one_line(err)
    assert rc != 0 and "32 x 40" in line and "32 x 48" in line and "--gt" in line
    assert not (tmp_path / "p.png").exists()


def test_a_bad_ground_truth_file_is_refused_by_name(tmp_path, capsys):
    dat, _, y = _still_pair(tmp_path)
    bad = y.copy()
    bad[0, 0] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    rc, err = run_cli(["panel", dat, "--gt", tmp_path / "nan.npy", "-o", tmp_path / "p.png"], capsys)
    assert rc != 0 and "nan.npy" in one_line(err) and "NaN" in err
    assert not (tmp_path / "p.png").exists()


def test_a_method_named_like_the_ground_truth_tile_is_refused():
    frame = np.zeros((4, 4))
    with pytest.raises(ValueError, match="ground truth"):
        with_ground_truth({GT_TILE: frame}, frame)
