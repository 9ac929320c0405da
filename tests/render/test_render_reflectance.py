"""Sensor reflectance: the mono path weights colours as the silicon pixel does, so it matches spectral."""
from __future__ import annotations

import numpy as np
import pytest

from render_testing import SUN
from spikesim.render import PixelResponse
from spikesim.render.reflectance import SensorReflectance, light_weight, srgb_to_linear


def _conv(spectrum: str = "D65") -> SensorReflectance:
    return SensorReflectance(light_weight({spectrum: 1.0}, PixelResponse().electrons_per_joule()))


def test_grey_stays_grey_and_red_is_brighter_than_its_luminance():
    conv = _conv()
    assert float(conv.of_linear_rgb(np.array([0.5, 0.5, 0.5]))) == pytest.approx(0.5, abs=0.01)
    red = float(conv.of_linear_rgb(np.array([1.0, 0.0, 0.0])))
    assert red > 0.2126 * 1.3                          # silicon sees more of red than V(lambda) does
    assert float(_conv("A").of_linear_rgb(np.array([1.0, 0.0, 0.0]))) > red   # tungsten is red-rich


def test_lookup_table_matches_exact_evaluation():
    conv = _conv("LED-B3")
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    exact = conv.of_linear_rgb(srgb_to_linear(img / 255.0))
    np.testing.assert_allclose(conv.of_srgb_image(img), exact, atol=2e-3)


def _red_plane(make_scene, lights=None):
    from PIL import Image

    shapes = ('<shape type="rectangle" id="plane"><transform name="to_world"><scale value="50"/></transform>'
              '<bsdf type="diffuse"><texture type="bitmap" name="reflectance"><string name="filename" value="red.png"/>'
              '</texture></bsdf></shape>')
    xml = make_scene(shapes, lights=lights)
    img = np.zeros((8, 8, 3), np.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 200, 40, 30
    Image.fromarray(img).save(xml.parent / "red.png")
    return xml


def test_mono_matches_spectral_on_a_coloured_surface(make_scene):
    from spikesim.render import SceneRenderer

    xml = _red_plane(make_scene)
    mono = SceneRenderer(xml, variant="mono", spp=4).render_step(0)
    spec = SceneRenderer(xml, variant="spectral", spp=64).render_step(0)
    assert mono.mean() == pytest.approx(spec.mean(), rel=0.015)
    # the eye's weighting (luminance) would be far off: it is what mono used to render
    lum = float(np.array([0.2126, 0.7152, 0.0722]) @ srgb_to_linear(np.array([200, 40, 30]) / 255.0))
    y_lum = SceneRenderer(xml, variant="mono").exposure.white_surface_y(100, "D65", lum)
    assert abs(y_lum / spec.mean() - 1) > 0.2


def test_auto_variant_follows_the_number_of_light_spectra(make_scene):
    from spikesim.render import SceneRenderer

    xml = _red_plane(make_scene)
    assert SceneRenderer(xml).variant == "mono"
    lamp = {"id": "bulb", "type": "point", "spectrum": "A", "position": [0, 0, 3], "power": {"luminous_flux_lm": 100}}
    mixed = _red_plane(make_scene, lights={"normal": {"emitters": [SUN, lamp]}})
    assert SceneRenderer(mixed).variant == "spectral"
