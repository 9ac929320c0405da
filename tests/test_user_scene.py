"""A scene of one's own through every command that renders it: the scene's film and spp are kept
unless a flag says otherwise (one function decides, for generate, render and simulate --scene);
a user scene takes a length as RLLR scenes do; render and simulate take --light-power-factor;
and what a run records is what it used (the quality's spp, a camera file's size, the camera's
name, the parameters that differ, every run's jobs in the manifest).

Tiny films (plain_scene's 40 x 25 or less), 1-16 spp, a few steps."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cli_testing import one_line, run_cli
from pipelines.cli import main
from spikesim._drjit import has_llvm

if not has_llvm():  # pragma: no cover - depends on the machine
    pytest.skip("Dr.Jit's LLVM backend is unavailable (libLLVM >= 17 missing)", allow_module_level=True)

PLAIN = Path(__file__).resolve().parent / "data" / "plain_scene" / "scene.xml"  # film 40 x 25, sampler 16 spp
BOUNCE = Path(__file__).resolve().parent / "data" / "bounce_scene" / "scene.xml"  # lit by bounced light only
TINY = ["--height", "8", "--width", "12", "--workers", "1", "--quiet"]


def run(argv, capsys) -> str:
    capsys.readouterr()
    assert main([str(a) for a in argv]) == 0
    return capsys.readouterr().out


def settings_line(out: str) -> str:
    return next(line for line in out.splitlines() if line.startswith("settings:"))


# ---- 6: every command keeps the scene's film and spp ----------------------------------------------
def test_render_keeps_the_scenes_film_and_spp_and_says_where_they_came_from(tmp_path, capsys):
    out = run(["render", PLAIN, "--steps", "0", "-o", tmp_path / "r"], capsys)
    line = settings_line(out)
    assert "height 25 (scene file scene.xml)" in line and "spp 16 (scene file scene.xml)" in line
    assert "camera realistic (default)" in line
    record = json.loads((tmp_path / "r" / "render.json").read_text())
    assert (record["render"]["spp"], record["render"]["height"], record["render"]["width"]) == (16, 25, 40)
    assert record["settings"]["spp"] == {"value": 16, "from": "scene file scene.xml"}


def test_render_flags_override_the_scene_file(tmp_path, capsys):
    out = run(["render", PLAIN, "--steps", "0", "--spp", "2", "--height", "10", "--width", "16", "-o", tmp_path / "r"],
              capsys)
    assert "spp 2 (--spp)" in settings_line(out) and "height 10 (--height)" in settings_line(out)
    record = json.loads((tmp_path / "r" / "render.json").read_text())
    assert (record["render"]["spp"], record["render"]["height"], record["render"]["width"]) == (2, 10, 16)


def _stream_record(dat: Path) -> dict:
    from spikesim.stream import sidecar_path
    return json.loads(sidecar_path(dat).read_text())


def test_simulate_scene_keeps_the_scenes_film_and_spp(tmp_path, capsys):
    dat = tmp_path / "s.dat"
    out = run(["simulate", "--scene", PLAIN, "--steps", "3", "--backend", "numpy", "--quiet", "-o", dat], capsys)
    assert "width 40 (scene file scene.xml)" in settings_line(out)
    side = _stream_record(dat)
    assert (side["height"], side["width"]) == (25, 40)  # not the camera's 250 x 400
    assert side["irradiance"]["render"]["spp"] == 16
    assert side["irradiance"]["settings"]["spp"]["from"] == "scene file scene.xml"


def test_simulate_scene_takes_a_camera_files_size_over_the_scene_film(tmp_path, capsys):
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"preset": "noiseless", "height": 10, "width": 14}))
    dat = tmp_path / "s.dat"
    out = run(["simulate", "--scene", PLAIN, "--camera", cam, "--steps", "2", "--spp", "1", "--backend", "numpy",
               "--quiet", "-o", dat], capsys)
    line = settings_line(out)
    assert f"camera {cam} (--camera)" in line and "height 10 (--camera cam.json)" in line
    assert (_stream_record(dat)["height"], _stream_record(dat)["width"]) == (10, 14)


# ---- 8: a user scene's length, and --light-power-factor on render and simulate --------------------
def test_generate_scene_takes_steps_and_a_ground_truth_stride(tmp_path, capsys):
    out = run(["generate", "scene", "--xml", PLAIN, "--steps", "6", "--gt-stride", "3", "--spp", "1", "--gt-spp", "1",
               *TINY, "-o", tmp_path / "d"], capsys)
    assert "steps 6 (--steps)" in settings_line(out) and "gt_stride 3 (--gt-stride)" in settings_line(out) and "rllr_" not in settings_line(out)
    meta = json.loads((tmp_path / "d" / "plain_scene_normal" / "meta.json").read_text())
    assert meta["job"]["num_steps"] == 6 and len(meta["job"]["gt_steps"]) == 2 and meta["windows"] == []
    # no light file names a subject: the view centre's is metered, and under the lamp it is all direct light
    subject = meta["source"]["light"]["subject"]
    assert meta["subject_illuminance"].startswith("total") and meta["subject_illuminance_lux"] == subject["total_illuminance_lux"]
    assert meta["subject_illuminance_lux"] == pytest.approx(subject["direct_illuminance_lux"],
                                                            abs=4 * subject["total_illuminance_se_lux"], rel=0.01)


def test_generate_scene_meters_a_subject_lit_by_bounced_light(tmp_path, capsys):
    """The ball's front faces away from its lamp: 0 lx of direct light, yet lit by the floor and wall."""
    out = run(["generate", "scene", "--xml", BOUNCE, "--steps", "2", "--gt-stride", "2", "--spp", "1", "--gt-spp", "1",
               *TINY, "-o", tmp_path / "d"], capsys)
    meta = json.loads((tmp_path / "d" / "bounce_scene_normal" / "meta.json").read_text())
    assert meta["source"]["light"]["subject"]["direct_illuminance_lux"] == 0.0
    assert meta["subject_illuminance_lux"] > 10 and meta["subject_illuminance"].startswith("total")
    assert f"{meta['subject_illuminance_lux']:.4g} lx at the subject (metered: direct and indirect)" in out


def test_generate_scene_refuses_windows_with_steps(tmp_path, capsys):
    rc, err = run_cli(["generate", "scene", "--xml", PLAIN, "--windows", "2", "--steps", "6", *TINY,
                       "-o", tmp_path / "d"], capsys)
    assert rc == 2 and "--windows and --steps/--gt-stride" in one_line(err)


def test_render_light_power_factor_dims_the_frames_and_the_record(tmp_path, capsys):
    from spikesim.imageio import read_exr
    common = ["--steps", "0", "--spp", "1", "--height", "10", "--width", "16"]
    run(["render", PLAIN, *common, "-o", tmp_path / "full"], capsys)
    out = run(["render", PLAIN, *common, "--light-power-factor", "0.25", "-o", tmp_path / "dim"], capsys)
    assert "light_power_factor 0.25 (--light-power-factor)" in settings_line(out)
    full = read_exr(tmp_path / "full" / "frames" / "step_000000.exr")
    dim = read_exr(tmp_path / "dim" / "frames" / "step_000000.exr")
    assert full.max() > 0 and np.allclose(dim, 0.25 * full, rtol=1e-5, atol=0)
    record = json.loads((tmp_path / "dim" / "render.json").read_text())
    assert record["light"]["light_power_factor"] == 0.25


@pytest.mark.parametrize("command", [["render", PLAIN], ["simulate", "--scene", PLAIN], ["generate", "scene"]])
@pytest.mark.parametrize("value", ["0", "nan", "2e6", "-1"])
def test_light_power_factor_is_validated_alike_by_every_command(tmp_path, capsys, command, value):
    rc, err = run_cli([*command, "--light-power-factor", value, "-o", tmp_path / "o"], capsys)
    assert rc == 2 and "argument --light-power-factor" in err


def test_light_power_factor_has_one_help_text(capsys):
    texts = []
    for command in ("render", "simulate", "generate"):
        assert main([command, "--help"]) == 0
        help_text = " ".join(capsys.readouterr().out.split())
        start = help_text.index("--light-power-factor LIGHT_POWER_FACTOR ")
        texts.append(help_text[start:help_text.index("recorded", start)])
    assert texts[0] == texts[1] == texts[2]


def test_simulate_refuses_light_power_factor_without_a_scene(tmp_path, capsys):
    rc, err = run_cli(["simulate", "--light-power-factor", "0.5", "--steps", "2", "-o", tmp_path / "s.dat"], capsys)
    assert rc == 2 and "give --scene too" in one_line(err)


# ---- 9: what is recorded is what was used ---------------------------------------------------------
def test_a_quality_records_the_spp_its_renderer_used(tmp_path, capsys):
    run(["generate", "scene", "--xml", PLAIN, "--quality", "draft", "--spp", "3", "--steps", "4", "--gt-stride", "4",
         *TINY, "-o", tmp_path / "d"], capsys)
    meta = json.loads((tmp_path / "d" / "plain_scene_normal" / "meta.json").read_text())
    used = meta["source"]["render"]["spp"]
    assert used == 16 and meta["job"]["render"]["spp"] == used and meta["settings"]["spp"]["value"] == used


def test_a_camera_files_size_is_used_and_the_camera_named(tmp_path, capsys):
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"preset": "noiseless", "height": 6, "width": 10}))
    out = run(["generate", "scene", "--xml", PLAIN, "--camera", cam, "--steps", "3", "--gt-stride", "3",
               "--spp", "1", "--gt-spp", "1", "--workers", "1", "--quiet", "-o", tmp_path / "d"], capsys)
    line = settings_line(out)
    assert f"camera {cam} (--camera)" in line and "height 6 (--camera cam.json)" in line
    meta = json.loads((tmp_path / "d" / "plain_scene_normal" / "meta.json").read_text())
    assert (meta["height"], meta["width"]) == (6, 10)


def test_other_parameters_are_named_with_old_and_new_values(tmp_path, capsys):
    argv = ["generate", "scene", "--xml", PLAIN, "--steps", "3", "--gt-stride", "3", "--gt-spp", "1", *TINY,
            "-o", tmp_path / "d"]
    run([*argv, "--spp", "1"], capsys)
    rc, err = run_cli([*argv, "--spp", "2"], capsys)
    assert rc == 2 and "generated with other parameters (render.spp 1 -> 2)" in one_line(err)


def test_the_manifest_keeps_every_runs_jobs(tmp_path, capsys):
    argv = ["generate", "scene", "--xml", PLAIN, "--steps", "3", "--gt-stride", "3", "--spp", "1", "--gt-spp", "1",
            *TINY, "-o", tmp_path / "d"]
    run([*argv, "--name", "first"], capsys)
    run([*argv, "--name", "second", "--light-power-factor", "0.5"], capsys)
    manifest = json.loads((tmp_path / "d" / "manifest.json").read_text())
    assert sorted(manifest["scenes"]) == ["first", "second"]
    assert sorted(manifest["jobs"]) == ["first", "second"]
    first = json.loads((tmp_path / "d" / "first" / "meta.json").read_text())
    assert manifest["jobs"]["first"] == first["job_digest"]


def test_a_scene_made_with_a_quality_before_its_knobs_were_recorded_is_not_stale(tmp_path, capsys):
    """Scenes generated with --quality before the job recorded the quality's knobs hold the same
    frames: a rerun takes them as finished rather than asking for --overwrite."""
    from spikesim.generation.run import _as_rendered
    from spikesim.quality import QualitySettings
    recorded = {"quality": "draft", "render": {"spp": 3, "gt_spp": 2, "variant": "auto", "seed": 1}, "keyframe_every": 4}
    knobs = QualitySettings.from_name("draft").render_kwargs()
    rendered = _as_rendered(recorded)
    assert rendered["render"]["spp"] == knobs["spp"] and rendered["keyframe_every"] == knobs["keyframe_every"]
    assert _as_rendered({**recorded, "quality": None}) == {**recorded, "quality": None}
