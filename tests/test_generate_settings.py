"""Generation settings and a user's own scene: a scene keeps its own film and samples per pixel
unless a flag says otherwise; `generate` prints every setting with its origin and records it in
meta.json; the recorded lux includes the light power factor; two variants of one scene do not
collide on a name."""
from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import pytest

from pipelines.cli import main
from sensor_testing import requires_llvm
from spikesim.generation import PRESETS, SceneJob, generate, plan_user
from spikesim.generation.job import run_job, scale_light_amounts
from spikesim.generation.plan import user_scene_name
from spikesim.generation.settings import resolve_settings, scene_file_settings

ROOT = Path(__file__).resolve().parents[1]
BALL = ROOT / "scenes" / "ball"


def user_scene(tmp_path: Path, width: int = 80, height: int = 50, spp: int | None = 16, name: str = "scene.xml") -> Path:
    """The bundled ball scene copied as a user's own, with its film (and sampler) changed."""
    folder = tmp_path / "myscene"
    if not folder.exists():
        shutil.copytree(BALL, folder)
    text = (BALL / "scene.xml").read_text()
    text = text.replace('<integer name="width" value="400"/>', f'<integer name="width" value="{width}"/>')
    text = text.replace('<integer name="height" value="250"/>', f'<integer name="height" value="{height}"/>')
    if spp is not None:
        text = text.replace("</film>", f'</film>\n        <sampler type="independent"><integer name="sample_count" '
                                       f'value="{spp}"/></sampler>', 1)
    (folder / name).write_text(text)
    return folder / name


# ---- a user scene keeps its own film and spp ------------------------------------------------------
def test_a_user_scene_keeps_its_film_and_spp_over_the_preset(tmp_path):
    xml = user_scene(tmp_path)
    assert scene_file_settings(xml) == {"width": 80, "height": 50, "spp": 16}
    resolved = resolve_settings("scene", "small", xml=xml)
    table = resolved.table()
    assert (table["height"]["value"], table["width"]["value"], table["spp"]["value"]) == (50, 80, 16)
    assert table["spp"]["from"] == "scene file scene.xml" and table["gt_spp"]["from"] == "preset small"
    job = plan_user(str(xml), "normal", resolved.preset)[0]
    assert (job.camera["height"], job.camera["width"], job.render["spp"]) == (50, 80, 16)
    assert job.render["resolution"] == [50, 80]


def test_a_user_scene_without_a_preset_gets_a_ground_truth_the_network_cannot_beat(tmp_path):
    """The small preset's 16-spp ground truth is grainy (24-38 dB from a 128-spp one); a user who
    asked for no preset gets 64 spp and is told why; one who asked for small gets small's."""
    from spikesim.generation.settings import USER_SCENE_GT_SPP
    xml = user_scene(tmp_path)
    unasked = resolve_settings("scene", "small", xml=xml, preset_given=False).table()["gt_spp"]
    assert unasked["value"] == USER_SCENE_GT_SPP == 64 and "without --preset" in unasked["from"]
    asked = resolve_settings("scene", "small", xml=xml).table()["gt_spp"]
    assert (asked["value"], asked["from"]) == (16, "preset small")
    assert resolve_settings("llr", "small", preset_given=False).table()["gt_spp"]["value"] == 16  # the bundled sets keep theirs
    flag = resolve_settings("scene", "small", xml=xml, preset_given=False, flags={"--gt-spp": {"gt_spp": 8}})
    assert flag.table()["gt_spp"]["value"] == 8


def test_flags_and_a_settings_file_override_the_scene_file_and_say_so(tmp_path):
    xml = user_scene(tmp_path)
    settings = tmp_path / "render.json"
    settings.write_text(json.dumps({"spp": 4, "gt_spp": 32}))
    resolved = resolve_settings("scene", "small", xml=xml, settings_file=settings,
                                flags={"--spp": {"spp": 2}, "--height": {"height": None}})
    table = resolved.table()
    assert table["spp"] == {"value": 2, "from": "--spp"}
    assert table["gt_spp"] == {"value": 32, "from": f"--render-settings {settings}"}
    assert table["height"] == {"value": 50, "from": "scene file scene.xml"}  # None: the flag was not given
    assert "spp 2 (--spp)" in resolved.summary()


def test_a_bad_settings_file_names_itself(tmp_path, capsys):
    bad = tmp_path / "render.json"
    bad.write_text(json.dumps({"spp": 0}))
    with pytest.raises(ValueError, match=str(bad)):
        resolve_settings("llr", "small", settings_file=bad)
    bad.write_text(json.dumps({"device": "cuda"}))
    with pytest.raises(ValueError, match="cannot be set for a dataset"):
        resolve_settings("llr", "small", settings_file=bad)


def test_the_quality_is_reported_as_the_origin_of_the_knobs_it_sets():
    resolved = resolve_settings("llr", "small", flags={"--spp": {"spp": 3}}, quality="draft")
    assert resolved.table()["spp"] == {"value": 16, "from": "--quality draft"}
    assert resolved.preset.spp == 16  # planned with: the job records the spp its renderer is given


def test_generate_prints_each_setting_with_its_origin_and_records_it_in_meta(tmp_path):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(["generate", "rllr", "--pattern", "--count", "1", "--steps", "12", "--gt-stride", "6",
                   "--height", "8", "--width", "12", "--workers", "1", "--quiet", "-o", str(tmp_path / "d")])
    assert rc == 0
    line = next(x for x in out.getvalue().splitlines() if x.startswith("settings:"))
    assert "height 8 (--height)" in line and "spp 2 (preset small)" in line and "steps 12 (--steps)" in line and "rllr_steps" not in line
    meta = json.loads((tmp_path / "d" / "rllr_0000" / "meta.json").read_text())
    assert meta["settings"]["width"] == {"value": 12, "from": "--width"}
    assert meta["settings"]["gt_spp"] == {"value": 16, "from": "preset small"}


# ---- the recorded lux includes the light power factor --------------------------------------------
def test_light_amounts_scale_with_the_power_factor():
    record = {"name": "low", "emitters": [{"type": "spot", "power": 2.0, "photometric": 100.0, "photometric_unit": "cd",
                                           "luminous_flux_lm": 50.0, "position": [1.0, 2.0, 3.0],
                                           "electrons_per_lumen_second": 7.0}],
              "subject": {"at": [0.0, 0.0, 0.0], "direct_illuminance_lux": 30.0}}
    half = scale_light_amounts(record, 0.5)
    em = half["emitters"][0]
    assert (em["power"], em["photometric"], em["luminous_flux_lm"]) == (1.0, 50.0, 25.0)
    assert em["position"] == [1.0, 2.0, 3.0] and em["electrons_per_lumen_second"] == 7.0
    assert half["subject"]["direct_illuminance_lux"] == 15.0 and record["subject"]["direct_illuminance_lux"] == 30.0


@requires_llvm
def test_meta_records_the_lux_the_scene_was_rendered_at(tmp_path):
    preset = PRESETS["small"].replace(height=8, width=12, llr_windows=1, spp=1, gt_spp=1, keyframe_every=40)
    lux = {}
    for factor in (1.0, 0.25):
        job = plan_user(str(BALL / "scene.xml"), "low", preset, light_power_factor=factor)[0]
        run_job(job, tmp_path, backend="numpy", device="llvm")
        meta = json.loads((tmp_path / job.name / "meta.json").read_text())
        lux[factor] = meta["subject_illuminance_lux"]
        assert meta["source"]["light"]["subject"]["direct_illuminance_lux"] == pytest.approx(lux[factor])
    assert lux[1.0] > 0 and lux[0.25] == pytest.approx(0.25 * lux[1.0])


# ---- two variants of one scene in one folder -------------------------------------------------------
def test_variants_of_one_scene_get_distinct_names_and_the_same_variant_the_same(tmp_path):
    xml = user_scene(tmp_path)
    other = user_scene(tmp_path, name="night.xml")
    fast = xml.parent / "motion_fast.json"
    fast.write_text((xml.parent / "motion.json").read_text())
    names = [user_scene_name(xml, "normal"), user_scene_name(other, "normal"),
             user_scene_name(xml, "normal", motion=fast), user_scene_name(xml, "normal", light_power_factor=0.5),
             user_scene_name(xml, "low")]
    assert names == ["myscene_normal", "myscene_night_normal", "myscene_normal_motion_fast", "myscene_normal_x0.5",
                     "myscene_low"]
    assert user_scene_name(xml, "normal", motion=xml.parent / "motion.json") == "myscene_normal"  # the default
    jobs = [plan_user(str(x), "normal", PRESETS["small"])[0] for x in (xml, other)]
    assert jobs[0].name != jobs[1].name


def test_a_second_scene_under_a_taken_name_is_refused_naming_both(tmp_path):
    from spikesim.camera import SpikeCamera
    cam = SpikeCamera.realistic(height=4, width=8).to_dict()

    def job(peak: float) -> SceneJob:
        return SceneJob(name="mine", source={"type": "pattern", "peak_y": peak}, camera=cam, render={},
                        num_steps=4, gt_steps=(0,))
    generate([job(0.2)], tmp_path, workers=1, show_progress=False)
    with pytest.raises(FileExistsError, match=r"holds another scene, \{.*0\.2.*under the name this run gives \{.*0\.3") as e:
        generate([job(0.3)], tmp_path, workers=1, show_progress=False)
    # a generated set names its own folders: --name (generate scene's) is no way out (round seven, low)
    assert "another output folder (-o)" in str(e.value) and "--name" not in str(e.value)


def test_a_user_scene_under_a_taken_name_is_offered_another_name(tmp_path):
    from spikesim.camera import SpikeCamera
    from spikesim.generation.run import _takes_name
    cam = SpikeCamera.realistic(height=4, width=8).to_dict()
    xml = user_scene(tmp_path)
    user = SceneJob(name="mine", source={"type": "scene", "scene": str(xml), "motion": None, "lights": None,
                                         "light": "low"}, camera=cam, render={}, num_steps=4, gt_steps=(0,))
    bundled = SceneJob(name="fan_low", source={"type": "scene", "scene": "fan", "motion": None, "lights": None,
                                               "light": "low"}, camera=cam, render={}, num_steps=4, gt_steps=(0,))
    assert _takes_name(user) and not _takes_name(bundled)


@requires_llvm
def test_generate_scene_keeps_the_xml_film_and_spp_end_to_end(tmp_path):
    """The issue's case: an 80 x 50, 16-spp scene under the `small` preset (100 x 64, 2 spp) keeps
    its film and samples, says so, and records them."""
    xml = user_scene(tmp_path)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(["generate", "scene", "--xml", str(xml), "--light", "low", "--windows", "1", "--keyframe-every", "40",
                   "--gt-spp", "1", "--workers", "1", "--device", "llvm", "--quiet", "-o", str(tmp_path / "d")])
    assert rc == 0
    line = next(x for x in out.getvalue().splitlines() if x.startswith("settings:"))
    for text in ("height 50 (scene file scene.xml)", "width 80 (scene file scene.xml)",
                 "spp 16 (scene file scene.xml)", "gt_spp 1 (--gt-spp)", "keyframe_every 40 (--keyframe-every)"):
        assert text in line
    meta = json.loads((tmp_path / "d" / "myscene_low" / "meta.json").read_text())
    assert (meta["height"], meta["width"], meta["source"]["render"]["spp"]) == (50, 80, 16)
    assert meta["settings"]["spp"] == {"value": 16, "from": "scene file scene.xml"}


def test_power_factors_that_print_alike_still_get_distinct_names(tmp_path):
    xml = user_scene(tmp_path)
    a, b = (user_scene_name(xml, "low", light_power_factor=f) for f in (0.1234567, 0.1234568))
    assert a != b and a == user_scene_name(xml, "low", light_power_factor=0.1234567)
    assert user_scene_name(xml, "low", light_power_factor=2.0) == "myscene_low_x2"


def test_a_scene_at_another_power_under_a_taken_name_is_refused_naming_both_powers(tmp_path):
    from spikesim.camera import SpikeCamera
    cam = SpikeCamera.realistic(height=4, width=8).to_dict()

    def job(factor: float) -> SceneJob:
        return SceneJob(name="mine", source={"type": "pattern", "peak_y": 0.2}, camera=cam, render={},
                        num_steps=4, gt_steps=(0,), light_power_factor=factor)
    generate([job(1.0)], tmp_path, workers=1, show_progress=False)
    with pytest.raises(FileExistsError, match=r"holds another scene, .*power x1\b.*this run gives .*power x0\.5"):
        generate([job(0.5)], tmp_path, workers=1, show_progress=False)


def test_a_quality_with_adaptive_keyframes_says_so_where_the_spacing_is_reported():
    """`--quality balanced` printed `keyframe_every 1 (--quality balanced)` though it places its
    keyframes by motion."""
    from spikesim.generation.settings import resolve_settings
    assert "keyframe_every 1 (--quality balanced: adaptive" in resolve_settings("llr", quality="balanced").summary()
    assert "keyframe_every 1 (--quality reference)" in resolve_settings("llr", quality="reference").summary()


def test_a_scene_without_a_ground_truth_step_is_refused_when_planned():
    """generate rllr --steps 10 --gt-stride 41 wrote scenes with gt_steps [] (round seven)."""
    import dataclasses
    from spikesim.generation.plan import plan_rllr
    job = plan_rllr(PRESETS["small"], count=1)[0]
    with pytest.raises(ValueError, match="no ground-truth step in its 10 steps"):
        dataclasses.replace(job, num_steps=10, gt_steps=())
