"""`render -o D` holds one run: its render.json lists the files it wrote, a rerun replaces them and
refuses files no record lists, and `simulate --frames D` reads only the listed frames (a rerun
with another light used to leave the first run's frames beside the new ones, and simulate mixed
both into one stream)."""
from __future__ import annotations

import json

import pytest

from identity_testing import make_user_scene
from pipelines.cli import main
from spikesim.stream import DatReader

SIZE = ["--height", "8", "--width", "12", "--spp", "1"]


@pytest.fixture
def xml(tmp_path):
    xml = make_user_scene(tmp_path / "sc")
    lights = json.loads((xml.parent / "lights.json").read_text())
    low = json.loads(json.dumps(lights["normal"]))
    low["emitters"][0]["power"]["illuminance_lux"] = 10
    (xml.parent / "lights.json").write_text(json.dumps({**lights, "low": low}))
    return xml


def _render(xml, out, *args):
    return main(["render", str(xml), *SIZE, *args, "-o", str(out)])


def _simulate(frames, out, *args):
    return main(["simulate", "--frames", str(frames), "--height", "8", "--width", "12", "--quiet", *args,
                 "-o", str(out)])


def test_a_rerun_replaces_the_previous_run_and_simulate_reads_only_it(tmp_path, xml, capsys):
    d = tmp_path / "d"
    assert _render(xml, d, "--light", "normal", "--steps", "0:3") == 0
    assert _render(xml, d, "--light", "low", "--steps", "0:2") == 0
    assert sorted(p.name for p in (d / "frames").iterdir()) == [
        "step_000000.exr", "step_000000.png", "step_000001.exr", "step_000001.png"]
    record = json.loads((d / "render.json").read_text())
    assert record["files"] == ["frames/step_000000.exr", "frames/step_000000.png", "frames/step_000001.exr",
                               "frames/step_000001.png"]
    assert record["light"]["name"] == "low"
    for frames in (d, d / "frames"):
        assert _simulate(frames, tmp_path / "s.dat") == 0
        assert DatReader(tmp_path / "s.dat", 8, 12).num_steps == 2
    assert not list(d.glob(".render.*"))


def test_another_kind_of_output_replaces_the_previous_one(tmp_path, xml):
    d = tmp_path / "d"
    assert _render(xml, d, "--steps", "0:2") == 0
    assert _render(xml, d, "--steps", "1", "--ground-truth", "--gt-spp", "1") == 0
    assert not (d / "frames").exists() and sorted(p.name for p in (d / "gt").iterdir()) == [
        "step_000001.exr", "step_000001.png"]


@pytest.mark.parametrize("record", ["none", "old"])
def test_files_no_record_lists_are_refused_and_kept(tmp_path, xml, capsys, record):
    d = tmp_path / "d"
    assert _render(xml, d, "--steps", "0:2") == 0
    if record == "none":
        (d / "render.json").unlink()
    else:  # a record from before it listed its files: its kind and steps say which
        meta = json.loads((d / "render.json").read_text())
        del meta["files"]
        meta["steps"] = [0]
        (d / "render.json").write_text(json.dumps(meta))
    capsys.readouterr()
    assert _render(xml, d, "--steps", "0:2") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{d}: holds " in err and "frames/step_000001.exr" in err
    assert ("its render.json does not list" if record == "old" else "no render.json lists") in err
    assert (d / "frames" / "step_000001.exr").exists()
    if record == "old":  # simulate reads what the record lists, and says what it ignores
        assert _simulate(d, tmp_path / "s.dat") == 0
        assert DatReader(tmp_path / "s.dat", 8, 12).num_steps == 1


def test_a_failed_rerun_leaves_the_previous_run_as_it_was(tmp_path, xml, monkeypatch):
    d = tmp_path / "d"
    assert _render(xml, d, "--steps", "0:2") == 0
    before = {p.relative_to(d).as_posix(): p.read_bytes() for p in d.rglob("*") if p.is_file()}
    from spikesim.render import SceneRenderer
    real = SceneRenderer.render_step

    def failing(self, step, spp=None):
        if step == 1:
            raise ValueError("a failure midway")
        return real(self, step, spp)

    monkeypatch.setattr(SceneRenderer, "render_step", failing)
    assert _render(xml, d, "--steps", "0:3", "--light", "low") == 2
    after = {p.relative_to(d).as_posix(): p.read_bytes() for p in d.rglob("*") if p.is_file()}
    assert after == before


def test_simulate_needs_the_recorded_keyframe_spacing(tmp_path, xml, capsys):
    d = tmp_path / "d"
    assert _render(xml, d, "--steps", "0:17:8") == 0
    capsys.readouterr()
    assert _simulate(d, tmp_path / "s.dat") == 2
    assert "its frames are steps 8 apart (render.json); give --keyframe-every 8" in capsys.readouterr().err
    assert _simulate(d, tmp_path / "s.dat", "--keyframe-every", "8") == 0
    assert DatReader(tmp_path / "s.dat", 8, 12).num_steps == 17


def test_a_render_into_a_folder_in_use_is_refused(tmp_path, capsys):
    """Two renders into one -o both ended rc 0: one's record, the other's frames beside it, and every
    later render there refused (round six)."""
    from spikesim.generation.lock import output_lock
    out = tmp_path / "rr"
    out.mkdir()
    with output_lock(out, "render other (pid 4242)", what="render run"):
        rc = main(["render", "tests/data/plain_scene/scene.xml", "--steps", "0", "--spp", "1", "-o", str(out)])
    assert rc == 2 and "another render run" in capsys.readouterr().err
    assert main(["render", "tests/data/plain_scene/scene.xml", "--steps", "0", "--spp", "1", "-o", str(out)]) == 0


def test_simulate_takes_a_render_folders_frame_size(tmp_path, capsys):
    """simulate --frames RENDERFOLDER of a 16 x 24 render was read as the default 250 x 400 and
    refused, pointing to the Python API (round six)."""
    out = tmp_path / "rf"
    assert main(["render", "tests/data/plain_scene/scene.xml", "--steps", "0:3", "--spp", "1", "--height", "16",
                 "--width", "24", "-o", str(out), "--quiet"]) == 0
    assert main(["simulate", "--frames", str(out), "--backend", "numpy", "-o", str(tmp_path / "s.dat"), "--quiet"]) == 0
    info = json.loads((tmp_path / "s.dat.json").read_text())
    assert (info["height"], info["width"], info["num_steps"]) == (16, 24, 3)


def test_simulate_takes_the_size_of_a_render_folder_of_keyframes(tmp_path, capsys):
    """With --keyframe-every 2 (what simulate's own message asks for) a render folder of steps 0, 2, 4
    was read as 250 x 400 again (round eight)."""
    out = tmp_path / "rf"
    assert main(["render", "tests/data/plain_scene/scene.xml", "--steps", "0,2,4", "--spp", "1", "--height", "16",
                 "--width", "24", "-o", str(out), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["simulate", "--frames", str(out), "--backend", "numpy", "-o", str(tmp_path / "s.dat"), "--quiet"]) == 2
    assert "give --keyframe-every 2" in capsys.readouterr().err
    assert main(["simulate", "--frames", str(out), "--keyframe-every", "2", "--backend", "numpy",
                 "-o", str(tmp_path / "s.dat"), "--quiet"]) == 0
    info = json.loads((tmp_path / "s.dat.json").read_text())
    assert (info["height"], info["width"]) == (16, 24)


@pytest.mark.parametrize("exposure, field, value, says", [
    ('{"readout_period_s": 0.0001}', "readout_period_s", 1e-4, "readout_period_s 0.0001 (the camera's 2.5e-05)"),
    ('{"threshold_electrons": 500.0}', "threshold_electrons", 500.0, "threshold_electrons 500 (the camera's 1000)"),
])
def test_simulate_takes_the_camera_fields_the_frames_were_rendered_for(tmp_path, capsys, exposure, field, value, says):
    """Frames rendered for a 1e-4 s readout were simulated at the default 25e-6 s (round eight), and
    frames for a 500-electron threshold at 1000, half as bright (round nine), rc 0: a preset camera
    takes the render's values; a camera file giving others is refused."""
    (tmp_path / "e.json").write_text(exposure)
    out = tmp_path / "rf"
    assert main(["render", "tests/data/plain_scene/scene.xml", "--steps", "0:2", "--spp", "1", "--height", "16",
                 "--width", "24", "--exposure", str(tmp_path / "e.json"), "-o", str(out), "--quiet"]) == 0
    assert main(["simulate", "--frames", str(out), "--backend", "numpy", "-o", str(tmp_path / "s.dat"), "--quiet"]) == 0
    assert json.loads((tmp_path / "s.dat.json").read_text())["camera"][field] == value
    assert main(["camera", "--write", str(tmp_path / "cam.toml")]) == 0
    capsys.readouterr()
    assert main(["simulate", "--frames", str(out), "--camera", str(tmp_path / "cam.toml"), "--height", "16",
                 "--width", "24", "--backend", "numpy", "-o", str(tmp_path / "t.dat"), "--quiet"]) == 2
    assert f"rendered for {says}" in capsys.readouterr().err


def test_frames_swapped_after_the_render_are_refused_naming_the_file(tmp_path, capsys):
    """Two EXR frames swapped after the render were simulated into another stream, rc 0 (round nine)."""
    out = tmp_path / "rf"
    assert main(["render", "tests/data/plain_scene/scene.xml", "--steps", "0:2", "--spp", "1", "--height", "16",
                 "--width", "24", "-o", str(out), "--quiet"]) == 0
    a, b = out / "frames" / "step_000000.exr", out / "frames" / "step_000001.exr"
    a_bytes, b_bytes = a.read_bytes(), b.read_bytes()
    a.write_bytes(b_bytes)
    b.write_bytes(a_bytes)
    capsys.readouterr()
    assert main(["simulate", "--frames", str(out), "--backend", "numpy", "-o", str(tmp_path / "s.dat"), "--quiet"]) == 2
    assert "step_000000.exr: not the frame the render wrote" in capsys.readouterr().err
