"""A scene's identity is the content of its inputs: an edited XML, mesh, texture, light or motion
file makes a rerun of `generate` rebuild that scene (and say why), not keep the old data; an
unchanged rerun keeps it, and a dataset written before the inputs were recorded stays valid."""
from __future__ import annotations

import hashlib
import json
import logging

import pytest

from identity_testing import SUN_LUX, make_user_scene, tiny_preset
from spikesim.dataset import CHECKSUMS, MANIFEST, META, verify
from spikesim.generation import PRESETS, generate, job_status, plan_llr, plan_rllr, plan_user
from spikesim.generation.inputs import job_inputs
from spikesim.imageio import read_exr


def _generate(xml, root, **kw):
    jobs = plan_user(str(xml), "normal", tiny_preset())
    return jobs, generate(jobs, root, workers=1, show_progress=False, **kw)


def _recorded(root, name, input_name):
    meta = json.loads((root / name / META).read_text())
    return next(i["identity"] for i in meta["inputs"] if i["name"] == input_name)


EDITS = {
    "scene.xml": lambda d: (d / "scene.xml").write_text((d / "scene.xml").read_text().replace('value="30"', 'value="32"')),
    "lights.json": lambda d: (d / "lights.json").write_text((d / "lights.json").read_text().replace(str(SUN_LUX), "10")),
    "motion.json": lambda d: (d / "motion.json").write_text((d / "motion.json").read_text().replace("1300", "13")),
    "textures/floor.png": lambda d: (d / "textures" / "floor.png").write_bytes(
        (d / "textures" / "floor.png").read_bytes().replace(b"IEND", b"IEND", 1) + b"\0"),
}


@pytest.mark.parametrize("edited", sorted(EDITS))
def test_an_edited_input_is_rebuilt_and_named(tmp_path, caplog, edited):
    xml = make_user_scene(tmp_path / "sc")
    root = tmp_path / "out"
    _, first = _generate(xml, root)
    name = first["generated"][0]["name"]
    _, again = _generate(xml, root)
    assert again["generated"] == [] and again["skipped"] == 1  # unchanged: kept
    EDITS[edited](xml.parent)
    caplog.set_level(logging.WARNING, logger="spikesim.generate")
    jobs, report = _generate(xml, root)
    assert [r["name"] for r in report["generated"]] == [name]
    assert report["rebuilt"] == {name: f"{edited} changed"}
    assert f"{name}: {edited} changed, rebuilding" in caplog.text
    new_sha = hashlib.sha256((xml.parent / edited).read_bytes()).hexdigest()
    assert _recorded(root, name, edited) == new_sha
    meta = json.loads((root / name / META).read_text())
    assert meta["job_digest"] == jobs[0].digest and meta["source"]["sha256"]["xml"] == _recorded(root, name, "scene.xml")
    assert verify(root) == [] and job_status(jobs[0], root) == "done"


def test_the_light_power_change_reaches_the_data(tmp_path):
    xml = make_user_scene(tmp_path / "sc")
    root = tmp_path / "out"
    _generate(xml, root, overwrite_stale=True)
    before = read_exr(root / "sc_normal" / "gt" / "step_000020.exr")
    EDITS["lights.json"](xml.parent)
    _generate(xml, root, overwrite_stale=True)  # --overwrite rebuilds it the same way
    after = read_exr(root / "sc_normal" / "gt" / "step_000020.exr")
    assert after.mean() == pytest.approx(before.mean() * 10 / SUN_LUX, rel=1e-3)


def test_a_file_edited_after_planning_is_not_written_under_the_old_identity(tmp_path):
    xml = make_user_scene(tmp_path / "sc")
    jobs = plan_user(str(xml), "normal", tiny_preset())
    EDITS["lights.json"](xml.parent)
    with pytest.raises(ValueError, match="lights.json changed since this run was planned"):
        generate(jobs, tmp_path / "out", workers=1, show_progress=False)
    assert not (tmp_path / "out" / "sc_normal").exists()


def _as_written_before(root, name):
    """Rewrite a scene as the generator wrote it before its inputs were recorded: a job without
    inputs, its digest from the parameters alone, no "inputs" record (checksums updated)."""
    folder = root / name
    meta = json.loads((folder / META).read_text())
    del meta["job"]["inputs"], meta["inputs"]
    meta["job_digest"] = hashlib.sha256(json.dumps(meta["job"], sort_keys=True).encode()).hexdigest()[:16]
    (folder / META).write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    sums = json.loads((folder / CHECKSUMS).read_text())
    data = (folder / META).read_bytes()
    sums["files"][META] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    (folder / CHECKSUMS).write_text(json.dumps(sums))
    manifest = json.loads((root / MANIFEST).read_text())
    manifest["scenes"][name] = {f"{name}/{k}": v for k, v in sums["files"].items()}
    (root / MANIFEST).write_text(json.dumps(manifest))


def test_a_dataset_written_before_stays_valid_until_an_input_changes(tmp_path, caplog):
    xml = make_user_scene(tmp_path / "sc")
    root = tmp_path / "out"
    _generate(xml, root)
    _as_written_before(root, "sc_normal")
    _, report = _generate(xml, root)
    assert report["generated"] == [] and report["skipped"] == 1
    EDITS["lights.json"](xml.parent)
    caplog.set_level(logging.WARNING, logger="spikesim.generate")
    _, report = _generate(xml, root)
    assert report["rebuilt"] == {"sc_normal": "lights.json changed"}
    assert "inputs" in json.loads((root / "sc_normal" / META).read_text())


def test_other_parameters_still_need_overwrite_and_are_named(tmp_path):
    xml = make_user_scene(tmp_path / "sc")
    root = tmp_path / "out"
    _generate(xml, root)
    jobs = plan_user(str(xml), "normal", tiny_preset().replace(spp=2))
    with pytest.raises(FileExistsError, match=r"other parameters \(render.spp 1 -> 2\)"):
        generate(jobs, root, workers=1, show_progress=False)


def test_bundled_scenes_are_identified_by_every_file_they_use():
    job = plan_llr(PRESETS["small"], scenes=["fan"], lights=("low",))[0]
    assert {"scene.xml", "motion.json", "lights.json", "textures/desk.jpg", "meshes/blades.ply"} <= set(job.inputs)
    roles = {i.name: i.role for i in job_inputs(job.source)}
    assert roles["scene.xml"] == "xml" and roles["textures/desk.jpg"] == "file" and roles["spikesim"] == "code"


def test_a_random_scene_is_its_seed_and_its_generator_version(monkeypatch):
    job = plan_rllr(PRESETS["small"], count=1)[0]
    assert set(job.inputs) == {"scenes/random_scene.py", "spikesim"}
    import scenes.random_scene as rs
    monkeypatch.setattr(rs, "GENERATOR_VERSION", rs.GENERATOR_VERSION + 1)
    bumped = plan_rllr(PRESETS["small"], count=1)[0]
    assert bumped.digest != job.digest and bumped.parameters() == job.parameters()


def test_references_through_parameters_and_filename_attributes_are_inputs(tmp_path):
    """`$name` values come from the XML's <default>s; `<spectrum filename=...>` is a reference too,
    resolved relative to the XML (not the working directory); a missing one is named at planning."""
    xml = make_user_scene(tmp_path / "sc")
    (xml.parent / "data").mkdir()
    (xml.parent / "data" / "r.spd").write_text("400 0.5\n700 0.5\n")
    text = xml.read_text().replace('<scene version="3.0.0">', '<scene version="3.0.0">\n  <default name="tex" '
                                   'value="textures/floor.png"/>').replace('value="textures/floor.png"/></texture>',
                                                                           'value="$tex"/></texture>')
    text = text.replace("</scene>", '  <shape type="sphere" id="s"><bsdf type="diffuse"><spectrum name="reflectance" '
                                    'filename="data/r.spd"/></bsdf></shape>\n</scene>')
    xml.write_text(text)
    job = plan_user(str(xml), "normal", tiny_preset())[0]
    assert {"textures/floor.png", "data/r.spd"} <= set(job.inputs)
    (xml.parent / "data" / "r.spd").unlink()
    with pytest.raises(ValueError, match=r"scene.xml: references file 'data/r.spd'"):
        plan_user(str(xml), "normal", tiny_preset())


def test_a_quality_presets_settings_are_part_of_the_jobs_identity(monkeypatch):
    # A job made with --quality is its preset's settings too: when a version's preset changes
    # (the fast rule's slope, say), the same job is another job, and a rerun rebuilds it saying why.
    import dataclasses

    import spikesim.quality as quality
    from spikesim.generation.inputs import changes
    from spikesim.generation.plan import PRESETS as SIZES, plan_llr
    before = plan_llr(SIZES["small"], scenes=["ball"], lights=("low",), quality="fast")[0]
    assert "quality fast" in before.inputs
    assert "quality fast" not in plan_llr(SIZES["small"], scenes=["ball"], lights=("low",))[0].inputs
    fast = quality.PRESETS["fast"]
    monkeypatch.setitem(quality.PRESETS, "fast", dataclasses.replace(
        fast, sample_rule=dataclasses.replace(fast.sample_rule, loss_db_per_ratio=0.1)))
    after = plan_llr(SIZES["small"], scenes=["ball"], lights=("low",), quality="fast")[0]
    assert after.digest != before.digest
    assert [c.split(" (")[0] for c in changes(before.inputs, after.inputs)] == ["quality fast changed"]
