"""Ground truth above the sensor's saturation (y = 1 spike per step): recorded by generate in
meta.json and the manifest, warned about, and clipped in every training sample and in evaluate."""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent / "model"))  # modeltest_fakes

from modeltest_fakes import FakeScene, make_scene  # noqa: E402
from spikesim.generation import PRESETS, SceneJob, generate, llr_windows, saturation_summary  # noqa: E402
from spikesim.dataset import SATURATION_Y, open_dataset, saturated_fraction  # noqa: E402


def bright_pattern_job(peak_y: float, name: str = "bright") -> SceneJob:
    """A built-in pattern scene (no renderer) whose ground truth peaks at `peak_y`."""
    from spikesim.generation.plan import _camera_dict, _render_dict
    preset = PRESETS["small"].replace(height=12, width=16)
    wins, centres = llr_windows(3)
    return SceneJob(name=name, source={"type": "pattern", "peak_y": peak_y, "pattern_seed": 4},
                    camera=_camera_dict(preset, None), render=_render_dict(preset, 4), num_steps=wins[-1][1],
                    gt_steps=centres, windows=wins, seed=4)


def test_saturated_fraction_counts_pixels_above_one_spike_per_step():
    assert SATURATION_Y == 1.0
    assert saturated_fraction(np.array([[0.5, 1.0], [1.0001, 7.0]])) == 0.5
    assert saturated_fraction(np.zeros((0, 3))) == 0.0


def test_sequence_dataset_clips_ground_truth_at_saturation():
    from model.data import SequenceDataset
    sc = make_scene("hot", 16, 16, 7 * 5, brightness=0.3, seed=2)
    sc.gt = {n: img * 6.0 for n, img in sc.gt.items()}  # most pixels above 1
    assert max(float(g.max()) for g in sc.gt.values()) > 2
    ds = SequenceDataset([sc], 7, 3, crop=8, seed=1, samples_per_epoch=4)
    for i in range(len(ds)):
        item = ds[i]
        c, y0, x0 = item["first_centre"], item["y0"], item["x0"]
        want = np.stack([np.minimum(sc.gt[c + 7 * k][y0:y0 + 8, x0:x0 + 8], 1.0) for k in range(3)])
        np.testing.assert_array_equal(item["gt"].numpy(), want)
        assert float(item["gt"].max()) == 1.0
    with pytest.raises(ValueError, match="saturation"):
        SequenceDataset([sc], 7, 3, crop=8, saturation=0.0)


def test_generated_scene_above_saturation_is_recorded_warned_and_clipped(tmp_path, caplog):
    from model.data import SequenceDataset, open_scenes
    jobs = [bright_pattern_job(3.0), bright_pattern_job(0.3, "dim")]
    with caplog.at_level(logging.WARNING, logger="spikesim.generate"):
        report = generate(jobs, tmp_path, workers=1, show_progress=False)
    bright = next(s for s in open_dataset(tmp_path) if s.name == "bright")
    stored = np.stack([bright.ground_truth(c) for c in bright.gt_steps])
    assert stored.max() > 2  # stored as rendered: the dataset keeps the physics
    rec = bright.meta["gt_saturation"]
    assert rec["saturated_fraction"] == pytest.approx(saturated_fraction(stored)) and rec["saturated_fraction"] > 0.01
    assert rec["max_y"] == pytest.approx(float(stored.max())) and rec["saturation_y"] == 1.0
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["gt_saturated_fraction"]["bright"] == pytest.approx(rec["saturated_fraction"])
    assert manifest["gt_saturated_fraction"]["dim"] == 0.0
    assert report["saturation"]["bright"] == pytest.approx(rec["saturated_fraction"])
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and warned[0].startswith("bright:") and "saturation" in warned[0]
    line = saturation_summary(report["saturation"])
    assert "1 scene(s) above 1 %: bright" in line
    # every sample the training data yields is clipped at saturation
    ds = SequenceDataset(open_scenes(tmp_path), 41, 3, crop=8, seed=0, samples_per_epoch=6)
    samples = [ds[i]["gt"].numpy() for i in range(len(ds))]
    assert max(float(g.max()) for g in samples) == 1.0
    assert all(float(g.min()) >= 0.0 for g in samples)


def test_generate_prints_the_saturation_per_scene_and_overall(tmp_path, capsys):
    from pipelines.cli import main
    rc = main(["generate", "rllr", "--pattern", "--count", "1", "--steps", "42", "--gt-stride", "41",
               "--height", "8", "--width", "8", "--workers", "1", "--quiet", "-o", str(tmp_path / "o")])
    out = capsys.readouterr().out
    assert rc == 0
    assert "rllr_0000:" in out and "0.00 % of ground-truth pixels saturated" in out
    assert "ground truth above saturation" not in out  # nothing saturates: no summary line


def test_evaluate_clips_ground_truth_at_saturation():
    from model.methods import MapMethod
    from pipelines import evaluate as ev
    hot = make_scene("hot", 16, 16, 7 * 4, brightness=0.4, seed=3)
    clipped = FakeScene("hot", hot.spike_array, {n: np.minimum(g * 5.0, 1.0) for n, g in hot.gt.items()})
    hot.gt = {n: g * 5.0 for n, g in hot.gt.items()}
    a = ev.evaluate([hot], [MapMethod("TFP", "tfp", 7)], 7, progress=False)[0]
    b = ev.evaluate([clipped], [MapMethod("TFP", "tfp", 7)], 7, progress=False)[0]
    assert a == b
