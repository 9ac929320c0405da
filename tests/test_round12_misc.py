"""Round twelve, library and lock findings: the output lock on a full disk (M3) and the holder it
names (L2), model.reconstruct streaming a file (M4) and taking a SpikeStream or a NumPy integer
window (L3, L4), Simulator.run refusing integer frames (L1), the stream I/O's argument checks
(L4) and the README's BatchSimulator comment (L5)."""
from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from cli_testing import one_line, run_cli
from spikesim.stream import DatReader, DatWriter, SpikeStream, write_dat

ROOT = Path(__file__).resolve().parents[1]


def _dat(path: Path, steps: int = 70, h: int = 12, w: int = 16, seed: int = 0) -> Path:
    spikes = np.random.default_rng(seed).random((steps, h, w)) < 0.2
    return write_dat(path, SpikeStream.from_bool(spikes), flip=False)


# ---- M3: a full disk at the lock file ---------------------------------------------------------------
def _no_space(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_full_disk_at_the_lock_names_it_and_leaves_no_folder(tmp_path, capsys, monkeypatch):
    """`reconstruct s.dat -o full/r` on a full disk: "[Errno 28] No space left on device" naming no
    file, and full/r/ left behind holding an empty .spikesim.lock."""
    dat = _dat(tmp_path / "s.dat")
    out = tmp_path / "full" / "r"
    monkeypatch.setattr(os, "pwrite", _no_space)
    rc, err = run_cli(["reconstruct", dat, "--height", 12, "--width", 16, "--window", 7, "--method", "tfp",
                       "--header-columns", 0, "-o", out, "--no-mp4", "--quiet"], capsys)
    line = one_line(err)
    assert rc == 2 and "No space left on device" in line and str(out / ".spikesim.lock") in line, line
    assert not (tmp_path / "full").exists()  # the folders made for the run are gone with the lock


def test_a_lock_that_cannot_be_written_is_removed_and_named(tmp_path, monkeypatch):
    from spikesim.generation.lock import output_lock
    monkeypatch.setattr(os, "pwrite", _no_space)
    with pytest.raises(OSError) as info:
        with output_lock(tmp_path, "reconstruct x", what="reconstruct run"):
            pytest.fail("the block ran without a lock record")
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(tmp_path / ".spikesim.lock")
    assert list(tmp_path.iterdir()) == []  # a folder that existed stays, without the lock file


# ---- L2: the holder's own command ------------------------------------------------------------------
@pytest.mark.parametrize("recorded,kind", [
    ("sweep", "sweep run"),
    ("spikesim generate --config c.toml -o data", "generate run"),
    ("/x/.venv/bin/python -m pipelines.cli train tiny", "train run"),
])
def test_a_held_lock_names_the_holders_command_not_the_blocked_one(recorded, kind, tmp_path):
    """A sweep holding MIX: `tradeoff -o MIX` said "another tradeoff run is writing here (pid N: sweep)"."""
    from spikesim.generation.lock import OutputLockedError, output_lock
    with output_lock(tmp_path, recorded, what="sweep run"):
        with pytest.raises(OutputLockedError) as info:
            with output_lock(tmp_path, "tradeoff", what="tradeoff run"):
                pass
    assert f"another {kind} is writing here (pid {os.getpid()}: {recorded})" in str(info.value), str(info.value)
    assert "tradeoff" not in str(info.value)


# ---- M4, L3, L4: model.reconstruct --------------------------------------------------------------------
@pytest.mark.parametrize("method", ["tfp", "tfi", "lrrep"])
def test_reconstruct_of_a_path_reads_it_in_chunks_with_the_same_frames(method, tmp_path, monkeypatch):
    """model.reconstruct(path) loaded the whole stream (reader.read().unpack(), then a copy): 3.6 GB
    for a 40 MB file, where `spikesim reconstruct` streams it."""
    import model
    steps, window, chunk = 41 * 6 + 5, 41, 2
    dat = _dat(tmp_path / "s.dat", steps=steps)
    full = model.reconstruct(DatReader(dat, 12, 16, flip=False).read().unpack(), method=method, chunk=chunk)
    reads: list[tuple[int, int]] = []
    real = DatReader.read

    def spy(self, start=0, stop=None):
        got = real(self, start, stop)
        reads.append((start, start + got.num_steps))
        return got

    monkeypatch.setattr(DatReader, "read", spy)
    frames = model.reconstruct(dat, method=method, chunk=chunk, height=12, width=16, flip=False,
                             header_columns=0)
    assert frames.dtype == np.float32 and frames.shape == (6, 12, 16)
    assert np.array_equal(frames, full)  # bit-identical to the whole stream in memory
    # a window average holds `chunk` windows; a network one piece of its 5 training windows (its horizon)
    held = chunk if method != "lrrep" else 5
    assert reads and max(b - a for a, b in reads) <= held * window < steps, reads
    if method == "lrrep":  # the one-shot pass over the whole stream holds `chunk` windows too
        reads.clear()
        whole = model.reconstruct(dat, method=method, chunk=chunk, height=12, width=16, flip=False,
                                  header_columns=0, horizon="all")
        assert whole.shape == (6, 12, 16) and reads and max(b - a for a, b in reads) <= chunk * window, reads


def test_reconstruct_takes_a_spike_stream_and_a_numpy_window(tmp_path):
    """DatReader(...).read(0, 82) was refused as "expected a 0/1 or bool array, got dtype object";
    window=np.int64(41) was refused while height=np.int64(16) was taken."""
    import model
    dat = _dat(tmp_path / "s.dat", steps=100)
    part = DatReader(dat, 12, 16, flip=False).read(0, 82)
    want = model.reconstruct(part.unpack(), method="tfp")
    assert np.array_equal(model.reconstruct(part, method="tfp"), want)
    assert np.array_equal(model.reconstruct(part, method="tfp", window=np.int64(41), height=np.int64(12)), want)
    assert np.array_equal(model.reconstruct(dat, method="tfp", window=np.int64(41), height=12, width=16,
                                            flip=False, header_columns=0), want)
    with pytest.raises(ValueError, match="window"):
        model.reconstruct(part, method="tfp", window=np.int64(40))
    with pytest.raises(ValueError, match="flip: applies to a .dat path"):
        model.reconstruct(part, method="tfp", flip=True)


# ---- L1: Simulator.run and integer frames ---------------------------------------------------------
@pytest.mark.parametrize("dtype", [np.uint8, np.int64, np.uint16])
def test_simulator_refuses_integer_frames(dtype):
    """An 8-bit image (200) was taken as y = 200 spikes per step: a saturated stream, silently."""
    from spikesim import SpikeCamera
    from spikesim.simulate import Simulator
    sim = Simulator(SpikeCamera.realistic(height=4, width=8), seed=0, backend="numpy")
    with pytest.raises(ValueError, match="float luminance") as info:
        sim.run(np.full((5, 4, 8), 200, dtype))
    assert "astype(np.float32)" in str(info.value) and "/ 255" in str(info.value)
    stream = Simulator(SpikeCamera.realistic(height=4, width=8), seed=0, backend="numpy").run(
        np.full((5, 4, 8), 0.05, np.float64))
    assert stream.shape == (5, 4, 8)


# ---- L4: the stream I/O's arguments ------------------------------------------------------------------
def test_writers_refuse_an_array_naming_what_they_take(tmp_path):
    frames = np.zeros((3, 4, 8), bool)
    with DatWriter(tmp_path / "a.dat", 4, 8) as w:
        with pytest.raises(TypeError, match="expected a SpikeStream.*SpikeStream.from_bool"):
            w.write(frames)
        w.write(SpikeStream.from_bool(frames))
    with pytest.raises(TypeError, match="write_dat: expected a SpikeStream.*from_bool"):
        write_dat(tmp_path / "b.dat", frames)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.dat"]  # no temporary file left


def test_chunk_sizes_must_be_positive(tmp_path):
    dat = _dat(tmp_path / "s.dat", steps=10, h=4, w=8)
    reader = DatReader(dat, 4, 8, flip=False)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="chunk must be a positive number"):
            reader.iter_chunks(bad)
        with pytest.raises(ValueError, match="chunk must be a positive number"):
            reader.read().counts(chunk=bad)
    assert [len(c) for c in reader.iter_chunks(4)] == [4, 4, 2]
    assert int(reader.read().counts(chunk=3).sum()) == int(reader.read().unpack().sum())


@pytest.mark.parametrize("frames", [np.full((2, 3, 8), 0.3), np.full((2, 3, 8), 255, np.uint8),
                                    np.full((2, 3, 8), np.nan), np.full((2, 3, 8), -1, np.int8),
                                    np.full((2, 3, 8), "1")], ids=["0.3", "255", "nan", "-1", "str"])
def test_from_bool_refuses_what_is_not_0_or_1(frames):
    with pytest.raises(ValueError, match="0 and 1"):
        SpikeStream.from_bool(frames)


def test_from_bool_takes_0_1_numbers_and_bools():
    ones = SpikeStream.from_bool(np.ones((2, 3, 8), np.uint8))
    assert ones == SpikeStream.from_bool(np.ones((2, 3, 8), bool)) == SpikeStream.from_bool(np.ones((2, 3, 8)))


# ---- L5: the README ------------------------------------------------------------------------------------
def test_the_readme_says_batch_simulator_returns_a_list_of_streams():
    text = (ROOT / "README.md").read_text()
    line = next(ln for ln in text.splitlines() if "BatchSimulator(SpikeCamera" in ln and ".run(" in ln)
    assert "(3, 250, 400) each" not in line and "list of 3" in line, line
