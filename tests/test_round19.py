"""Round nineteen (docs/robustness.md): the tradeoff cache's damaged or odd files are damaged
files, not tracebacks or hangs, and only a killed simulate's own lock record lets a rerun remove
temporaries."""
from __future__ import annotations

import logging
import os
import socket
import zipfile

import numpy as np
import pytest

from cli_testing import one_line, run_cli

SIMULATE = ["simulate", "--steps", "30", "--height", "16", "--width", "24", "--backend", "numpy", "--quiet"]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    from pipelines import tradeoff_study as tradeoff
    out = tmp_path_factory.mktemp("r19") / "study"
    cfg = tradeoff.StudyConfig.of(scenes=("ball",), lights=("low",), resolution=(16, 24), windows=1, ref_spp=2,
                                  gt_spp=4, knobs=("precision",), repeats=1)
    rows = {r["run"]: r for r in tradeoff.run_study(cfg, out, progress=False)}
    return cfg, out, rows


def _zero_member(path, member):
    """Overwrite the compressed bytes of one member of a zip with zeros: inflating it fails (zlib)."""
    data = bytearray(path.read_bytes())
    info = zipfile.ZipFile(path).getinfo(member)
    o = info.header_offset
    n, e = int.from_bytes(data[o + 26:o + 28], "little"), int.from_bytes(data[o + 28:o + 30], "little")
    start = o + 30 + n + e
    data[start:start + info.compress_size] = bytes(info.compress_size)
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("member", ["cache_key.npy", "packed.npy"])
def test_a_cache_file_that_does_not_inflate_is_damaged_not_a_traceback(study, tmp_path, member):
    import shutil

    from pipelines import tradeoff_study as tradeoff
    cfg, src, rows = study
    out = tmp_path / "s"
    shutil.copytree(src, out)
    npz = out / "runs" / "ball_low" / "float32.npz"
    _zero_member(npz, member)
    with pytest.raises(ValueError, match="float32.npz: (damaged cache file|cached for another)"):
        tradeoff.collect_rows(cfg, out)  # --report-only: one line naming the file
    again = {r["run"]: r for r in tradeoff.run_study(cfg, out, progress=False)}  # measured again
    assert again["float32"]["rate_err"] == pytest.approx(rows["float32"]["rate_err"], rel=1e-9)


def test_reference_frames_that_do_not_inflate_are_rendered_again(study, tmp_path, caplog):
    import shutil

    from pipelines import tradeoff_study as tradeoff
    cfg, src, rows = study
    out = tmp_path / "s"
    shutil.copytree(src, out)
    _zero_member(out / "runs" / "ball_low" / "reference_frames.npz", "frames.npy")
    (out / "runs" / "ball_low" / "float32.json").unlink()
    caplog.set_level(logging.WARNING)
    again = {r["run"]: r for r in tradeoff.run_study(cfg, out, progress=False)}
    assert not again["float32"]["render_reused"] and "render them again" in caplog.text
    assert again["float32"]["rate_err"] == pytest.approx(rows["float32"]["rate_err"], rel=1e-9)


def test_a_fifo_at_a_cache_file_is_named_not_waited_on(study, tmp_path):
    import shutil

    from pipelines import tradeoff_study as tradeoff
    cfg, src, _ = study
    out = tmp_path / "s"
    shutil.copytree(src, out)
    npz = out / "runs" / "ball_low" / "float32.npz"
    npz.unlink()
    os.mkfifo(npz)
    with pytest.raises(ValueError, match="float32.npz: is a FIFO"):  # named before the run is measured (round twenty)
        tradeoff._is_cached(npz.with_suffix(".json"), npz, "any")
    with pytest.raises(ValueError, match="float32.npz: is a FIFO"):
        tradeoff.collect_rows(cfg, out)
    with pytest.raises(ValueError, match="float32.npz: is a FIFO"):  # the study does not replace it either
        tradeoff.run_study(cfg, out, progress=False)
    assert not npz.is_file()


@pytest.mark.parametrize("content", [b"hello\n", b"\0\0"])
def test_a_lock_without_a_holders_record_removes_no_temporary(tmp_path, capsys, content):
    folder = tmp_path / "L"
    folder.mkdir()
    mine = folder / ".a.dat.0123abcd.part"
    mine.write_text("keep")
    (folder / ".a.dat.spikesim-lock").write_bytes(content)
    rc, err = run_cli([*SIMULATE, "-o", folder / "a.dat"], capsys)
    assert rc == 0, err
    assert mine.read_text() == "keep"


def test_a_socket_at_the_lock_is_named(tmp_path, capsys):
    folder = tmp_path / "s"
    folder.mkdir()
    sock = socket.socket(socket.AF_UNIX)
    try:
        sock.bind(str(folder / ".a.dat.spikesim-lock"))
        rc, err = run_cli([*SIMULATE, "-o", folder / "a.dat"], capsys)
    finally:
        sock.close()
    assert rc == 2 and "is a socket, not a regular file, where spikesim keeps the lock of a.dat" in one_line(err)
