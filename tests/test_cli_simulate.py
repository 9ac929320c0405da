"""`spikesim simulate`: step counts the source cannot give are refused, and nothing is written."""
from __future__ import annotations

import numpy as np
import pytest

from pipelines.cli import main
from spikesim.stream import read_dat

H, W = 8, 16


def simulate(*args: str) -> list[str]:
    return ["simulate", "--height", str(H), "--width", str(W), "--backend", "numpy", "--camera", "noiseless",
            "--quiet", *args]


def test_zero_steps_is_refused_and_writes_nothing(tmp_path, capsys):
    assert main(simulate("--steps", "0", "-o", str(tmp_path / "s.dat"))) == 2
    assert "argument --steps: must be a positive integer, got 0" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("frames, k, steps, covered", [(20, 1, 100, 20), (20, 10, 200, 191), (1, 10, 2, 1)])
def test_steps_beyond_the_frames_are_refused(frames, k, steps, covered, tmp_path, capsys):
    np.save(tmp_path / "f.npy", np.full((frames, H, W), 0.25, np.float32))
    out = tmp_path / "out" / "s.dat"
    rc = main(simulate("--frames", str(tmp_path / "f.npy"), "--keyframe-every", str(k), "--steps", str(steps),
                       "-o", str(out)))
    err = capsys.readouterr().err
    assert rc == 2
    assert f"--steps {steps}:" in err and f"cover only {covered} steps" in err, err
    assert not (tmp_path / "out").exists()


def test_steps_the_keyframes_cover_are_simulated(tmp_path):
    np.save(tmp_path / "f.npy", np.full((20, H, W), 0.25, np.float32))
    out = tmp_path / "s.dat"
    assert main(simulate("--frames", str(tmp_path / "f.npy"), "--keyframe-every", "10", "--steps", "191",
                         "-o", str(out))) == 0
    assert read_dat(out, H, W).num_steps == 191


def test_steps_beyond_an_exr_folder_are_refused(tmp_path, capsys):
    from spikesim.imageio import write_exr

    for i in range(3):
        write_exr(tmp_path / "exr" / f"{i:03d}.exr", np.full((H, W), 0.25, np.float32))
    assert main(simulate("--frames", str(tmp_path / "exr"), "--steps", "5", "-o", str(tmp_path / "s.dat"))) == 2
    assert "cover only 3 steps" in capsys.readouterr().err
    assert main(simulate("--frames", str(tmp_path / "exr"), "--steps", "3", "-o", str(tmp_path / "s.dat"))) == 0
    assert read_dat(tmp_path / "s.dat", H, W).num_steps == 3


def test_scene_options_without_a_scene_are_refused(tmp_path, capsys):
    np.save(tmp_path / "f.npy", np.full((4, H, W), 0.25, np.float32))
    assert main(simulate("--frames", str(tmp_path / "f.npy"), "--spp", "4", "-o", str(tmp_path / "s.dat"))) == 2
    assert "--spp applies to a rendered scene" in capsys.readouterr().err



def test_frames_give_the_camera_their_size_unless_told_otherwise(tmp_path, capsys):
    """`simulate --frames x.npy` asked for the size the array has."""
    frames = tmp_path / "f.npy"
    np.save(frames, np.full((30, 6, 10), 0.2, np.float32))
    assert main(["simulate", "--frames", str(frames), "--backend", "numpy", "--quiet", "-o", str(tmp_path / "a.dat")]) == 0
    assert read_dat(tmp_path / "a.dat", 6, 10).num_steps == 30
    assert main(["simulate", "--frames", str(frames), "--height", "8", "--width", "10", "--backend", "numpy",
                 "--quiet", "-o", str(tmp_path / "b.dat")]) == 2  # a size given is a size checked
    assert "frames are 6x10" in capsys.readouterr().err


def test_a_users_file_at_the_sidecars_name_is_not_replaced(tmp_path, capsys):
    """-o X.dat with the user's X.dat.json (and --twin with X_twin.dat.json) beside no stream: the
    record was replaced by the new stream's, rc 0 (round nine)."""
    frames = tmp_path / "f.npy"
    np.save(frames, np.full((20, 8, 8), 0.1, np.float32))
    for name, extra in (("s.dat.json", []), ("t_twin.dat.json", ["--twin"])):
        (tmp_path / name).write_text("precious")
        out = tmp_path / (name.split("_twin")[0].replace(".dat.json", "") + ".dat")
        assert main(["simulate", "--frames", str(frames), "--backend", "numpy", "-o", str(out), "--quiet", *extra]) == 2
        assert f"{name} exists beside no stream" in capsys.readouterr().err
        assert (tmp_path / name).read_text() == "precious"
        assert main(["simulate", "--frames", str(frames), "--backend", "numpy", "-o", str(out), "--quiet", *extra,
                     "--overwrite"]) == 0
