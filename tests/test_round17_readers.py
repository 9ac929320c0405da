"""Round seventeen: a `.dat` that is not a regular file (a FIFO) is refused by inspect, reconstruct
and panel before it is opened; read_dat follows the recorded flip; reading zero frames of a flipped
stream is an empty stream; a read's start/stop and open_stream's header_columns are checked; train
--resume refuses a config.json that is a FIFO; camera's --preset/--overwrite without --write are
refused; verify reports more damaged manifest fields."""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from cli_testing import one_line, run_cli
from spikesim.stream import DatReader, SpikeStream, open_stream, read_dat, write_dat, write_sidecar

pytestmark = pytest.mark.timeout(60)  # a FIFO opened for reading blocks: the test fails instead of hanging


def _stream(tmp_path: Path, flip: bool = True, name: str = "s.dat", steps: int = 6) -> tuple[Path, np.ndarray]:
    frames = np.random.default_rng(1).random((steps, 16, 24)) < 0.3
    path = write_dat(tmp_path / name, SpikeStream.from_bool(frames), flip=flip)
    write_sidecar(path, {"height": 16, "width": 24, "flip": flip, "num_steps": steps})
    return path, frames


# ---- A: a FIFO given as a stream ----------------------------------------------------------------
@pytest.mark.parametrize("argv", [["inspect"], ["inspect", "--height", "32", "--width", "48"],
                                  ["reconstruct", "--height", "32", "--width", "48", "-o", "r"],
                                  ["panel", "--methods", "tfp", "-o", "p.png"]])
def test_a_fifo_given_as_a_stream_is_not_a_regular_file(tmp_path, capsys, monkeypatch, argv):
    """inspect waited forever on it (reading 6 magic bytes); reconstruct and panel said "0 steps
    leave no full 41-step window"."""
    monkeypatch.chdir(tmp_path)
    os.mkfifo("f.dat")
    rc, err = run_cli([argv[0], "f.dat", *argv[1:]], capsys)
    assert rc == 2
    assert "f.dat" in one_line(err) and "not a regular file" in err


def test_the_readers_refuse_a_fifo_naming_it(tmp_path):
    os.mkfifo(tmp_path / "f.dat")
    for read in (lambda: DatReader(tmp_path / "f.dat", 4, 8), lambda: open_stream(tmp_path / "f.dat", 4, 8),
                 lambda: read_dat(tmp_path / "f.dat", 4, 8)):
        with pytest.raises(ValueError, match=r"f\.dat.*not a regular file"):
            read()


# ---- B: read_dat's flip follows the record ------------------------------------------------------
def test_read_dat_follows_the_recorded_flip_unless_given(tmp_path):
    path, frames = _stream(tmp_path, flip=False)
    assert np.array_equal(read_dat(path, 16, 24).unpack(), frames)
    assert read_dat(path, 16, 24) == DatReader(path).read()
    assert np.array_equal(read_dat(path, 16, 24, flip=True).unpack(), frames[:, ::-1, :])  # given: it wins


def test_read_dat_takes_the_recorded_geometry_as_datreader_does(tmp_path):
    """read_dat(path) defaulted to 250 x 400 where DatReader(path) read the sidecar's 16 x 24: the
    same file refused by one reader and read by the other."""
    path, frames = _stream(tmp_path, flip=False)
    got = read_dat(path)
    assert (got.height, got.width) == (16, 24) and np.array_equal(got.unpack(), frames)
    assert read_dat(path, start=2, stop=4) == DatReader(path).read(2, 4)
    # no record: the PKU camera's 250 x 400, rows bottom-up, as before
    bare = tmp_path / "bare.dat"
    pku = np.random.default_rng(2).random((2, 250, 400)) < 0.1
    write_dat(bare, SpikeStream.from_bool(pku))
    assert np.array_equal(read_dat(bare).unpack(), pku)
    # a geometry given wins over the record (and is checked against the file's size)
    with pytest.raises(ValueError, match="not a whole number"):
        read_dat(path, 17, 24)


# ---- C: zero frames of a flipped stream; start/stop types ----------------------------------------
def test_zero_frames_of_a_flipped_stream_are_an_empty_stream(tmp_path):
    path, _ = _stream(tmp_path, flip=True)
    (tmp_path / "e.dat").write_bytes(b"")
    for got in (DatReader(path).read(5, 5), DatReader(tmp_path / "e.dat", 32, 48).read(),
                read_dat(tmp_path / "e.dat", 32, 48), DatReader(tmp_path / "e.dat", 32, 400, header_columns=16).read(),
                DatReader(tmp_path / "e.dat", 3, 5, header_columns=3).read()):
        assert got.num_steps == 0 and got.unpack().shape[0] == 0


@pytest.mark.parametrize("start,stop,name", [(0, 2.5, "stop"), ("0", 5, "start"), (True, 5, "start")])
def test_read_refuses_a_start_or_stop_that_is_not_an_integer(tmp_path, start, stop, name):
    path, _ = _stream(tmp_path)
    with pytest.raises(ValueError, match=f"{name} must be an integer"):
        DatReader(path).read(start, stop)
    assert DatReader(path).read(np.int64(1), np.int64(3)).num_steps == 2


# ---- D: header_columns ---------------------------------------------------------------------------
@pytest.mark.parametrize("value", [2.7, True, "2", "x", -1])
def test_open_stream_and_reconstruct_check_header_columns(tmp_path, value):
    import model

    path, _ = _stream(tmp_path, flip=True, steps=41)
    with pytest.raises(ValueError, match="header_columns must be"):
        open_stream(path, 16, 24, header_columns=value)
    with pytest.raises(ValueError, match="header_columns must be"):
        model.reconstruct(path, method="tfp", height=16, width=24, header_columns=value)
    assert open_stream(path, 16, 24, header_columns=np.int64(0))[1] == 0


# ---- E: train --resume with a config.json that is a FIFO ----------------------------------------
def test_resume_refuses_a_config_record_that_is_a_fifo_before_saying_anything(tmp_path, capsys):
    from model.training import _restore_config_record

    os.mkfifo(tmp_path / "config.json")
    with pytest.raises(OSError, match=r"not a regular file.*config\.json"):
        _restore_config_record(tmp_path, None)
    assert "rewritten" not in capsys.readouterr().err
    assert not (tmp_path / "config.json").is_file()  # the FIFO was not replaced


# ---- F: camera flags that go with --write --------------------------------------------------------
@pytest.mark.parametrize("argv,flag", [(["--preset", "noiseless"], "--preset"), (["realistic", "--preset", "noiseless"], "--preset"),
                                       (["--overwrite"], "--overwrite"), (["--preset", "realistic"], "--preset")])
def test_camera_refuses_write_flags_without_write(capsys, argv, flag):
    rc, err = run_cli(["camera", *argv], capsys)
    assert rc == 2
    line = one_line(err)
    assert line.startswith(f"spikesim camera: error: {flag}") and "goes with --write" in line


def test_camera_write_still_takes_preset_and_overwrite(tmp_path, capsys):
    path = tmp_path / "c.toml"
    assert run_cli(["camera", "--write", path, "--preset", "noiseless"], capsys)[0] == 0
    assert run_cli(["camera", "--write", path, "--overwrite"], capsys)[0] == 0
    assert run_cli(["camera"], capsys)[0] == 0


# ---- G: manifest fields verify checks ------------------------------------------------------------
def _one_scene_dataset(root: Path, info: dict) -> None:
    from spikesim.dataset import write_manifest, write_scene

    rng = np.random.default_rng(0)
    write_scene(root, "s_low", SpikeStream.from_bool(rng.random((8, 4, 6)) < 0.3),
                {4: rng.random((4, 6)).astype(np.float32)}, meta={})
    write_manifest(root, info)


GENERATED = {"kind": "llr", "seed": 3, "preset": {"name": "small", "height": 4, "width": 6}, "jobs": {"s_low": "ab12"}}


@pytest.mark.parametrize("field,value", [
    ("layout_version", -5), ("layout_version", 0), ("preset", {}), ("preset", {"name": "small", "height": "x"}),
    ("preset", {"name": "small", "height": 4, "width": -64}), ("preset", {"height": True, "width": 6}),
    ("gt_saturated_fraction", "x"), ("gt_saturated_fraction", {"s_low": "x"}),
    ("gt_saturated_fraction", {"s_low": math.nan}), ("gt_saturated_fraction", {"s_low": -3}),
    ("gt_saturated_fraction", {"s_low": 1.5}), ("jobs", {"s_low": "ab12", "nope": "cd34"}), ("kind", "zzz")])
def test_verify_reports_more_edited_manifest_fields(tmp_path, field, value):
    from spikesim.dataset import MANIFEST, verify

    root = tmp_path / "ds"
    _one_scene_dataset(root, GENERATED)
    assert verify(root) == []
    doc = json.loads((root / MANIFEST).read_text())
    doc[field] = value
    (root / MANIFEST).write_text(json.dumps(doc, allow_nan=True))
    assert any(p.startswith(f"{MANIFEST}: {field}") for p in verify(root)), verify(root)


@pytest.mark.parametrize("info", [GENERATED, {**GENERATED, "kind": "demo"}, {**GENERATED, "kind": "scene"},
                                  {"kind": "rllr", "preset": {"steps": 8}}, {"kind": "test"}, {}])
def test_verify_keeps_taking_the_manifests_the_project_writes(tmp_path, info):
    """generate's kinds (llr, rllr, scene; demo's "demo") with their jobs; a manifest written by
    write_manifest alone (no jobs) names any kind; a scene written before its saturation was
    recorded has None; layout 1 is still read."""
    from spikesim.dataset import MANIFEST, verify

    root = tmp_path / "ds"
    _one_scene_dataset(root, info)
    assert verify(root) == []
    doc = json.loads((root / MANIFEST).read_text())
    doc["gt_saturated_fraction"] = {"s_low": None}
    doc["layout_version"] = 1
    (root / MANIFEST).write_text(json.dumps(doc))
    assert verify(root) == []


def test_a_scene_dropped_from_the_manifest_takes_its_job_with_it(tmp_path):
    """drop_from_manifest (a scene about to be rebuilt) left its job digest behind, which verify
    now reports as a job for a scene the manifest does not list."""
    from spikesim.dataset import MANIFEST, drop_from_manifest, verify

    root = tmp_path / "ds"
    _one_scene_dataset(root, GENERATED)
    drop_from_manifest(root, ["s_low"])
    assert "s_low" not in json.loads((root / MANIFEST).read_text())["jobs"]
    assert verify(root) == []


@pytest.mark.parametrize("folder", [".", "/", ".."])
def test_a_folder_given_as_a_stream_is_named_not_a_pathlib_error(folder, capsys, tmp_path):
    """`spikesim inspect .` said "PosixPath('.') has an empty name" (the recorded-geometry lookup asked
    pathlib for the sidecar of a path with no name); now every reader says the path is a folder."""
    with pytest.raises(ValueError, match="names a folder, not a spike stream"):
        read_dat(folder)
    for argv in (["inspect", folder], ["reconstruct", folder, "-o", tmp_path / "frames"]):
        rc, err = run_cli(argv, capsys)
        assert rc == 2 and f"{folder}: names a folder, not a spike stream" in one_line(err)
