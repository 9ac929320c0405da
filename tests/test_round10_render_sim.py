"""Round ten, render and simulate: step ranges and counts beyond what the code can hold are
refused by the parser, a stream that cannot fit on the disk is refused before it is simulated,
flags another source ignored are refused, a render folder of another size or without a digest of
every frame is refused saying what to do, and SIGTERM to render leaves no stage behind."""
from __future__ import annotations

import argparse
import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from cli_testing import one_line, run_cli

SCENE = "tests/data/plain_scene/scene.xml"


def _parser_error(err):
    assert "Traceback" not in err and err.splitlines()[0].startswith("usage:"), err
    return err.strip().splitlines()[-1]


def test_a_step_range_too_long_to_count_is_a_parser_error(tmp_path, capsys):
    """5:10**21:3 overflowed len(range) in a C ssize_t: rc 1 and a traceback (round ten)."""
    from pipelines.render_cmd import parse_steps
    with pytest.raises(argparse.ArgumentTypeError, match="selects 333,333,333,333,333,333,332 steps; at most 1,000,000"):
        parse_steps("5:1000000000000000000000:3")
    assert parse_steps("10:0:-3") == [10, 7, 4, 1]
    code, err = run_cli(["render", SCENE, "--steps", "5:1000000000000000000000:3", "-o", tmp_path / "rb"], capsys)
    assert code == 2 and "argument --steps:" in _parser_error(err) and "at most 1,000,000" in err
    assert not (tmp_path / "rb").exists()


@pytest.mark.parametrize("flag, value", [("--keyframe-every", "5000000000"), ("--steps", "100000000000000000000000"),
                                         ("--steps", "2147483648")])
def test_steps_beyond_the_sensors_32_bit_counter_are_parser_errors(tmp_path, capsys, flag, value):
    """--keyframe-every 5e9 crashed the llvm backend inside Dr.Jit; --steps 1e23 ran until the disk
    was full (round ten)."""
    np.save(tmp_path / "f.npy", np.full((3, 16, 24), 0.1, np.float32))
    code, err = run_cli(["simulate", "--frames", tmp_path / "f.npy", flag, value, "-o", tmp_path / "k.dat"], capsys)
    line = _parser_error(err)
    assert code == 2 and f"argument {flag}: at most 2,147,483,647 (2**31 - 1" in line, line
    assert not list(tmp_path.glob("k.dat*"))


def test_a_stream_larger_than_the_free_disk_is_refused_before_it_is_simulated(tmp_path, capsys, monkeypatch):
    import shutil
    from collections import namedtuple
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10 ** 6, 10 ** 6 - 1000, 1000))
    code, err = run_cli(["simulate", "--steps", "1000", "--height", "16", "--width", "24", "--backend", "numpy",
                         "--quiet", "-o", tmp_path / "big.dat"], capsys)
    line = one_line(err)
    assert code == 2 and "--out" in line and "1,000 steps of 16 x 24 make" in line and "free" in line, line
    assert not list(tmp_path.glob("big.dat*"))
    monkeypatch.undo()
    assert run_cli(["simulate", "--steps", "1000", "--height", "16", "--width", "24", "--backend", "numpy",
                    "--quiet", "-o", tmp_path / "big.dat"], capsys)[0] == 0


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from pipelines.cli import main
    out = tmp_path_factory.mktemp("r") / "rf"
    assert main(["render", SCENE, "--steps", "0:2", "--spp", "1", "--height", "16", "--width", "24", "-o", str(out),
                 "--quiet"]) == 0
    return out


def _simulate(frames, out, *args):
    return ["simulate", "--frames", frames, "--backend", "numpy", "--quiet", *args, "-o", out]


@pytest.mark.parametrize("flags, says", [(["--light", "low"], "--light low: the render fixed the light"),
                                         (["--peak-y", "0.9"], "--peak-y 0.9 sets the built-in pattern's")])
def test_light_flags_a_render_folder_ignored_are_refused(rendered, tmp_path, capsys, flags, says):
    """--light low and --peak-y 0.9 were ignored with --frames RENDERFOLDER, rc 0 (round ten)."""
    code, err = run_cli(_simulate(rendered, tmp_path / "s.dat", *flags), capsys)
    assert code == 2 and says in one_line(err) and not (tmp_path / "s.dat").exists()
    np.save(tmp_path / "f.npy", np.full((3, 16, 24), 0.1, np.float32))
    code, err = run_cli(_simulate(tmp_path / "f.npy", tmp_path / "s.dat", *flags), capsys)
    assert code == 2 and flags[0] in one_line(err)


def test_a_render_folder_of_another_size_says_its_size_and_what_to_do(rendered, tmp_path, capsys):
    """The error advised SpikeCamera.realistic(height=..., width=...), a Python call (round ten)."""
    code, err = run_cli(_simulate(rendered, tmp_path / "s.dat", "--height", "32", "--width", "48"), capsys)
    line = one_line(err)
    assert code == 2 and "frames (step_000000.exr and on) are 16 x 24" in line and "drop --height/--width" in line, line
    assert "SpikeCamera" not in line


@pytest.mark.parametrize("damage", ["empty", "absent", "one"])
def test_a_render_record_without_every_frames_digest_is_refused(rendered, tmp_path, capsys, damage):
    """Swapped EXRs were simulated, rc 0, when render.json held "sha256": {} or none (round ten)."""
    import shutil
    folder = tmp_path / "rf"
    shutil.copytree(rendered, folder)
    record = json.loads((folder / "render.json").read_text())
    if damage == "empty":
        record["sha256"] = {}
    elif damage == "absent":
        del record["sha256"]
    else:
        del record["sha256"]["frames/step_000001.exr"]
    (folder / "render.json").write_text(json.dumps(record))
    a, b = folder / "frames" / "step_000000.exr", folder / "frames" / "step_000001.exr"
    a_bytes = a.read_bytes()
    a.write_bytes(b.read_bytes())
    b.write_bytes(a_bytes)
    code, err = run_cli(_simulate(folder, tmp_path / "s.dat"), capsys)
    line = one_line(err)
    assert code == 2 and f"{folder / 'render.json'}: records no sha256 of frames/step_00000" in line, line
    assert "render again" in line and not (tmp_path / "s.dat").exists()


def test_sigterm_to_render_leaves_no_stage_and_a_rerun_removes_a_killed_runs(tmp_path, capsys, monkeypatch):
    """SIGTERM left .render.XXXX.part/ (60 files) and no later run removed it (round ten)."""
    from spikesim.render import SceneRenderer
    out = tmp_path / "rk"
    (out / ".render.dead.part" / "frames").mkdir(parents=True)
    (out / ".render.dead.part" / "frames" / "step_000000.exr").write_bytes(b"killed")
    base = ["render", SCENE, "--spp", "1", "--height", "8", "--width", "12", "--quiet", "-o", out]
    assert run_cli([*base, "--steps", "0"], capsys)[0] == 0
    assert not list(out.glob(".render.*.part"))
    real = SceneRenderer.render_step

    def killed(self, step, *a, **k):
        if step == 1:
            os.kill(os.getpid(), signal.SIGTERM)
        return real(self, step, *a, **k)
    monkeypatch.setattr(SceneRenderer, "render_step", killed)
    ignored = []  # without a handler of the command's, SIGTERM is noted here, not fatal to pytest
    previous = signal.signal(signal.SIGTERM, lambda *a: ignored.append(a))
    try:
        code, err = run_cli([*base, "--steps", "0:3", "-o", tmp_path / "r2"], capsys)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert code == 143 and "terminated (SIGTERM)" in err and not ignored, err  # as Ctrl-C, said as SIGTERM (round fourteen)
    assert not Path(tmp_path / "r2").exists() or not os.listdir(tmp_path / "r2")
