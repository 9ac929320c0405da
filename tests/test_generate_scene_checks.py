"""A scene that cannot light the sensor is refused, not written as data, and a scene file's own
settings are checked rather than replaced: each bad value gets one line naming the XML and the
value, before any output folder is made."""
from __future__ import annotations

import numpy as np
import pytest

from identity_testing import make_user_scene, tiny_preset
from pipelines.cli import main
from spikesim.generation import generate, plan_user
from spikesim.render import SceneError

FLAGS = ["--windows", "1", "--gt-spp", "1", "--spp", "1", "--workers", "1", "--quiet"]


def _generate_cli(capsys, xml, out, *extra):
    rc = main(["generate", "scene", "--xml", str(xml), *FLAGS, *extra, "-o", str(out)])
    err = capsys.readouterr().err.strip()
    return rc, err


@pytest.mark.parametrize("field, value, message", [
    ("width", "0", "film width 0 must be a positive integer"),
    ("width", "-5", "film width -5 must be a positive integer"),
    ("height", "abc", "film height 'abc' is not an integer"),
    ("spp", "0", "sampler sample_count 0 must be a positive integer"),
    ("spp", "4e9", "sampler sample_count '4e9' is not an integer"),
    ("spp", "4000000000", "sampler sample_count 4000000000 is more than 1048576"),
])
def test_a_bad_film_or_sample_count_in_the_xml_is_refused(tmp_path, capsys, field, value, message):
    xml = make_user_scene(tmp_path / "sc", **{field: value})
    rc, err = _generate_cli(capsys, xml, tmp_path / "out", "--height", "8", "--width", "12")
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert err == f"spikesim generate: error: {xml}: {message}"
    assert not (tmp_path / "out").exists()


def test_too_many_samples_for_one_render_is_refused_before_anything_is_written(tmp_path, capsys):
    xml = make_user_scene(tmp_path / "sc")
    rc, err = _generate_cli(capsys, xml, tmp_path / "out", "--gt-spp", "100000000")
    assert rc == 2 and "gt_spp=100000000 at 8x12 pixels" in err and "Mitsuba" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kw, message", [
    ({"fov": "nan"}, "sensor fov nan must be a finite angle between 0 and 180 degrees"),
    ({"fov": "0"}, "sensor fov 0 must be a finite angle"),
    ({"fov": "180"}, "sensor fov 180 must be a finite angle"),
    ({"fov": "wide"}, "sensor fov 'wide' is not a number"),
    ({"integrator": "aov"}, "<integrator type='aov'> does not render the light reaching the camera"),
    ({"integrator": "depth"}, "<integrator type='depth'>"),
])
def test_a_camera_or_integrator_that_cannot_light_the_sensor_is_refused(tmp_path, capsys, kw, message):
    xml = make_user_scene(tmp_path / "sc", **kw)
    rc, err = _generate_cli(capsys, xml, tmp_path / "out")
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"spikesim generate: error: {xml}: {message}"), err
    assert not (tmp_path / "out").exists()


def test_a_radiance_integrator_is_accepted(tmp_path):
    xml = make_user_scene(tmp_path / "sc", integrator="path")
    report = generate(plan_user(str(xml), "normal", tiny_preset()), tmp_path / "out", workers=1, show_progress=False)
    assert len(report["generated"]) == 1


def test_black_ground_truth_from_a_lit_scene_is_refused(tmp_path, monkeypatch):
    """A camera that sees nothing lit (here: frames and ground truth forced to black)."""
    from spikesim.render import SceneRenderer
    monkeypatch.setattr(SceneRenderer, "ground_truth", lambda self, step, spp=None: np.full(
        (self.height, self.width), 3e-18, np.float32))
    xml = make_user_scene(tmp_path / "sc")
    with pytest.raises(SceneError, match=r"its ground truth is black \(brightest pixel y = 3e-18 spikes per step over "
                                         r"1 image\(s\)\) although its lights are on \(100 lx at the subject\)"):
        generate(plan_user(str(xml), "normal", tiny_preset()), tmp_path / "out", workers=1, show_progress=False)
    assert not (tmp_path / "out").exists()


def test_a_non_finite_rendered_frame_names_the_xml(tmp_path, monkeypatch):
    """On the host (render_step) and on the render device, where the sensor kernel finds it."""
    from spikesim._drjit import dr
    from spikesim.render import SceneRenderer
    real_film, real_device = SceneRenderer._film, SceneRenderer.render_step_device

    def film(self, step, spp, stream):
        out = real_film(self, step, spp, stream)
        out[0, 0] = np.nan if step == 3 else out[0, 0]
        return out

    def device(self, step, spp=None):
        y = real_device(self, step, spp)
        return dr.select(dr.arange(type(y), dr.width(y)) == 0, np.nan, y) if step == 3 else y

    monkeypatch.setattr(SceneRenderer, "_film", film)
    monkeypatch.setattr(SceneRenderer, "render_step_device", device)
    xml = make_user_scene(tmp_path / "sc")
    r = SceneRenderer(xml, spp=1, resolution=(8, 12), device="llvm")
    r.render_step(2)
    with pytest.raises(SceneError, match=r"step 3 rendered 1 non-finite pixel\(s\) \(NaN or infinite\) of 96") as info:
        r.render_step(3)
    assert str(info.value).startswith(str(xml))
    with pytest.raises(SceneError, match=r"a rendered frame cannot be simulated: frame 3: 1 NaN") as info:
        generate(plan_user(str(xml), "normal", tiny_preset()), tmp_path / "out", workers=1, show_progress=False,
                 device="llvm")
    assert str(info.value).startswith(str(xml))
    assert not (tmp_path / "out").exists()
