"""Round ten, reconstruct: a rerun owns an output by its content (reconstruct.json records each
one's sha256), a reconstruct.json that is no run's record is refused before any work, and every
method holds --chunk windows at once (TFP and TFI held 64 whatever it said), with the same frames."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch

from cli_testing import run_cli
from modeltest_fakes import make_scene
from model.methods import method_from_spec
from model.streaming import TensorWindows


@pytest.fixture
def dat(tmp_path):
    from spikesim.stream import SpikeStream, write_dat
    sc = make_scene("r", 12, 16, 7 * 5, brightness=0.3)
    return write_dat(tmp_path / "s.dat", SpikeStream.from_bool(sc.spike_array))


def _base(dat, out):
    return ["reconstruct", dat, "--height", 12, "--width", 16, "--window", 7, "--out", out, "--no-mp4", "--quiet"]


def _tree(root):
    return {p.relative_to(root).as_posix(): (p.read_bytes() if p.is_file() else None) for p in root.rglob("*")}


def test_a_users_content_over_a_runs_output_is_kept(dat, tmp_path, capsys):
    """The user's own array saved over a run's frames.npy was deleted by a rerun, rc 0 (round ten):
    the record lists names only. It records each output's sha256; a changed one is the user's."""
    out = tmp_path / "r2"
    assert run_cli(_base(dat, out) + ["--save-npy"], capsys)[0] == 0
    record = json.loads((out / "reconstruct.json").read_text())
    assert set(record["sha256"]) == {"frames.gif", "frames.npy", *(f"png/{n}" for n in record["png_frames"])}
    np.save(out / "frames.npy", np.ones((2, 3), np.float32))  # the user's array, over the run's
    mine = (out / "frames.npy").read_bytes()
    code, err = run_cli(_base(dat, out) + ["--no-gif"], capsys)
    assert code == 2 and "holds frames.npy, changed since the reconstruct run wrote it" in err, err
    assert (out / "frames.npy").read_bytes() == mine
    frame = out / "png" / record["png_frames"][0]
    frame.write_bytes(b"my edit")
    (out / "frames.npy").unlink()
    code, err = run_cli(_base(dat, out), capsys)
    assert code == 2 and f"png/{frame.name}, changed since" in err and frame.read_bytes() == b"my edit"
    frame.unlink()
    assert run_cli(_base(dat, out) + ["--num-windows", 2], capsys)[0] == 0  # unchanged outputs are its own


def test_a_record_older_than_its_digests_keeps_the_name_rule(dat, tmp_path, capsys):
    out = tmp_path / "old"
    assert run_cli(_base(dat, out) + ["--save-npy"], capsys)[0] == 0
    record = json.loads((out / "reconstruct.json").read_text())
    del record["sha256"]
    (out / "reconstruct.json").write_text(json.dumps(record))
    np.save(out / "frames.npy", np.ones((2, 3), np.float32))
    assert run_cli(_base(dat, out), capsys)[0] == 0 and not (out / "frames.npy").exists()


@pytest.mark.parametrize("kind", ["notes", "json", "folder", "fifo"])
def test_a_reconstruct_json_that_is_no_record_is_refused_before_any_work(dat, tmp_path, capsys, kind):
    """The user's notes at reconstruct.json were overwritten (round ten); a folder there was found
    only after png/ and frames.gif were moved in, rc 2, and the rerun refused them."""
    out = tmp_path / "r1"
    out.mkdir()
    path = out / "reconstruct.json"
    if kind == "notes":
        path.write_text("my notes\n")
    elif kind == "json":
        path.write_text(json.dumps({"experiment": 3}))
    elif kind == "folder":
        path.mkdir()
    else:
        os.mkfifo(path)
    before = _tree(out) if kind != "fifo" else None
    code, err = run_cli(_base(dat, out), capsys)
    assert code == 2 and "Traceback" not in err, err
    assert f"{path}: " in err and ("not a reconstruct record" in err or "where a reconstruct run writes" in err)
    assert sorted(p.name for p in out.iterdir()) == ["reconstruct.json"]
    if before is not None:
        assert _tree(out) == before


class _Counting:
    """A window source that remembers the most windows asked for at once."""

    def __init__(self, spikes):
        self.inner = TensorWindows(spikes)
        self.num_windows, self.window, self.first_step = self.inner.num_windows, self.inner.window, 0
        self.most = 0

    def windows(self, start, stop):
        self.most = max(self.most, stop - start)
        return self.inner.windows(start, stop)


@pytest.mark.parametrize("spec", ["tfp", "tfi", "tfp:21", "stp", "snm", "mean"])
def test_every_method_holds_chunk_windows_and_makes_the_same_frames(spec):
    """TFP and TFI held 64 windows whatever --chunk said: 2.9 GB for a 51 MB stream (round ten)."""
    spikes = torch.from_numpy(np.random.default_rng(1).random((13, 7, 6, 5)) < 0.3)
    frames = {}
    for chunk in (1, 3, 13, 64):
        source = _Counting(spikes)
        method = method_from_spec(spec, 7, chunk)
        assert method.chunk == chunk
        frames[chunk] = torch.stack([f for _, f in method.frames(source)])
        assert source.most <= chunk
    assert all(torch.equal(frames[1], f) for f in frames.values())  # bit-identical


def test_reconstruct_chunk_reaches_tfp(dat, tmp_path, capsys, monkeypatch):
    from model.streaming import StepWindows
    most, real = [0], StepWindows.windows

    def counting(self, start, stop):
        most[0] = max(most[0], stop - start)
        return real(self, start, stop)
    monkeypatch.setattr(StepWindows, "windows", counting)
    for chunk in (1, 2):
        most[0] = 0
        assert run_cli(_base(dat, tmp_path / f"c{chunk}") + ["--chunk", chunk, "--save-npy"], capsys)[0] == 0
        assert most[0] == chunk
    assert np.array_equal(np.load(tmp_path / "c1" / "frames.npy"), np.load(tmp_path / "c2" / "frames.npy"))
