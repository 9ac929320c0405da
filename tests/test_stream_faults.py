"""The `.dat` writer and reader under faults and foreign files: file modes follow the umask, a
failed write leaves nothing behind, 416-wide recordings follow the ecosystem's column convention,
and `header_columns="auto"` never guesses silently between two readings of one file size."""
import json
import os
import stat

import numpy as np
import pytest

from spikesim.stream import (DatReader, DatWriter, SpikeStream, detect_header_columns, read_dat,
                             write_dat, write_sidecar)


def pack_like_a_camera(frames: np.ndarray) -> bytes:
    """PKU `.dat` bytes packed by hand, independently of spikesim's packers: each frame's rows
    bottom-up, row-scanned, 8 pixels per byte with the first pixel in bit 0."""
    out = bytearray()
    weights = np.array([1, 2, 4, 8, 16, 32, 64, 128], dtype=np.uint16)
    for frame in frames:
        bits = np.asarray(frame[::-1], dtype=np.uint16).reshape(-1, 8)
        out += (bits * weights).sum(axis=1).astype(np.uint8).tobytes()
    return bytes(out)


def random_stream(n=5, h=6, w=16, seed=0):
    return SpikeStream.from_bool(np.random.default_rng(seed).random((n, h, w)) < 0.3)


# ---- file modes ---------------------------------------------------------------------------------
@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_dat_file_mode_follows_the_umask(tmp_path, mask, mode):
    old = os.umask(mask)
    try:
        write_dat(tmp_path / "s.dat", random_stream())
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "s.dat").stat().st_mode) == mode


# ---- failed writes leave nothing ----------------------------------------------------------------
def test_existing_directory_as_output_is_an_error_and_leaves_no_part_file(tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    with pytest.raises(IsADirectoryError, match="out"):
        write_dat(target, random_stream())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert list(target.iterdir()) == []


def test_zero_steps_is_an_error_and_leaves_nothing(tmp_path):
    with pytest.raises(ValueError, match="no frames"):
        with DatWriter(tmp_path / "e.dat", 6, 16):
            pass
    assert list(tmp_path.iterdir()) == []


def test_failed_rename_removes_the_part_file(tmp_path, monkeypatch):
    def refuse(src, dst):
        raise PermissionError(13, "Permission denied", str(dst))
    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(PermissionError):
        write_dat(tmp_path / "s.dat", random_stream())
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


def test_simulate_steps_zero_to_dat_leaves_no_dat_and_no_sidecar(tmp_path):
    from spikesim import SpikeCamera
    from spikesim.simulate import Simulator
    sim = Simulator(SpikeCamera(height=4, width=8), backend="numpy")
    with pytest.raises(ValueError):
        sim.run_to_dat(iter([]), tmp_path / "z.dat")
    assert list(tmp_path.iterdir()) == []


# ---- directories and unreadable files -----------------------------------------------------------
def test_directory_given_as_dat_is_a_clear_error(tmp_path):
    (tmp_path / "d.dat").mkdir()
    with pytest.raises(IsADirectoryError, match="d.dat"):
        DatReader(tmp_path / "d.dat", 6, 16)


# ---- 416-wide recordings ------------------------------------------------------------------------
def test_416_wide_recording_drops_the_last_16_columns(tmp_path):
    rng = np.random.default_rng(4)
    image = rng.random((3, 6, 400)) < 0.3
    header = np.ones((3, 6, 16), bool)  # something unmistakable where the 16 extra columns are
    (tmp_path / "rec.dat").write_bytes(pack_like_a_camera(np.concatenate([image, header], axis=2)))
    got = read_dat(tmp_path / "rec.dat", 6, 400, flip=True, header_columns=16)
    assert np.array_equal(got.unpack(), image)


def test_416_wide_with_widths_not_on_byte_boundaries(tmp_path):
    rng = np.random.default_rng(5)
    image = rng.random((2, 8, 13)) < 0.5
    stored = np.concatenate([image, np.ones((2, 8, 3), bool)], axis=2)  # 8 x 16: whole bytes
    (tmp_path / "odd.dat").write_bytes(pack_like_a_camera(stored))
    assert np.array_equal(read_dat(tmp_path / "odd.dat", 8, 13, header_columns=3).unpack(), image)


def _scene(n, h, w, seed=0):
    """A structured scene (bright blocks on a dark ramp) seen by an exact integrate-and-fire
    sensor: every pixel keeps its own rate, so the right reading of a file shows the structure."""
    yy, xx = np.mgrid[0:h, 0:w]
    y = 0.02 + 0.3 * (xx / w) + 0.5 * (((yy // 25) + (xx // 40)) % 2)
    acc = np.random.default_rng(seed).random((h, w))
    out = np.zeros((n, h, w), bool)
    for t in range(n):
        acc += y
        out[t] = acc >= 1
        acc[out[t]] -= 1
    return out


def test_auto_detects_a_416_wide_file_of_25_frames(tmp_path):
    # 25 frames of 416 x 250 are exactly 26 frames of 400 x 250: the size alone cannot tell.
    frames = np.concatenate([_scene(25, 250, 400), np.zeros((25, 250, 16), bool)], axis=2)
    (tmp_path / "rec.dat").write_bytes(pack_like_a_camera(frames))
    assert detect_header_columns(tmp_path / "rec.dat", 250, 400) == 16


def test_auto_detects_a_400_wide_file_of_26_frames(tmp_path):
    (tmp_path / "sim.dat").write_bytes(pack_like_a_camera(_scene(26, 250, 400)))
    assert detect_header_columns(tmp_path / "sim.dat", 250, 400) == 0


def test_auto_refuses_an_ambiguous_size_it_cannot_decide(tmp_path):
    noise = np.random.default_rng(1).random((26, 250, 400)) < 0.2  # no structure in either reading
    (tmp_path / "n.dat").write_bytes(pack_like_a_camera(noise))
    with pytest.raises(ValueError) as err:
        detect_header_columns(tmp_path / "n.dat", 250, 400)
    msg = str(err.value)
    assert "n.dat" in msg and "26 frames of 400x250" in msg and "25 frames of 416x250" in msg
    assert "--header-columns" in msg


def test_auto_trusts_the_sidecar(tmp_path):
    noise = np.random.default_rng(1).random((26, 250, 400)) < 0.2
    (tmp_path / "n.dat").write_bytes(pack_like_a_camera(noise))
    write_sidecar(tmp_path / "n.dat", {"height": 250, "width": 400, "flip": True})
    assert detect_header_columns(tmp_path / "n.dat", 250, 400) == 0


def test_auto_trusts_a_dataset_meta_json(tmp_path):
    scene = tmp_path / "fan_low"
    scene.mkdir()
    noise = np.random.default_rng(1).random((26, 250, 400)) < 0.2
    (scene / "spikes.dat").write_bytes(pack_like_a_camera(noise))
    (scene / "meta.json").write_text(json.dumps({"height": 250, "width": 400, "flip": True, "num_steps": 26}))
    assert detect_header_columns(scene / "spikes.dat", 250, 400) == 0


def test_auto_refuses_a_sidecar_of_another_geometry(tmp_path):
    write_dat(tmp_path / "s.dat", random_stream(n=4, h=6, w=16))
    write_sidecar(tmp_path / "s.dat", {"height": 6, "width": 16, "flip": True})
    with pytest.raises(ValueError, match=r"s.dat.json.*16x6"):
        detect_header_columns(tmp_path / "s.dat", 250, 400)


def test_auto_unambiguous_sizes(tmp_path):
    s = random_stream(n=3, h=6, w=16)  # 12 bytes a frame; 6 x 32 frames are 24 bytes
    write_dat(tmp_path / "a.dat", s)  # 36 bytes: whole 16-wide frames, not whole 32-wide ones
    assert detect_header_columns(tmp_path / "a.dat", 6, 16) == 0
    (tmp_path / "wide.dat").write_bytes(b"\0" * 13000)  # one 416 x 250 frame, not whole 400 x 250 ones
    assert detect_header_columns(tmp_path / "wide.dat", 250, 400) == 16
    (tmp_path / "b.dat").write_bytes(b"\0" * 7)
    with pytest.raises(ValueError, match="not a whole number"):
        detect_header_columns(tmp_path / "b.dat", 6, 16)


# ---- display ------------------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, word", [({"gamma": 0}, "gamma"), ({"gamma": -2}, "gamma"),
                                          ({"gamma": float("nan")}, "gamma"), ({"scale": -1}, "scale"),
                                          ({"percentile": 120}, "percentile")])
def test_display_refuses_impossible_settings(kwargs, word):
    from spikesim.imageio import to_display
    with pytest.raises(ValueError, match=word):
        to_display(np.full((2, 2), 0.5), **kwargs)


def test_failed_png_write_leaves_no_part_file(tmp_path, monkeypatch):
    from PIL import Image

    from spikesim.imageio import write_png

    def full_disk(self, fp, *a, **k):
        open(fp, "wb").write(b"\x89PNG")
        raise OSError(28, "No space left on device", str(fp))
    monkeypatch.setattr(Image.Image, "save", full_disk)
    with pytest.raises(OSError, match="No space"):
        write_png(tmp_path / "p.png", np.zeros((4, 4)))
    assert list(tmp_path.iterdir()) == []


def test_write_png_writes_only_under_a_png_name(tmp_path):
    """PNG bytes were written under x.jpg (round seven, low); x.PNG is a PNG name too."""
    from spikesim.imageio import write_png
    for name in ("x.jpg", "x", "x.png.tmp"):
        with pytest.raises(ValueError, match=r"write_png writes PNG data; name the file \*\.png"):
            write_png(tmp_path / name, np.zeros((4, 4)))
    assert list(tmp_path.iterdir()) == []
    assert write_png(tmp_path / "x.PNG", np.zeros((4, 4))).read_bytes()[:4] == b"\x89PNG"


def test_a_sidecar_recording_another_length_is_named(tmp_path):
    """A sidecar's num_steps of 5000 beside a 123-step file was read silently: a stale record."""
    from spikesim.stream import open_stream, write_dat, write_sidecar
    path = tmp_path / "s.dat"
    write_dat(path, SpikeStream.from_bool(np.zeros((123, 8, 16), bool)), flip=True)
    write_sidecar(path, {"height": 8, "width": 16, "flip": True, "num_steps": 5000})
    with pytest.raises(ValueError, match=r"s.dat.json records 5000 steps, .*holds 123"):
        open_stream(path)
    reader, _ = open_stream(path, height=8, width=16)  # the record set aside: read as told
    assert reader.num_steps == 123
    side = json.loads((tmp_path / "s.dat.json").read_text())
    write_sidecar(path, {**side, "num_steps": 123})
    assert open_stream(path)[0].num_steps == 123
