"""The PKU .dat format, byte for byte, and the reader on data the project did not write."""
import numpy as np
import pytest
from PIL import Image

from spikesim.stream import DatReader, SpikeStream, read_dat, read_sidecar, write_dat, write_sidecar


def random_stream(n=5, h=6, w=16, seed=0):
    return SpikeStream.from_bool(np.random.default_rng(seed).random((n, h, w)) < 0.3)


def test_bit_layout_by_hand(tmp_path):
    # One spike at the top-left pixel (row 0, col 0) and one at row 0, col 9 of a 2x16 frame.
    frames = np.zeros((1, 2, 16), bool)
    frames[0, 0, 0] = True
    frames[0, 0, 9] = True
    s = SpikeStream.from_bool(frames)
    write_dat(tmp_path / "a.dat", s, flip=False)
    assert (tmp_path / "a.dat").read_bytes() == bytes([0b00000001, 0b00000010, 0, 0])
    # flipped: row 0 is stored last
    write_dat(tmp_path / "b.dat", s, flip=True)
    assert (tmp_path / "b.dat").read_bytes() == bytes([0, 0, 0b00000001, 0b00000010])


@pytest.mark.parametrize("flip", [True, False])
@pytest.mark.parametrize("w", [16, 13])  # 13: rows do not end on byte boundaries
def test_round_trip(tmp_path, flip, w):
    s = random_stream(w=w)
    write_dat(tmp_path / "s.dat", s, flip=flip)
    assert (tmp_path / "s.dat").stat().st_size == 5 * ((6 * w + 7) // 8)
    assert read_dat(tmp_path / "s.dat", 6, w, flip=flip) == s
    assert np.array_equal(read_dat(tmp_path / "s.dat", 6, w, flip=not flip).unpack(), s.unpack()[:, ::-1, :])
    assert read_dat(tmp_path / "s.dat", 6, w, start=2, stop=4, flip=flip) == s.slice(2, 4)


def test_truncated_file_is_an_error_unless_asked(tmp_path):
    s = random_stream()
    write_dat(tmp_path / "s.dat", s)
    data = (tmp_path / "s.dat").read_bytes()
    (tmp_path / "t.dat").write_bytes(data[:-3])
    with pytest.raises(ValueError, match=r"t.dat.*not a whole number.*drop_partial"):
        read_dat(tmp_path / "t.dat", 6, 16)
    r = DatReader(tmp_path / "t.dat", 6, 16, drop_partial=True)
    assert len(r) == 4 and r.read() == s.slice(0, 4)
    with pytest.raises(FileNotFoundError, match="nope.dat"):
        read_dat(tmp_path / "nope.dat")
    with pytest.raises(IndexError, match="outside"):
        r.read(2, 9)


def test_header_columns_are_dropped(tmp_path):
    # stored after the image columns of each row, as SpikeCV and Spike-Zoo read them
    s = random_stream(h=4, w=32)
    header = np.ones((5, 4, 16), bool)
    write_dat(tmp_path / "h.dat", SpikeStream.from_bool(np.concatenate([s.unpack(), header], axis=2)))
    assert read_dat(tmp_path / "h.dat", 4, 32, header_columns=16) == s


def test_writer_is_atomic(tmp_path):
    from spikesim.stream import DatWriter
    s = random_stream()
    with pytest.raises(RuntimeError):
        with DatWriter(tmp_path / "x.dat", 6, 16) as w:
            w.write(s)
            raise RuntimeError("interrupted")
    assert not (tmp_path / "x.dat").exists()
    assert list(tmp_path.iterdir()) == []


def test_sidecar_round_trip(tmp_path):
    write_sidecar(tmp_path / "s.dat", {"seed": 3, "camera": {"width": 400}})
    assert read_sidecar(tmp_path / "s.dat") == {"seed": 3, "camera": {"width": 400}}
    assert read_sidecar(tmp_path / "other.dat") is None


def test_reads_the_spk2imgnet_sample(shared_data):
    # A stream written by another simulator (Spk2ImgNet's, via Spike-Zoo/WGSE): 301 frames of
    # 250 x 400, rows flipped; its firing rate / 0.6 is the ground-truth intensity (README).
    d = shared_data / "spk2imgnet-sample"
    r = DatReader(d / "203_part1_key_id151.dat", 250, 400, flip=True)
    assert len(r) == 301
    tfp = r.read(131, 172).unpack().mean(axis=0) / 0.6
    gt = np.asarray(Image.open(d / "203_part1_key_id151.png").convert("L"), dtype=np.float64) / 255.0
    assert gt.shape == tfp.shape == (250, 400)
    mse = np.mean((np.clip(tfp, 0, 1) - gt) ** 2)
    psnr = 10 * np.log10(1.0 / mse)
    assert psnr > 22.0  # about 23.5 dB measured independently (README)
    corr = np.corrcoef(tfp.ravel(), gt.ravel())[0, 1]
    unflipped = DatReader(d / "203_part1_key_id151.dat", 250, 400, flip=False).read(131, 172).unpack().mean(axis=0)
    assert corr > 0.8 and abs(np.corrcoef(unflipped.ravel(), gt.ravel())[0, 1]) < 0.3


def test_a_reader_without_geometry_reads_what_is_recorded_beside_the_stream(tmp_path):
    """DatReader(path) takes height, width and row order from the stream's sidecar (it assumed
    250 x 400 bottom-up, and advised drop_partial, which returned garbage)."""
    import dataclasses

    from spikesim import SpikeCamera
    from spikesim.simulate import Simulator

    y = np.linspace(0.05, 0.9, 30 * 40, dtype=np.float32).reshape(30, 40)
    cam = dataclasses.replace(SpikeCamera.noiseless(), height=30, width=40)
    dat = Simulator(cam, backend="numpy", seed=0).run_to_dat([y] * 20, tmp_path / "s.dat", flip=False)
    reader = DatReader(dat)
    assert (reader.height, reader.width, reader.flip, reader.num_steps) == (30, 40, False, 20)
    counts = reader.read().unpack().sum(0)
    assert counts[:, 0].mean() < counts[:, -1].mean()  # bright on the right, top-down as written
    plain = tmp_path / "plain.dat"
    plain.write_bytes(dat.read_bytes())  # no sidecar: 250 x 400 is assumed, and the error says what to do
    with pytest.raises(ValueError, match="geometry is likely wrong: give height, width and header_columns"):
        DatReader(plain)


def test_run_to_dat_keeps_its_own_record_and_never_a_stale_one(tmp_path):
    """extra={'height': 12, 'width': 8} overwrote the geometry (readers returned transposed
    frames); extra={'flip': 1} failed after the new .dat had replaced the old one, beside the old
    sidecar (round six). Both are refused before anything is written."""
    import json

    from spikesim.camera import SpikeCamera
    from spikesim.simulate import Simulator
    from spikesim.stream import sidecar_path
    sim = Simulator(SpikeCamera.realistic(height=8, width=12), backend="numpy", seed=0)
    frames = [np.full((8, 12), 0.2, np.float32)] * 5
    dat = sim.run_to_dat(frames, tmp_path / "ok.dat", flip=False, extra={"note": "kept"})
    before = (dat.read_bytes(), sidecar_path(dat).read_text())
    for bad in ({"height": 12, "width": 8}, {"flip": True}, {"keyframe_every": 1}):
        with pytest.raises(ValueError, match="the stream's own record"):
            sim.run_to_dat(frames, dat, flip=False, extra=bad)
    assert (dat.read_bytes(), sidecar_path(dat).read_text()) == before
    assert json.loads(sidecar_path(dat).read_text())["note"] == "kept"
    # a NaN was written into the sidecar as the token NaN, which strict JSON readers refuse (round seven):
    # it is null there now, and "non_finite" says what it was
    sim.run_to_dat(frames, dat, flip=False, extra={"a": float("nan"), "b": [1.0, float("inf")]})
    record = json.loads(sidecar_path(dat).read_text(), parse_constant=lambda c: pytest.fail(f"non-standard {c}"))
    assert record["a"] is None and record["b"] == [1.0, None]
    assert record["non_finite"] == {"a": "nan", "b[1]": "inf"}
    from spikesim.stream import read_sidecar
    assert read_sidecar(dat)["a"] is None


def test_a_stream_written_over_another_drops_the_old_ones_record(tmp_path):
    """write_dat over a 16 x 24 stream left its sidecar: the new 12 x 32 stream (same bytes per
    frame) was read as 16 x 24 (round seven). flip must be a bool, sizes positive integers."""
    from spikesim.stream import DatReader, DatWriter, open_stream, sidecar_path, write_dat, write_sidecar
    path = write_dat(tmp_path / "x.dat", SpikeStream.from_bool(np.zeros((5, 16, 24), bool)), flip=False)
    write_sidecar(path, {"height": 16, "width": 24, "flip": False})
    write_dat(path, SpikeStream.from_bool(np.ones((5, 12, 32), bool)), flip=False)
    assert not sidecar_path(path).exists()
    with pytest.raises(ValueError):
        open_stream(path, None, None, None, "auto", False)  # no record: asks for the size, never the old one
    for bad in ({"flip": "false"}, {"height": 0}, {"height": "12"}):
        with pytest.raises(ValueError, match="must be"):
            DatWriter(tmp_path / "y.dat", **{"height": 4, "width": 8, "flip": False, **bad})
    for bad in ({"flip": "no"}, {"height": 0}, {"height": 12.0}):
        with pytest.raises(ValueError, match="must be"):
            DatReader(path, **{"width": 32, **bad})


def test_no_frames_make_an_empty_stream_and_a_batch_names_its_stream_count():
    """Simulator.run(frames[:0]) raised NumPy's reshape error; BatchSimulator with 3 seeds given 2
    streams' frames blamed the camera's size (round eight)."""
    from spikesim.camera import SpikeCamera
    from spikesim.simulate import BatchSimulator, Simulator
    cam = SpikeCamera.realistic(height=8, width=8)
    for backend in ("numpy", "llvm"):
        try:
            sim = Simulator(cam, seed=0, backend=backend)
        except Exception:  # noqa: BLE001 - a machine without the LLVM backend checks NumPy alone
            continue
        assert sim.run(np.zeros((0, 8, 8), np.float32)).num_steps == 0
    with pytest.raises(ValueError, match=r"2 streams' frames of 8 x 8, but this simulator makes 3 streams"):
        BatchSimulator(cam, seeds=[0, 1, 2], backend="numpy").run(np.full((41, 2, 8, 8), 0.05, np.float32))


def test_an_empty_read_unpacks_to_no_frames(tmp_path):
    """DatReader.read(0, 0).unpack() raised NumPy's reshape error (round nine)."""
    from spikesim.stream import DatReader, write_dat
    path = write_dat(tmp_path / "s.dat", SpikeStream.from_bool(np.zeros((3, 4, 8), bool)), flip=False)
    assert DatReader(path, 4, 8, flip=False).read(0, 0).unpack().shape == (0, 4, 8)
