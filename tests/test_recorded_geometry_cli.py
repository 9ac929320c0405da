"""`inspect` and `reconstruct` read a stream's size and row order from what is recorded beside
it (its sidecar `<name>.dat.json`, or a dataset scene's `meta.json`), so a user passes none of
them; flags given explicitly win over the record."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cli_testing import one_line, run_cli
from spikesim.stream import SpikeStream, write_dat, write_sidecar

H, W, N = 6, 10, 28


def top_row_stream() -> SpikeStream:
    """Only the top image row fires, every step: the row order shows in any reconstruction."""
    frames = np.zeros((N, H, W), dtype=bool)
    frames[:, 0, :] = True
    return SpikeStream.from_bool(frames)


@pytest.fixture(params=["sidecar", "dataset"])
def recorded(request, tmp_path):
    """A top-down (flip=False) 6 x 10 stream whose geometry is written only beside it."""
    if request.param == "sidecar":
        path = write_dat(tmp_path / "s.dat", top_row_stream(), flip=False)
        write_sidecar(path, {"height": H, "width": W, "flip": False})
    else:
        scene = tmp_path / "llr" / "fan_low"
        scene.mkdir(parents=True)
        path = write_dat(scene / "spikes.dat", top_row_stream(), flip=False)
        (scene / "meta.json").write_text(json.dumps({"height": H, "width": W, "flip": False, "num_steps": N}))
    return path


def run_inspect(path, capsys, *flags):
    capsys.readouterr()
    from pipelines.cli import main
    code = main([str(a) for a in ["inspect", path, "--json", *flags]])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


def reconstructed_rows(path, out, capsys, *flags) -> np.ndarray:
    """Mean reconstruction per image row (TFP over one 7-step window)."""
    code, err = run_cli(["reconstruct", path, "--out", out, "--window", 7, "--num-windows", 1, "--save-npy",
                         "--no-gif", "--no-mp4", "--quiet", "--device", "cpu", *flags], capsys)
    assert code == 0, err
    return np.load(out / "frames.npy")[0].mean(axis=1)


def test_inspect_reads_size_and_row_order_from_the_record(recorded, capsys):
    info = run_inspect(recorded, capsys)
    assert (info["num_steps"], info["height"], info["width"], info["flip"]) == (N, H, W, False)
    assert info["header_columns"] == 0 and info["spikes"] == N * W


def test_reconstruct_reads_size_and_row_order_from_the_record(recorded, tmp_path, capsys):
    rows = reconstructed_rows(recorded, tmp_path / "o", capsys)
    summary = json.loads((tmp_path / "o" / "reconstruct.json").read_text())
    assert (summary["height"], summary["width"], summary["flip"]) == (H, W, False)
    assert rows[0] > 0 and not rows[1:].any()  # the top row is on top: the recorded flip was used


def test_explicit_flags_win_over_the_record(recorded, tmp_path, capsys):
    """The same bytes read as 10 x 6 bottom-up, because the user says so."""
    flags = ("--height", W, "--width", H, "--header-columns", 0, "--flip")
    info = run_inspect(recorded, capsys, *flags)
    assert (info["height"], info["width"], info["flip"]) == (W, H, True)
    rows = reconstructed_rows(recorded, tmp_path / "o", capsys, *flags)
    summary = json.loads((tmp_path / "o" / "reconstruct.json").read_text())
    assert (summary["height"], summary["width"], summary["flip"]) == (W, H, True)
    assert rows.shape == (W,)


def test_an_explicit_flip_alone_wins(recorded, tmp_path, capsys):
    assert run_inspect(recorded, capsys, "--flip")["flip"] is True
    rows = reconstructed_rows(recorded, tmp_path / "o", capsys, "--flip")
    assert rows[-1] > 0 and not rows[:-1].any()  # read bottom-up, the firing row lands at the bottom


def test_a_size_that_contradicts_the_record_is_one_line_naming_it(recorded, tmp_path, capsys):
    """Without --header-columns the record decides how rows are laid out; a contradicting size is
    refused (naming the record and the flags that read the file otherwise), never misread."""
    for argv in (["inspect", recorded, "--height", W, "--width", H],
                 ["reconstruct", recorded, "--height", W, "--width", H, "--out", tmp_path / "o"]):
        code, err = run_cli(argv, capsys)
        line = one_line(err)
        record = "meta.json" if recorded.name == "spikes.dat" else recorded.name + ".json"
        assert code == 2 and record in line, line
        assert "--header-columns" in line


def test_without_a_record_the_pku_camera_is_assumed(tmp_path, capsys):
    frames = np.zeros((3, 250, 400), dtype=bool)
    frames[:, 0, 0] = True
    path = write_dat(tmp_path / "raw.dat", SpikeStream.from_bool(frames))  # bottom-up, as real cameras
    info = run_inspect(path, capsys)
    assert (info["height"], info["width"], info["flip"], info["spikes"]) == (250, 400, True, 3)


@pytest.mark.parametrize("command", ["inspect", "reconstruct"])
def test_a_record_that_does_not_fit_the_file_is_named_in_the_error(recorded, tmp_path, capsys, command):
    """A stale sidecar or meta.json (here one row too many) is blamed, not the file: the one line
    names the record the size came from and the flags that override it."""
    record = recorded.parent / "meta.json" if recorded.name == "spikes.dat" else recorded.with_name("s.dat.json")
    info = json.loads(record.read_text())
    record.write_text(json.dumps({**info, "height": H + 1}))
    argv = [command, recorded] + (["--out", tmp_path / "o"] if command == "reconstruct" else [])
    code, err = run_cli(argv, capsys)
    line = one_line(err)
    assert code == 2 and f"height {H + 1}, width {W}" in line and record.name in line, line
    assert "--height/--width" in line
    assert not (tmp_path / "o").exists()
