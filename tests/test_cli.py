"""The command line end to end, on tiny inputs."""
import json

import numpy as np
import pytest

from pipelines.cli import main


def test_simulate_then_inspect(tmp_path, capsys):
    out = tmp_path / "s.dat"
    assert main(["simulate", "--height", "20", "--width", "32", "--steps", "50", "--backend", "numpy",
                 "--quiet", "-o", str(out)]) == 0
    assert out.exists() and out.with_suffix(".dat.json").exists()
    side = json.loads(out.with_suffix(".dat.json").read_text())
    assert side["num_steps"] == 50 and side["camera"]["width"] == 32 and side["seed"] == 0
    capsys.readouterr()
    assert main(["inspect", str(out), "--json", "--preview", str(tmp_path / "p.png"), "--window", "11"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["num_steps"], info["height"], info["width"]) == (50, 20, 32)
    assert 0 < info["mean_rate_per_step"] < 1 and (tmp_path / "p.png").exists()


def test_simulate_from_npy_with_keyframes(tmp_path):
    frames = np.full((4, 8, 16), 0.25, np.float32)
    np.save(tmp_path / "f.npy", frames)
    out = tmp_path / "k.dat"
    assert main(["simulate", "--frames", str(tmp_path / "f.npy"), "--height", "8", "--width", "16",
                 "--camera", "noiseless", "--keyframe-every", "10", "--quiet", "-o", str(out)]) == 0
    from spikesim.stream import read_dat
    s = read_dat(out, 8, 16)
    assert s.num_steps == 31 and np.all(s.counts() == 7)  # floor(31 * 0.25)


def test_bad_input_is_one_clear_line(tmp_path, capsys):
    (tmp_path / "odd.dat").write_bytes(b"\x00" * 7)
    assert main(["inspect", str(tmp_path / "odd.dat"), "--height", "2", "--width", "16"]) == 2
    err = capsys.readouterr().err
    assert "odd.dat" in err and "not a whole number" in err and "Traceback" not in err
    bad = np.full((2, 4, 8), 0.1, np.float32)
    bad[1, 0, 0] = -1
    np.save(tmp_path / "bad.npy", bad)
    assert main(["simulate", "--frames", str(tmp_path / "bad.npy"), "--height", "4", "--width", "8",
                 "--quiet", "-o", str(tmp_path / "b.dat")]) == 2
    assert "frame 1" in capsys.readouterr().err
    assert not (tmp_path / "b.dat").exists()


def test_bench_reports_ratios(capsys):
    assert main(["bench", "--height", "8", "--width", "32", "--steps", "16", "--numpy-steps", "8", "--streams", "2",
                 "--pipeline-steps", "9", "--keyframe-every", "4", "--repeats", "1", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["machine"]["cpu"] and res["machine"]["cores"] >= 1
    rows = res["results"]
    stages = {r["stage"] for r in rows}
    assert stages == {"sensor", "render", "pipeline"}
    ref = {r["what"].split(",")[0]: r["pixel_steps_per_s"] for r in rows if r["device"] == "numpy"}
    assert set(ref) == {"noiseless", "realistic", "realistic-renewal"}
    for r in rows:
        assert r["pixel_steps_per_s"] > 0
        assert r["vs_real_time"] == pytest.approx(r["pixel_steps_per_s"] / 4e9)
        if r["stage"] == "sensor":   # each against the NumPy reference of its own camera model
            assert r["vs_reference"] == pytest.approx(r["pixel_steps_per_s"] / ref[r["what"].split(",")[0]])
        if r["stage"] == "pipeline" and "render_share" in r:
            assert 0 < r["render_share"] <= 1
    assert any("2 streams per launch" in r["what"] for r in rows)
    assert any("frames stay on the device" in r["what"] for r in rows)