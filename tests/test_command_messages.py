"""A new user's walls (issue 30, "First use"): what commands print, and what they say they did."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest


sys.path.insert(0, str(Path(__file__).parent / "model"))  # modeltest_fakes
from modeltest_fakes import make_scene  # noqa: E402


@pytest.fixture()
def dat(tmp_path):
    from spikesim.stream import SpikeStream, write_dat
    s = np.random.default_rng(0).random((123, 16, 24)) < 0.05
    write_dat(tmp_path / "s.dat", SpikeStream.from_bool(s))
    return tmp_path / "s.dat"


def test_reconstruct_stdout(dat, tmp_path, capsys):
    from pipelines.cli import main
    base = ["reconstruct", str(dat), "--height", "16", "--width", "24", "--method", "tfp", "--no-gif", "--no-mp4",
            "--quiet"]
    assert main([*base, "-o", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("[reconstruct] 3 frame(s)") and "{" not in out
    assert main([*base, "-o", str(tmp_path / "b"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 3


def test_panel_quiet_and_two_line_captions(dat, tmp_path, capsys):
    from pipelines.cli import main
    assert main(["panel", str(dat), "--height", "16", "--width", "24", "--methods", "tfp", "tfi", "--quiet",
                 "-o", str(tmp_path / "p.png")]) == 0
    assert capsys.readouterr().err == ""
    from PIL import Image
    assert Image.open(tmp_path / "p.png").height == 16 + 2 * 6 + 44


def test_a_second_evaluate_says_it_replaces_the_first(tmp_path, capsys, monkeypatch):
    from pipelines.cli import main
    from spikesim.dataset import write_scene
    from spikesim.stream import SpikeStream
    sc = make_scene("a_low", 12, 16, 41 * 2, brightness=0.05, velocity=0.2, seed=1)
    write_scene(tmp_path / "d", "a_low", SpikeStream.from_bool(sc.spike_array), {20: sc.gt[20], 61: sc.gt[61]}, meta={})
    monkeypatch.chdir(tmp_path)
    argv = ["evaluate", "--data", str(tmp_path / "d"), "--methods", "tfp", "--quiet"]
    assert main(argv) == 0
    assert "replacing" not in capsys.readouterr().err
    assert main(argv) == 0
    assert "replacing an earlier evaluation's" in capsys.readouterr().err


def test_reconstruct_stretches_only_dark_frames_by_default():
    """Low-light frames were near black (max 30/255) unless --enhance stretch was given."""
    from pipelines.reconstruct import display_frame

    dark = np.linspace(0, 0.01, 64).reshape(8, 8)
    bright = np.linspace(0, 0.8, 64).reshape(8, 8)
    assert display_frame(dark, "auto", 2.2, 1.0, 99.5).max() > 240
    assert display_frame(dark, "gamma", 2.2, 1.0, 99.5).max() < 40
    np.testing.assert_array_equal(display_frame(bright, "auto", 2.2, 1.0, 99.5),
                                  display_frame(bright, "gamma", 2.2, 1.0, 99.5))


def test_a_dark_preview_is_stretched_unless_a_scale_is_asked():
    """`render --steps 0` of a low-light scene wrote a near-black preview."""
    from spikesim.imageio import auto_percentile

    dark, bright = np.full((4, 4), 0.01), np.full((4, 4), 0.5)
    assert auto_percentile(dark) == 99.5 and auto_percentile(bright) is None
    assert auto_percentile(dark, scale=30.0) is None and auto_percentile(dark, percentile=90.0) == 90.0


def test_generate_progress_counts_renders_with_the_ground_truth(tmp_path):
    """The per-scene bar counted simulated steps only (100 % at 78 s of a 180 s scene); it counts
    renders now, the ground truth's included, and ends at its total."""
    from spikesim.generation.job import run_job
    from spikesim.generation.plan import PRESETS, plan_user

    job = plan_user("tests/data/plain_scene/scene.xml", "normal", PRESETS["small"], num_windows=2)[0]
    import dataclasses
    job = dataclasses.replace(job, camera={**job.camera, "height": 8, "width": 12},
                              render={**job.render, "resolution": [8, 12], "spp": 1, "gt_spp": 1})
    seen = []
    run_job(job, tmp_path, progress=lambda name, done, total: seen.append((done, total)))
    total = job.num_steps + len(job.gt_steps)  # a render per step, and one per ground-truth frame
    assert all(t == total for _, t in seen) and seen[-1][0] == total
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)


def test_a_notebook_scores_without_importing_pipelines(tmp_path):
    """Evaluation is a library (model.evaluation), as training is (model.training)."""
    import subprocess
    code = f"""
import sys
from model.evaluation import evaluate, markdown_table
from model.methods import method_from_spec
sys.path.insert(0, {str(Path(__file__).parent / 'model')!r})
from modeltest_fakes import make_scene
sc = make_scene("a_low", 12, 16, 41 * 2, brightness=0.05, velocity=0.2, seed=1)
rows = evaluate([sc], [method_from_spec("tfp")], 41, progress=False)
assert "TFP" in markdown_table(rows, ["TFP"])
assert not any(m == "pipelines" or m.startswith("pipelines.") for m in sys.modules), sorted(sys.modules)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
