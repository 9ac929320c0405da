"""Round twenty-one (issue 40): what a hostile round found on round twenty's code, each checked here
on the behaviour it broke (docs/robustness.md, "Round twenty-one")."""
from __future__ import annotations

import dataclasses
import json
import logging
import os

import numpy as np
import pytest
from test_round20 import _dataset

from spikesim import SpikeCamera, Simulator
from spikesim.stream import SpikeStream, is_stream_sidecar, sidecar_path, write_dat


# ---- H1: a baseline's kept scores answer for their window ---------------------------------------------
def test_a_baseline_scored_at_another_window_is_scored_again(tmp_path):
    """`compare` into one -o with window 41, then 21: TFP's kept scores of window 41 were shown beside
    the window-21 networks ("1 kept from before"), rc 0."""
    from model.comparison import evaluate_runs
    from model.data import open_scenes
    scenes = open_scenes(_dataset(tmp_path / "test", 0.3, steps=180))
    out = tmp_path / "cmp"
    out.mkdir()

    def tfp(window, where):
        return {r.scene: (r.psnr_aligned, r.frames) for r in evaluate_runs({}, scenes, window, ["tfp"], out=where)}
    wide = tfp(21, out)
    narrow = tfp(7, out)
    assert narrow == tfp(7, None) and narrow != wide  # scored again: as a fresh comparison scores it
    assert tfp(21, out) == wide  # and each window's own scores are kept


# ---- H2: the simulator's own writer and the record's name ------------------------------------------------
def _frames():
    return np.full((6, 4, 8), 0.3, np.float32)


@pytest.mark.parametrize("kind", ["user file", "fifo", "link", "folder"])
def test_run_to_dat_refuses_what_is_not_a_streams_record_at_its_name(tmp_path, kind):
    """Simulator.run_to_dat replaced a user's other.json, a FIFO and a link at the record's name; the
    CLI refused them. Refused before simulating, the thing there kept."""
    sim = Simulator(SpikeCamera.realistic(height=4, width=8), backend="numpy", seed=0)
    side = tmp_path / "other.json"
    if kind == "user file":
        side.write_text('{"title": "my notes"}')
    elif kind == "fifo":
        os.mkfifo(side)
    elif kind == "link":
        (tmp_path / "target.json").write_text('{"mine": 1}')
        side.symlink_to(tmp_path / "target.json")
    else:
        side.mkdir()
    with pytest.raises((ValueError, IsADirectoryError)):
        sim.run_to_dat(_frames(), tmp_path / "other")
    assert not (tmp_path / "other").exists()
    if kind == "user file":
        assert json.loads(side.read_text()) == {"title": "my notes"}
    if kind == "link":
        assert side.is_symlink() and json.loads((tmp_path / "target.json").read_text()) == {"mine": 1}
    if kind == "fifo":
        assert not side.is_file() and os.path.exists(side)


def test_run_to_dat_replaces_an_earlier_streams_record_and_the_twin_checks_too(tmp_path):
    from spikesim.simulate import TwinSimulator
    sim = Simulator(SpikeCamera.realistic(height=4, width=8), backend="numpy", seed=0)
    out = sim.run_to_dat(_frames(), tmp_path / "a.dat")
    assert is_stream_sidecar(sidecar_path(out))
    sim.run_to_dat(np.full((9, 4, 8), 0.3, np.float32), out)  # its own earlier record: replaced
    assert json.loads(sidecar_path(out).read_text())["num_steps"] == 9
    (tmp_path / "t.dat.json").write_text('{"title": "my notes"}')
    with pytest.raises(ValueError, match=r"t\.dat\.json: exists and is not a stream's record"):
        TwinSimulator(Simulator(SpikeCamera.realistic(height=4, width=8), backend="numpy", seed=0),
                      None).run_to_dat(_frames(), tmp_path / "s.dat", tmp_path / "t.dat")
    assert not (tmp_path / "s.dat").exists()


# ---- M1: a resume with nothing to do --------------------------------------------------------------------
def test_a_resume_with_nothing_to_do_leaves_the_config_record_alone(tmp_path):
    """`train --resume --max-steps 1` of a run at step 2 said "nothing to do" after rewriting
    config.json to max_steps 1, where last.pt holds 2."""
    from model.config import ExperimentConfig, ModelConfig, TrainConfig
    from model.data import open_scenes
    from model.training import run_training
    data = _dataset(tmp_path / "train", 0.3)
    exp = ExperimentConfig("tiny21", model=ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2),
                           train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=1, lr_milestones=(5,),
                                             samples_per_epoch=2, val_fraction=0.0, max_steps=2))
    run_training(exp, open_scenes(data), [], tmp_path / "run", device="cpu", progress=False)
    before = (tmp_path / "run" / "config.json").read_bytes()
    shorter = dataclasses.replace(exp, train=dataclasses.replace(exp.train, max_steps=1))
    got = run_training(shorter, open_scenes(data), [], tmp_path / "run", device="cpu", resume=True, progress=False)
    assert got["nothing_to_do"] and (tmp_path / "run" / "config.json").read_bytes() == before


# ---- M2 and L1: the trade study's reconstruction scores and Monte Carlo probe ------------------------------
def test_edited_reconstruction_scores_are_scored_again(tmp_path, monkeypatch, caplog):
    """An edited <run>.recon.json (a list field set to 5, a field removed, "abc" for a PSNR) gave a
    TypeError traceback or an error naming no file; it is damage, scored again with a warning."""
    from types import SimpleNamespace

    from pipelines import tradeoff_study as tradeoff
    calls = []

    def fake_scores(packed, gt, cfg):
        calls.append(1)
        return {"recon_tfp_span": 41, "tfp_gt_psnr": 20.0, "tfp_gt_psnr_frames": [19.0, 21.0],
                "net_gt_psnr": float("nan"), "net_gt_psnr_frames": [], "recon_note": ""}
    monkeypatch.setattr(tradeoff, "recon_scores", fake_scores)
    cfg = SimpleNamespace(tfp_span=41, windows=1)

    def scores():
        return tradeoff.cached_recon_scores(tmp_path, "spp=4", "run", "ref", np.zeros(1), np.zeros(1), cfg)
    assert scores()["tfp_gt_psnr"] == 20.0 and len(calls) == 1
    got = scores()  # kept: "nan" read back as NaN, not as damage
    assert len(calls) == 1 and np.isnan(got["net_gt_psnr"])
    path = tmp_path / "spp=4.recon.json"
    good = json.loads(path.read_text())
    for edit in ({"tfp_gt_psnr_frames": 5}, {"tfp_gt_psnr": "abc"}, {"tfp_gt_psnr": True}, {"tfp_gt_psnr": None}):
        path.write_text(json.dumps({**good, **edit}))
        with caplog.at_level(logging.WARNING):
            assert scores()["tfp_gt_psnr"] == 20.0
        assert "damaged cache file" in caplog.text and str(path) in caplog.text
        caplog.clear()
    path.write_text(json.dumps({k: v for k, v in good.items() if k != "tfp_gt_psnr"}))
    scores()
    assert len(calls) == 6


@pytest.mark.parametrize("ratio", [True, -5, "12", 1e400, None])
def test_a_monte_carlo_ratio_that_is_not_a_finite_number_is_measured_again(tmp_path, ratio):
    from pipelines.tradeoff_study import _probe_of
    path = tmp_path / "mc_probe.json"
    path.write_text(json.dumps({"key": "k", "mc_ratio": ratio}).replace("Infinity", "1e400"))
    assert _probe_of(path, "k") is None
    path.write_text(json.dumps({"key": "k", "mc_ratio": 0}))
    assert _probe_of(path, "k") == {"key": "k", "mc_ratio": 0}


# ---- M3: the input normalisation's floor ---------------------------------------------------------------------
def test_a_floor_that_underflows_float32_is_refused_and_a_dark_window_stays_finite():
    import torch

    from model.arch import build_model
    from model.config import ModelConfig
    cfg = ModelConfig(num_features=8, num_blocks=1, deform_groups=2, interval_transform="inverse",
                      input_norm="window_rate")
    for bad in (1e-50, 1e-7):
        with pytest.raises(ValueError, match=r"input_norm_floor_rate must be a rate in \[1e-06, 1\]"):
            dataclasses.replace(cfg, input_norm_floor_rate=bad)
    net = build_model(dataclasses.replace(cfg, input_norm_floor_rate=1e-6)).eval()
    with torch.no_grad():
        out = net(torch.zeros(1, 3, 41, 8, 8, dtype=torch.bool))
    assert torch.isfinite(out).all()


# ---- L2: a look-alike of a record, and a FIFO where a folder should be ------------------------------------
def test_a_users_json_with_a_height_and_width_is_not_taken_for_a_record(tmp_path):
    """write_dat('geom') deleted geom.json holding a region of interest (height and width, no num_steps)."""
    roi = tmp_path / "geom.json"
    roi.write_text(json.dumps({"description": "my ROI", "height": 100, "width": 200, "x": 5, "y": 7}))
    write_dat(tmp_path / "geom", SpikeStream.from_bool(np.ones((3, 4, 8), bool)))
    assert json.loads(roi.read_text())["description"] == "my ROI"


def test_a_fifo_where_the_streams_folder_should_be_is_named(tmp_path):
    os.mkfifo(tmp_path / "f.dat")
    with pytest.raises(NotADirectoryError, match=r"is a FIFO \(named pipe\), not a folder, where the folder of x\.dat would be: .*f\.dat'"):
        write_dat(tmp_path / "f.dat" / "x.dat", SpikeStream.from_bool(np.ones((3, 4, 8), bool)))
    (tmp_path / "f.dat").unlink()  # (shutil.rmtree opens a FIFO, and waits)
