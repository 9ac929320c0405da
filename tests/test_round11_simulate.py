"""Round eleven, simulate: a render folder's frames are read in step order past step 999,999 and a
folder of one's own EXRs in natural name order; SIGTERM leaves no partial stream; an integer .npy
is refused; the step count the frames give is bounded as --steps is; --light messages say what
applies."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cli_testing import one_line, run_cli
from spikesim.stream import DatReader

H, W = 4, 6
SIM = ["--camera", "noiseless", "--backend", "numpy", "--quiet"]


def _render_folder(folder: Path, values: dict[int, float], light: str = "normal") -> Path:
    """A render -o folder written directly (no rendering): frames/step_NNNNNN.exr of constant y per
    step, and a render.json listing them with their sha256, as render writes it."""
    from spikesim.dataset import sha256_file
    from spikesim.imageio import write_exr
    (folder / "frames").mkdir(parents=True)
    files = []
    for step, y in values.items():
        rel = f"frames/step_{step:06d}.exr"
        write_exr(folder / rel, np.full((H, W), y, np.float32))
        files.append(rel)
    record = {"kind": "frames", "steps": sorted(values), "light": {"name": light}, "files": sorted(files),
              "sha256": {f: sha256_file(folder / f) for f in files}}
    (folder / "render.json").write_text(json.dumps(record))
    return folder


def _spikes_per_step(dat: Path) -> np.ndarray:
    stream = DatReader(dat, H, W).read()
    return stream.unpack().reshape(len(stream), -1).sum(axis=1)


def test_a_render_folder_past_step_999999_is_read_in_step_order(tmp_path, capsys):
    """step_1000000.exr sorted (as text) before step_999997.exr: the stream was silently reordered,
    rc 0 (round eleven)."""
    from pipelines.render_folder import listed_frames
    steps = list(range(999997, 1000003))
    folder = _render_folder(tmp_path / "r3", {s: (0.0 if s < 1000000 else 0.9) for s in steps})
    assert [p.name for p in listed_frames(folder, 1)] == [f"step_{s:06d}.exr" for s in steps]
    code, err = run_cli(["simulate", "--frames", folder, *SIM, "-o", tmp_path / "s.dat"], capsys)
    assert code == 0, err
    per_step = _spikes_per_step(tmp_path / "s.dat")
    assert len(per_step) == 6 and per_step[:3].sum() == 0 and per_step[3:].sum() > 0, per_step


def test_a_folder_of_own_exrs_is_read_in_natural_name_order(tmp_path, capsys):
    """frame_0.exr ... frame_11.exr (not zero-padded) were read as 0, 1, 10, 11, 2, ... (round eleven)."""
    from pipelines.simulate_cmd import exr_files
    from spikesim.imageio import write_exr
    folder = tmp_path / "own"
    folder.mkdir()
    for i in range(12):
        write_exr(folder / f"frame_{i}.exr", np.full((H, W), 0.0 if i < 10 else 0.9, np.float32))
    assert [p.name for p in exr_files(folder)] == [f"frame_{i}.exr" for i in range(12)]
    code, err = run_cli(["simulate", "--frames", folder, *SIM, "-o", tmp_path / "s.dat"], capsys)
    assert code == 0, err
    per_step = _spikes_per_step(tmp_path / "s.dat")
    assert len(per_step) == 12 and per_step[:10].sum() == 0 and per_step[10:].sum() > 0, per_step
    from pipelines.cli import main
    capsys.readouterr()
    assert main(["simulate", "--help"]) == 0
    assert "natural name order, numbers compared as numbers" in " ".join(capsys.readouterr().out.split())


def test_sigterm_leaves_no_partial_stream(tmp_path):
    """SIGTERM to simulate left the hidden partial stream .s.dat.XXXX.part (SIGINT removed it) (round
    eleven)."""
    spikesim = Path(sys.executable).parent / "spikesim"
    cmd = [str(spikesim), "simulate", "--steps", "20000000", "--height", "16", "--width", "16", "--backend", "numpy",
           "--quiet", "-o", str(tmp_path / "s.dat")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob(".s.dat*.part")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert list(tmp_path.glob(".s.dat*.part")), "the run never started writing"
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 143 and "spikesim simulate: terminated (SIGTERM)" in err, (proc.returncode, err)
    assert not list(tmp_path.glob("*.part")) and not list(tmp_path.glob(".*.part")), sorted(os.listdir(tmp_path))
    assert not (tmp_path / "s.dat").exists()


@pytest.mark.parametrize("dtype, value", [(np.uint8, 200), (np.int32, 0), (np.bool_, True)])
def test_an_integer_npy_is_refused(tmp_path, capsys, dtype, value):
    """np.full((4, 8, 8), 200, np.uint8) was taken as y = 200: a saturated stream, rc 0 (round eleven)."""
    np.save(tmp_path / "u8.npy", np.full((4, 8, 8), value, dtype))
    code, err = run_cli(["simulate", "--frames", tmp_path / "u8.npy", *SIM, "-o", tmp_path / "s.dat"], capsys)
    line = one_line(err)
    assert code == 2 and "u8.npy" in line and "as floats" in line and "must be scaled" in line, line
    assert not (tmp_path / "s.dat").exists()


def test_the_step_count_the_frames_give_is_bounded(tmp_path, capsys, monkeypatch):
    """Two frames with --keyframe-every 2**31 - 1 started simulating 2,147,483,648 steps, beyond the
    bound --steps has (round eleven)."""
    import pipelines.simulate_cmd as simulate_cmd

    def no_long_run(args, cam, steps):  # reached only once the step count is decided: never simulate 2**31 steps
        assert steps <= 2 ** 31 - 1, f"about to simulate {steps:,} steps"
    monkeypatch.setattr(simulate_cmd, "check_free_space", no_long_run)
    np.save(tmp_path / "two.npy", np.full((2, 8, 8), 0.2, np.float32))
    code, err = run_cli(["simulate", "--frames", tmp_path / "two.npy", "--keyframe-every", "2147483647", *SIM,
                         "-o", tmp_path / "x.dat"], capsys)
    line = one_line(err)
    assert code == 2 and "--keyframe-every 2147483647" in line and "2 keyframes" in line, line
    assert "2,147,483,648 steps" in line and "2,147,483,647" in line, line
    assert not list(tmp_path.glob("x.dat*"))
    code, err = run_cli(["simulate", "--frames", tmp_path / "two.npy", "--keyframe-every", "2147483647", "--steps",
                         "3", *SIM, "-o", tmp_path / "x.dat"], capsys)
    assert code == 0, err


def test_light_messages_say_what_applies(tmp_path, capsys):
    """--light normal with a render lit normal said "render again with --light normal"; --light low
    with no --frames said "frames are lit as they were made" (round eleven)."""
    folder = _render_folder(tmp_path / "r1", {0: 0.1, 1: 0.1}, light="normal")
    code, err = run_cli(["simulate", "--frames", folder, "--light", "normal", *SIM, "-o", tmp_path / "s.dat"], capsys)
    line = one_line(err)
    assert code == 2 and "not taken with --frames" in line and "'normal'" in line and "drop --light" in line, line
    assert "render again" not in line
    code, err = run_cli(["simulate", "--frames", folder, "--light", "low", *SIM, "-o", tmp_path / "s.dat"], capsys)
    assert code == 2 and "render again with --light low" in one_line(err)
    code, err = run_cli(["simulate", "--light", "low", "--steps", "2", *SIM, "-o", tmp_path / "s.dat"], capsys)
    line = one_line(err)
    assert code == 2 and "--scene only" in line and "--peak-y" in line and "frames" not in line, line
    assert not (tmp_path / "s.dat").exists()
