"""The shipped weights: they load by name, match the model card's fingerprint, refuse a damaged
file, and reconstruct a small low-light stream better than one window of TFP does."""
from __future__ import annotations

import dataclasses
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from cli_testing import one_line, run_cli
from model import pretrained
from model.checkpoint import state_fingerprint
from model.methods import method_from_spec
from model.metrics import psnr_aligned
from model.pretrained import PRETRAINED, load_pretrained, pretrained_path
from model.streaming import TensorWindows

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", sorted(PRETRAINED))
def test_the_model_card_names_the_shipped_fingerprints(name):
    """docs/model.md's card and the registry agree, and the file on disk is the one they name, for
    the shipped network and every earlier one kept for comparison."""
    card = (ROOT / "docs" / "model.md").read_text()
    entry = PRETRAINED[name]
    assert re.search(rf"weights fingerprint[^\n]*`{entry.weights_sha256}`", card)
    assert re.search(rf"file sha256[^\n]*`{entry.file_sha256}`", card)
    path = pretrained_path(name)
    assert path.stat().st_size < 16 * 2**20
    model, experiment = load_pretrained(name)
    assert state_fingerprint(model.state_dict()) == entry.weights_sha256
    assert not model.training and model.max_interval == experiment.train.num_windows * experiment.model.window + 1


def test_the_shipped_network_is_the_budget_run_and_fine_tunes_with_its_named_config():
    """`lrrep` is the budget run's network (docs/model.md, "The budget run ships"): a refining
    network whose model section is the named config `lrrep_span_shot`'s, so `train --config
    lrrep_span_shot --init lrrep` starts from it, and its file says which run and command made it."""
    from model.checkpoint import load_checkpoint
    from model.config import load_config

    _, experiment = load_pretrained("lrrep")
    assert experiment.name == "lrrep_span_shot" and experiment.model == load_config("lrrep_span_shot").model
    assert experiment.model.output == "refine" and experiment.train.num_windows == 5
    provenance = load_checkpoint(pretrained_path("lrrep"))["extra"]["provenance"]
    assert provenance["seed"] == 21 and provenance["steps"] == 11000 and provenance["init"].startswith("a random draw")
    assert "DATA_VARIANT=procedural" in provenance["command"] and "budget_run.sh" in provenance["command"]
    card = (ROOT / "docs" / "model.md").read_text()
    assert provenance["command"] in card.replace("\n", " ")


def _still_scene(h: int = 48, w: int = 64) -> np.ndarray:
    """A bright square on a dim background, in low light (a few spikes per pixel per window)."""
    y = np.full((h, w), 0.004, np.float32)
    y[12:36, 16:48] = 0.03
    return y


def test_the_shipped_model_sees_structure_one_window_of_tfp_misses():
    from spikesim import SpikeCamera
    from spikesim.simulate import Simulator

    y = _still_scene()
    cam = dataclasses.replace(SpikeCamera.realistic(), height=y.shape[0], width=y.shape[1])
    stream = Simulator(cam, backend="numpy", seed=0).run([y] * (5 * 41))
    spikes = torch.from_numpy(np.asarray(stream.unpack())).reshape(5, 41, *y.shape)
    frames = {}
    for spec in ("tfp", "lrrep"):
        out = dict(method_from_spec(spec).frames(TensorWindows(spikes)))
        assert sorted(out) == list(range(5))
        frames[spec] = out[2].numpy()
    assert frames["lrrep"].shape == y.shape and np.isfinite(frames["lrrep"]).all()
    assert psnr_aligned(frames["lrrep"], y) > psnr_aligned(frames["tfp"], y) + 3


def test_a_damaged_shipped_file_is_refused(tmp_path, monkeypatch):
    copy = tmp_path / "weights"
    copy.mkdir()
    shutil.copy(pretrained_path("lrrep"), copy / PRETRAINED["lrrep"].file)
    data = bytearray((copy / PRETRAINED["lrrep"].file).read_bytes())
    data[len(data) // 2] ^= 0x10
    (copy / PRETRAINED["lrrep"].file).write_bytes(bytes(data))
    monkeypatch.setattr(pretrained, "WEIGHTS_DIR", copy)
    with pytest.raises(ValueError, match="damaged or was replaced"):
        load_pretrained("lrrep")
    with pytest.raises(ValueError, match="no shipped weights called 'nope'"):
        load_pretrained("nope")


def test_reconstruct_and_evaluate_take_lrrep_by_name(tmp_path, capsys):
    from spikesim import SpikeCamera
    from spikesim.simulate import Simulator

    y = _still_scene(32, 40)
    cam = dataclasses.replace(SpikeCamera.realistic(), height=32, width=40)
    dat = Simulator(cam, backend="numpy", seed=1).run_to_dat([y] * 123, tmp_path / "s.dat", flip=False)
    rc, err = run_cli(["reconstruct", dat, "--method", "lrrep", "-o", tmp_path / "rec", "--no-gif", "--no-mp4"], capsys)
    assert rc == 0, err
    assert len(list((tmp_path / "rec").rglob("*.png"))) == 3
    np.save(tmp_path / "gt.npy", y)
    rc, err = run_cli(["evaluate", "--dat", dat, "--gt", tmp_path / "gt.npy", "--center", 61, "--methods", "tfp",
                       "lrrep", "--json"], capsys)
    assert rc == 0, one_line(err)
