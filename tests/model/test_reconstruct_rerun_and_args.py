"""reconstruct / evaluate / train on bad arguments (one line naming the flag, exit status 2) and
reconstruct rerun into the same folder (its outputs describe exactly the last run)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from modeltest_fakes import make_scene
from pipelines import reconstruct as rc
from cli_testing import run_cli, one_line


@pytest.fixture
def dat(tmp_path):
    from spikesim.stream import SpikeStream, write_dat
    sc = make_scene("r", 12, 16, 7 * 5, brightness=0.3)
    return write_dat(tmp_path / "s.dat", SpikeStream.from_bool(sc.spike_array))






def parser_error(err):
    """argparse's refusal: a usage line, then one error line naming the flag."""
    assert "Traceback" not in err and err.splitlines()[0].startswith("usage:"), err
    return err.strip().splitlines()[-1]


def tree(root):
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*"))


def test_rerun_replaces_its_own_outputs_and_keeps_the_users(dat, tmp_path, capsys):
    out = tmp_path / "out"
    base = ["reconstruct", dat, "--height", 12, "--width", 16, "--window", 7, "--out", out, "--no-mp4", "--quiet"]
    assert run_cli(base + ["--save-npy"], capsys)[0] == 0
    assert len(list((out / "png").glob("step_*.png"))) == 5 and (out / "frames.npy").exists()
    (out / "notes.txt").write_text("mine")
    (out / "png" / "README").write_text("mine too")
    assert run_cli(base + ["--num-windows", 2, "--no-gif"], capsys)[0] == 0
    assert tree(out) == ["notes.txt", "png", "png/README", "png/step_000003.png", "png/step_000010.png",
                         "reconstruct.json"]
    summary = json.loads((out / "reconstruct.json").read_text())
    assert summary["frames"] == 2 and summary["outputs"] == ["png", "reconstruct.json"]


def test_a_failed_rerun_keeps_the_previous_outputs(dat, tmp_path, monkeypatch):
    out = tmp_path / "out"
    rc.reconstruct_file(dat, out, "tfp", 12, 16, window=7, save_npy=True, mp4=False, progress=False)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    calls = []

    def fail_on_third(*a, **k):
        calls.append(1)
        if len(calls) == 3:
            raise OSError(28, "No space left on device", str(out / "png"))
        return np.zeros((12, 16), np.uint8)
    monkeypatch.setattr(rc, "display_frame", fail_on_third)
    with pytest.raises(OSError, match="No space"):
        rc.reconstruct_file(dat, out, "tfp", 12, 16, window=7, num_windows=4, mp4=False, progress=False)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_geometry_comes_from_the_sidecar(dat, tmp_path):
    from spikesim.stream import write_sidecar
    write_sidecar(dat, {"height": 12, "width": 16, "flip": False})
    s = rc.reconstruct_file(dat, tmp_path / "o", "tfp", window=7, gif=False, mp4=False, progress=False)
    assert (s["height"], s["width"], s["flip"], s["header_columns"]) == (12, 16, False, 0)


@pytest.mark.parametrize("flag, value", [
    ("--fps", 0), ("--gamma", 0), ("--gamma", -1), ("--window", 0), ("--window", 40), ("--start", -1), ("--percentile", 101),
    ("--percentile", 0), ("--height", 0), ("--width", -4), ("--header-columns", -1),
    ("--header-columns", "x"), ("--scale", 0), ("--chunk", 0), ("--num-windows", 0), ("--threads", -1),
    ("--fps", "nan"), ("--fps", "0.001"), ("--fps", "1e6"), ("--threads", 99999)])
def test_reconstruct_refuses_bad_values(flag, value, dat, tmp_path, capsys):
    code, err = run_cli(["reconstruct", dat, "--out", tmp_path / "o", flag, value], capsys)
    assert code == 2 and f"argument {flag}" in parser_error(err)
    assert not (tmp_path / "o").exists()


def test_reconstruct_bad_inputs_are_one_line(dat, tmp_path, capsys):
    (tmp_path / "d.dat").mkdir()
    code, err = run_cli(["reconstruct", tmp_path / "d.dat", "--out", tmp_path / "o"], capsys)
    assert code == 2 and "d.dat" in one_line(err) and "directory" in err
    code, err = run_cli(["reconstruct", tmp_path / "nope.dat", "--out", tmp_path / "o"], capsys)
    assert code == 2 and "nope.dat" in one_line(err)
    code, err = run_cli(["reconstruct", dat, "--height", 12, "--width", 16, "--window", 7, "--start", 99,
                         "--out", tmp_path / "o"], capsys)
    assert code == 2 and "--start 99" in one_line(err)
    (tmp_path / "empty.dat").write_bytes(b"")
    code, err = run_cli(["reconstruct", tmp_path / "empty.dat", "--out", tmp_path / "o"], capsys)
    assert code == 2 and "empty.dat" in one_line(err)
    (tmp_path / "file").write_text("x")
    code, err = run_cli(["reconstruct", dat, "--height", 12, "--width", 16, "--window", 7,
                         "--out", tmp_path / "file"], capsys)
    assert code == 2 and "file" in one_line(err)


def test_reconstruct_refuses_an_ambiguous_416_file(tmp_path, capsys):
    noise = np.random.default_rng(0).random((26, 250, 400)) < 0.2
    from spikesim.stream import SpikeStream, write_dat
    write_dat(tmp_path / "n.dat", SpikeStream.from_bool(noise))
    code, err = run_cli(["reconstruct", tmp_path / "n.dat", "--out", tmp_path / "o"], capsys)
    line = one_line(err)
    assert code == 2 and "26 frames of 400x250" in line and "25 frames of 416x250" in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("flag, value", [("--window", 0), ("--chunk", 0), ("--threads", -2)])
def test_evaluate_refuses_bad_values(flag, value, tmp_path, capsys):
    code, err = run_cli(["evaluate", "--data", tmp_path, "--out", tmp_path / "o", flag, value], capsys)
    assert code == 2 and f"argument {flag}" in parser_error(err)


def test_evaluate_unknown_scene_is_one_line(tmp_path, capsys):
    pytest.importorskip("OpenEXR", reason="the dataset layout stores ground truth as EXR")
    from spikesim.dataset import write_scene
    from spikesim.stream import SpikeStream
    sc = make_scene("only", 12, 16, 7 * 3, brightness=0.3)
    write_scene(tmp_path / "data", sc.name, SpikeStream.from_bool(sc.spike_array), {3: sc.gt[3]}, meta={})
    code, err = run_cli(["evaluate", "--data", tmp_path / "data", "--scenes", "nope", "--window", 7,
                         "--out", tmp_path / "o", "--device", "cpu"], capsys)
    assert code == 2 and "--scenes" in one_line(err) and "nope" in err


@pytest.mark.parametrize("flag, value", [("--epochs", 0), ("--max-steps", 0), ("--batch-size", 0), ("--lr", 0),
                                         ("--num-workers", -1), ("--crop", 0), ("--seed", -1),
                                         ("--threads", -1), ("--samples-per-epoch", 0)])
def test_train_refuses_bad_values(flag, value, tmp_path, capsys):
    code, err = run_cli(["train", "--data", tmp_path, "--config", "tiny", "--out", tmp_path / "o", flag, value],
                        capsys)
    assert code == 2 and f"argument {flag}" in parser_error(err)


def test_a_second_reconstruct_into_a_folder_in_use_is_refused(tmp_path):
    """Two reconstruct runs into one -o left one run's PNGs and GIF under the other's reconstruct.json."""
    import numpy as np

    from pipelines.reconstruct import reconstruct_file
    from spikesim.generation.lock import OutputLockedError, output_lock
    from spikesim.stream import SpikeStream, write_dat
    dat = tmp_path / "s.dat"
    write_dat(dat, SpikeStream.from_bool(np.random.default_rng(0).random((82, 12, 16)) < 0.2), flip=False)
    out = tmp_path / "rec"
    out.mkdir()
    with output_lock(out, "reconstruct other (pid 4242)", what="reconstruct run"):
        with pytest.raises(OutputLockedError, match="another reconstruct run.*4242"):
            reconstruct_file(dat, out, "tfp", 12, 16, 0, False, gif=False, mp4=False, progress=False)
    summary = reconstruct_file(dat, out, "tfp", 12, 16, 0, False, gif=False, mp4=False, progress=False)
    assert summary["frames"] == 2 and not (out / ".spikesim.lock").exists()


def test_reconstruct_never_replaces_a_file_no_earlier_run_wrote(tmp_path):
    """The README's simulate --frames frames.npy, then reconstruct -o . deleted the user's frames.npy;
    a png/step_000999.png of theirs was removed (round seven). A rerun still replaces its own."""
    import numpy as np

    from pipelines.reconstruct import reconstruct_file
    from spikesim.stream import SpikeStream, write_dat
    dat = tmp_path / "s.dat"
    write_dat(dat, SpikeStream.from_bool(np.random.default_rng(0).random((82, 12, 16)) < 0.2), flip=False)
    out = tmp_path / "here"
    out.mkdir()
    np.save(out / "frames.npy", np.zeros((2, 12, 16), np.float32))
    mine = (out / "frames.npy").read_bytes()
    with pytest.raises(FileExistsError, match="frames.npy, which no reconstruct.json"):
        reconstruct_file(dat, out, "tfp", 12, 16, 0, False, gif=False, mp4=False, progress=False)
    assert (out / "frames.npy").read_bytes() == mine
    (out / "frames.npy").unlink()
    (out / "png").mkdir()
    (out / "png" / "step_000999.png").write_bytes(b"mine")
    with pytest.raises(FileExistsError, match="png/step_000999.png"):
        reconstruct_file(dat, out, "tfp", 12, 16, 0, False, gif=False, mp4=False, progress=False)
    (out / "png" / "step_000999.png").unlink()
    reconstruct_file(dat, out, "tfp", 12, 16, 0, False, gif=False, mp4=False, save_npy=True, progress=False)
    summary = reconstruct_file(dat, out, "tfp", 12, 16, 0, False, gif=False, mp4=False, progress=False)  # its own
    assert summary["frames"] == 2 and not (out / "frames.npy").exists()


def test_a_run_that_makes_other_than_asked_says_so(tmp_path, capsys):
    """--num-windows 9 where 5 fit made 5 frames silently; an odd-sided frame's MP4 was padded
    silently (round seven, low). Both are said on stderr and kept in reconstruct.json."""
    pytest.importorskip("imageio_ffmpeg")
    from spikesim.stream import SpikeStream, write_dat
    sc = make_scene("r", 11, 16, 7 * 5, brightness=0.3)
    dat = write_dat(tmp_path / "s.dat", SpikeStream.from_bool(sc.spike_array))
    out = tmp_path / "out"
    code, err = run_cli(["reconstruct", dat, "--height", 11, "--width", 16, "--window", 7, "--num-windows", 9,
                         "--out", out, "--quiet", "--no-gif"], capsys)
    assert code == 0 and "Traceback" not in err
    assert "note: --num-windows 9: only 5 full 7-step window(s) fit in 35 steps after --start 0; made 5" in err
    assert "note: frames.mp4 is 12 x 16: video needs even sides" in err
    record = json.loads((out / "reconstruct.json").read_text())
    assert record["frames"] == 5 and len(record["notes"]) == 2
    code, err = run_cli(["reconstruct", dat, "--height", 11, "--width", 16, "--window", 7, "--num-windows", 2,
                         "--out", tmp_path / "o2", "--quiet", "--no-mp4"], capsys)
    assert code == 0 and "note:" not in err
    assert json.loads((tmp_path / "o2" / "reconstruct.json").read_text())["notes"] == []


def test_a_recording_cut_off_mid_frame_is_read_where_the_message_says_it_can_be(dat, tmp_path, capsys):
    """The partial-frame error advised --drop-partial to reconstruct and panel, which refused the
    flag (round eight); both take it now and make the whole frames' output."""
    cut = tmp_path / "cut.dat"
    cut.write_bytes(dat.read_bytes() + b"\0" * 5)
    base = ["reconstruct", cut, "--height", 12, "--width", 16, "--window", 7, "--no-mp4", "--no-gif", "--quiet"]
    code, err = run_cli([*base, "--out", tmp_path / "a"], capsys)
    assert code == 2 and "inspect, reconstruct and panel" in err and "--drop-partial" in err
    code, err = run_cli([*base, "--out", tmp_path / "b", "--drop-partial", "--header-columns", 0], capsys)
    assert code == 0, err
    assert json.loads((tmp_path / "b" / "reconstruct.json").read_text())["frames"] == 5
    from spikesim.stream import SpikeStream, write_dat
    big = write_dat(tmp_path / "big.dat", SpikeStream.from_bool(make_scene("q", 16, 16, 7 * 3, brightness=0.3).spike_array))
    big.write_bytes(big.read_bytes() + b"\0" * 5)
    code, err = run_cli(["panel", big, "--height", 16, "--width", 16, "--window", 7, "--methods", "tfp", "--quiet",
                         "--drop-partial", "--header-columns", 0, "-o", tmp_path / "p.png"], capsys)
    assert code == 0 and (tmp_path / "p.png").is_file(), err


def test_a_users_frame_named_png_beside_a_runs_frames_is_kept(dat, tmp_path, capsys):
    """Once reconstruct.json listed "png", every png/step_*.png was taken for the run's: a rerun
    deleted the user's step_009999.png (round nine). The record lists the frames by name."""
    out = tmp_path / "out"
    base = ["reconstruct", dat, "--height", 12, "--width", 16, "--window", 7, "--out", out, "--no-mp4", "--quiet"]
    assert run_cli(base, capsys)[0] == 0
    record = json.loads((out / "reconstruct.json").read_text())
    assert record["png_frames"] == [p.name for p in sorted((out / "png").glob("step_*.png"))]
    (out / "png" / "step_009999.png").write_bytes(b"the user's")
    code, err = run_cli(base, capsys)
    assert code == 2 and "png/step_009999.png, which no reconstruct.json there says" in err
    assert (out / "png" / "step_009999.png").read_bytes() == b"the user's"
    (out / "png" / "step_009999.png").unlink()
    assert run_cli(base + ["--num-windows", 2], capsys)[0] == 0  # its own frames: the stale three removed
    assert len(list((out / "png").glob("step_*.png"))) == 2


def test_sigterm_and_a_killed_runs_stage_leave_nothing_behind(dat, tmp_path, capsys):
    """SIGTERM left .reconstruct.XXXX.part/ and the lock, and no later run cleaned the stage up
    (round nine): SIGTERM now stops a run as Ctrl-C does, and a run removes a dead run's stage."""
    import os
    import signal

    out = tmp_path / "out"
    (out / ".reconstruct.dead.part" / "png").mkdir(parents=True)
    base = ["reconstruct", dat, "--height", 12, "--width", 16, "--window", 7, "--out", out, "--no-mp4", "--quiet"]
    assert run_cli(base, capsys)[0] == 0
    assert not list(out.glob(".reconstruct.*.part"))

    def stop(*a, **k):  # the signal arrives while the frames are made
        os.kill(os.getpid(), signal.SIGTERM)
    import pipelines.reconstruct as rc_module
    real = rc_module._render_frames
    try:
        rc_module._render_frames = lambda *a, **k: (stop(), real(*a, **k))
        with pytest.raises(KeyboardInterrupt):
            rc.reconstruct_file(dat, tmp_path / "o2", "tfp", 12, 16, 0, window=7, mp4=False, progress=False)
    finally:
        rc_module._render_frames = real
    assert not list((tmp_path / "o2").glob(".reconstruct.*.part")) and not (tmp_path / "o2" / ".spikesim.lock").exists()
