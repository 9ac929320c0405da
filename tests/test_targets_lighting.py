"""RLLR's random lighting: the lamps' range, recorded in each job, and the study that chose it."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pipelines import rllr_lighting as rl
from spikesim.generation import PRESETS, plan_rllr


def _subject_lux(lights_path) -> float:
    from spikesim.render.lights import load_lights
    return load_lights(lights_path)["normal"].subject_illuminance_lux()


def test_lamps_are_drawn_in_the_range_below_saturation(tmp_path):
    pytest.importorskip("trimesh")
    from scenes.random_scene import LAMPS_LUX, build_random_scene
    assert LAMPS_LUX == (30.0, 250.0)
    lux = []
    for seed in range(6):
        _, _, lights, _ = build_random_scene(seed, tmp_path / str(seed), resolution=(8, 8))
        lux.append(_subject_lux(lights))
    assert all(30.0 * 0.999 <= v <= 250.0 * 1.001 for v in lux), lux


def test_the_range_changes_the_level_and_nothing_else(tmp_path):
    pytest.importorskip("trimesh")
    from scenes.random_scene import LAMPS_LUX_BEFORE_STUDY, build_random_scene
    new = build_random_scene(11, tmp_path / "new", resolution=(8, 8))
    old = build_random_scene(11, tmp_path / "old", resolution=(8, 8), lamps_lux=LAMPS_LUX_BEFORE_STUDY)
    assert new[0].read_text() == old[0].read_text() and new[1].read_text() == old[1].read_text()
    a, b = json.loads(new[2].read_text())["normal"], json.loads(old[2].read_text())["normal"]
    assert [e["position"] for e in a["emitters"]] == [e["position"] for e in b["emitters"]]
    assert [e["spectrum"] for e in a["emitters"]] == [e["spectrum"] for e in b["emitters"]]
    # one log-uniform draw u mapped to each range: the same u in both
    u_new = np.log(_subject_lux(new[2]) / 30.0) / np.log(250.0 / 30.0)
    u_old = np.log(_subject_lux(old[2]) / 100.0) / np.log(10.0)
    assert u_new == pytest.approx(u_old, abs=1e-3)
    with pytest.raises(ValueError, match="lamps_lux"):
        build_random_scene(11, tmp_path / "bad", lamps_lux=(0.0, 10.0))


def test_rllr_jobs_record_the_lamp_range_and_keep_the_darkening():
    jobs = plan_rllr(PRESETS["paper"], seed=0)
    assert len(jobs) == 100
    assert all(j.source["lamps_lux"] == [30.0, 250.0] for j in jobs)
    factors = np.array([j.light_power_factor for j in jobs])
    assert factors.min() > 0 and factors.max() < 1 and 0.4 < factors.mean() < 0.6  # U(0, 1), paper
    pattern = plan_rllr(PRESETS["small"], seed=0, source="pattern")
    assert "lamps_lux" not in pattern[0].source


def test_study_summary_of_light_and_saturation():
    y = np.full((2, 4, 5), 0.5)
    y[0, 0, :2] = 1.5  # 2 of 40 pixels above saturation
    rec = rl.scene_record("s", y, lamps_lux=100.0, factor=0.05)
    assert rec["subject_lux"] == pytest.approx(5.0) and rec["saturated_fraction"] == pytest.approx(0.05)
    assert rec["y_max"] == 1.5 and rec["pixels"] == 40
    dark = rl.scene_record("d", np.zeros((1, 4, 10)), lamps_lux=200.0, factor=0.6)
    s = rl.summarise([rec, dark])
    assert s["saturated_fraction_pooled"] == pytest.approx(2 / 80)
    assert s["scenes_above_1_percent"] == 1 and s["scenes_with_any_saturation"] == 1
    assert s["share_in_llr_low"] == 0.5 and s["share_in_llr_normal"] == 0.5
    text = rl.markdown(s)
    assert "| illuminance at the subject (lx) |" in text and "2.500 %" in text


def test_study_command_refuses_bad_arguments(capsys):
    with pytest.raises(SystemExit) as e:
        rl.main(["--count", "0"])
    assert e.value.code == 2 and "--count" in capsys.readouterr().err


def test_study_refuses_an_inverted_lamp_range(capsys):
    assert rl.main(["--count", "1", "--lamps-lux", "250", "30", "--quiet"]) == 2
    assert "--lamps-lux 250 30" in capsys.readouterr().err


def test_study_outputs_are_not_written_through_links(tmp_path, capsys):
    """The study's --out and --save-frames go through the project's output guard: a link there is
    refused before anything is rendered, and the file it points to is untouched."""
    outside = tmp_path / "keep.json"
    outside.write_text("keep")
    for flag in ("--out", "--save-frames"):
        link = tmp_path / f"link{flag}"
        link.symlink_to(outside)
        assert rl.main(["--count", "1", flag, str(link), "--quiet"]) == 2
        assert "is a symlink" in capsys.readouterr().err and outside.read_text() == "keep"
