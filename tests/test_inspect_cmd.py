"""`spikesim inspect` streams the file: bounded memory whatever its length, the same figures as
`spikesim.stats.summary`, and one-line errors for bad ranges, flags and files."""
import json
import os
import tracemalloc

import numpy as np
import pytest

from pipelines import inspect_cmd
from pipelines.cli import main
from spikesim.stats import summary
from spikesim.stream import DatReader, SpikeStream, write_dat, write_sidecar
from cli_testing import run_cli, one_line


def structured_stream(n=300, h=10, w=24, seed=0):
    """Pixels of very different rates, some dark, some firing every step."""
    rng = np.random.default_rng(seed)
    y = rng.choice([0.0, 0.003, 0.05, 0.4, 1.0], size=(h, w))
    acc = rng.random((h, w))
    out = np.zeros((n, h, w), bool)
    for t in range(n):
        acc += y
        out[t] = acc >= 1
        acc[out[t]] -= 1
    return SpikeStream.from_bool(out)


@pytest.mark.parametrize("chunk", [1, 7, 41, 64, 1000])
def test_chunked_summary_equals_the_in_memory_one(tmp_path, chunk):
    s = structured_stream()
    write_dat(tmp_path / "s.dat", s)
    reader = DatReader(tmp_path / "s.dat", 10, 24)
    for start, stop, window in ((0, 300, 41), (13, 290, 5), (100, 140, 41)):
        got = inspect_cmd.summarize(reader, start, stop, 25e-6, window, chunk=chunk)
        want = summary(s.slice(start, stop), 25e-6, window=window)
        assert got.keys() == want.keys()
        for key in want:
            if isinstance(want[key], dict):
                assert got[key] == pytest.approx(want[key], rel=1e-12), key
            else:
                assert got[key] == pytest.approx(want[key], rel=1e-12), key


def test_isi_histogram_is_exact_below_its_bound_and_close_above():
    rng = np.random.default_rng(0)
    isi = np.concatenate([rng.integers(1, 5000, 10_000), rng.integers(70_000, 9_000_000, 2_000)])
    h = inspect_cmd.IsiHistogram()
    for part in np.array_split(isi, 7):
        h.add(part)
    assert (h.count, h.min, h.max, h.total) == (isi.size, isi.min(), isi.max(), isi.sum())
    assert h.percentile(50) == np.percentile(isi, 50)
    assert h.percentile(99) == pytest.approx(np.percentile(isi, 99), rel=0.012)  # 1/64 octave


def _sparse_file(path, frames, h, w, seed=0):
    """A long stream written in blocks (rate about 1 %), without building it in memory."""
    rng = np.random.default_rng(seed)
    nbytes = h * w // 8
    block = (rng.random((256, nbytes)) < 0.08).astype(np.uint8) << rng.integers(0, 8, (256, nbytes)).astype(np.uint8)
    with open(path, "wb") as f:
        for _ in range(frames // 256):
            f.write(block.tobytes())
    return path


def _peak_bytes(path, h, w):
    args = ["inspect", str(path), "--height", str(h), "--width", str(w), "--header-columns", "0", "--json"]
    tracemalloc.start()
    try:
        assert main(args) == 0
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_inspect_memory_is_bounded_independently_of_the_stream_length(tmp_path, capsys):
    h, w = 64, 128  # 1 KiB a frame; a chunk is 128 frames
    short = _sparse_file(tmp_path / "short.dat", 1024, h, w)  # 1 MiB
    long = _sparse_file(tmp_path / "long.dat", 24 * 1024, h, w)  # 24 MiB, 192 chunks
    _peak_bytes(short, h, w)  # imports and first-use allocations out of the way
    peak_short, peak_long = _peak_bytes(short, h, w), _peak_bytes(long, h, w)
    capsys.readouterr()
    budget = 8 << 20
    assert peak_long < budget, f"inspect peaked at {peak_long / 2**20:.1f} MiB on a 24 MiB stream"
    assert peak_long < peak_short + (1 << 20), (peak_short, peak_long)


# ---- errors -------------------------------------------------------------------------------------




@pytest.fixture
def dat(tmp_path):
    path = write_dat(tmp_path / "s.dat", structured_stream(n=50))
    write_sidecar(path, {"height": 10, "width": 24, "flip": True, "camera": {"readout_period_s": 25e-6}})
    return path


@pytest.mark.parametrize("flag, value", [("--start", -1), ("--window", 0), ("--stop", 0), ("--height", 0),
                                         ("--width", -1), ("--readout-period-s", 0), ("--readout-period-s", 1e9),
                                         ("--readout-period-s", "1e-12"), ("--header-columns", -2),
                                         ("--header-columns", "x"), ("--window", "1.5")])
def test_inspect_refuses_bad_values(flag, value, dat, capsys):
    code, err = run_cli(["inspect", dat, flag, value], capsys)
    assert code == 2 and "Traceback" not in err and f"argument {flag}" in err.strip().splitlines()[-1]


def test_inspect_prints_a_slow_readout_in_seconds_and_hertz(dat, capsys):
    """--readout-period-s 1e9 printed 205000000000000.000 ms at 0 Hz (round seven, low); a 1 s
    readout, the slowest accepted, prints its duration in seconds and its rate as 1 Hz."""
    capsys.readouterr()
    assert main(["inspect", str(dat)]) == 0
    assert "1.25 ms at 40,000 Hz" in capsys.readouterr().out
    write_sidecar(dat, {"height": 10, "width": 24, "flip": True})  # a record without the period: the flag gives it
    assert main(["inspect", str(dat), "--readout-period-s", "1"]) == 0
    out = capsys.readouterr().out
    assert "50 x 10 x 24 (flip=True), 50 s at 1 Hz" in out, out


def test_inspect_refuses_a_period_its_record_contradicts(dat, capsys):
    """--readout-period-s 5e-5 over a sidecar's 2.5e-5 printed half the rates silently (round nine)."""
    code, err = run_cli(["inspect", dat, "--readout-period-s", "5e-5"], capsys)
    assert code == 2 and "s.dat's record gives 2.5e-05 s" in one_line(err)
    assert run_cli(["inspect", dat, "--readout-period-s", "25e-6"], capsys)[0] == 0


@pytest.mark.parametrize("extra, words", [(["--start", 50], ["--start 50", "s.dat", "50 frames"]),
                                          (["--start", 999], ["--start 999"]),
                                          (["--start", 20, "--stop", 10], ["--stop 10", "--start 20"])])
def test_inspect_ranges_outside_the_stream_are_one_line(extra, words, dat, capsys):
    code, err = run_cli(["inspect", dat, *extra], capsys)
    line = one_line(err)
    assert code == 2 and all(w in line for w in words), line


def test_inspect_bad_files_are_one_line(tmp_path, capsys):
    (tmp_path / "d.dat").mkdir()
    (tmp_path / "empty.dat").write_bytes(b"")
    (tmp_path / "bad.dat").write_bytes(b"\0" * 24)
    (tmp_path / "bad.dat.json").write_text("{not json")
    (tmp_path / "list.dat").write_bytes(b"\0" * 30)
    (tmp_path / "list.dat.json").write_text("[1, 2]")
    for name, word in (("d.dat", "directory"), ("nope.dat", "does not exist"), ("empty.dat", "no frames"),
                       ("bad.dat", "not valid JSON"), ("list.dat", "not a JSON object")):
        code, err = run_cli(["inspect", tmp_path / name, "--height", 4, "--width", 6], capsys)
        line = one_line(err)
        assert code == 2 and name in line and word in line, line


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads any file")
def test_inspect_unreadable_file_is_one_line(dat, capsys):
    os.chmod(dat, 0)
    code, err = run_cli(["inspect", dat], capsys)
    assert code == 2 and "s.dat" in one_line(err)


def test_inspect_ambiguous_416_file_is_refused_unless_told(tmp_path, capsys):
    noise = np.random.default_rng(0).random((26, 250, 400)) < 0.2
    write_dat(tmp_path / "n.dat", SpikeStream.from_bool(noise))
    code, err = run_cli(["inspect", tmp_path / "n.dat"], capsys)
    line = one_line(err)
    assert code == 2 and "26 frames of 400x250" in line and "25 frames of 416x250" in line
    code, _ = run_cli(["inspect", tmp_path / "n.dat", "--header-columns", 0, "--json"], capsys)
    assert code == 0


def test_inspect_preview_and_header_columns_in_json(dat, tmp_path, capsys):
    capsys.readouterr()
    assert main(["inspect", str(dat), "--json", "--preview", str(tmp_path / "p.png"), "--start", "10"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["num_steps"] == 40 and info["header_columns"] == 0 and (tmp_path / "p.png").exists()


def test_a_dark_streams_preview_is_stretched_and_says_so(tmp_path, capsys):
    """`inspect --preview` of a low-light stream was near-black."""
    from PIL import Image

    from pipelines.cli import main
    from spikesim.stream import SpikeStream, write_dat
    path = tmp_path / "dark.dat"
    rng = np.random.default_rng(0)
    write_dat(path, SpikeStream.from_bool(rng.random((82, 16, 32)) < np.linspace(0, 0.02, 32)), flip=True)
    assert main(["inspect", str(path), "--height", "16", "--width", "32", "--preview", str(tmp_path / "p.png")]) == 0
    assert "stretched" in capsys.readouterr().out
    assert np.asarray(Image.open(tmp_path / "p.png")).max() > 200  # white is the brightest part, not y = 1
