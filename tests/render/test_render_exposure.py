"""Exposure calibration: analytic values, and renders of uniformly lit planes that must match them."""
from __future__ import annotations

import math

import numpy as np
import pytest

from render_testing import PLANE
from spikesim.render import Exposure, Optics, PixelResponse
from spikesim.render import spectra
from spikesim.render.lights import _rectangle_geometry, parse_emitter


def test_photometric_normalisation_and_luminous_efficacy():
    for name in ("A", "D65", "FL2", "LED-B3"):
        s = spectra.light_spectrum(name)
        assert spectra.K_M * spectra.integrate(s * spectra.photopic_v()) == pytest.approx(1.0, rel=1e-9)
    # Luminous efficacy of radiation over 360-830 nm: D65 ~ 180-205 lm/W, a 2856 K black body
    # ~ 120-160 lm/W (CIE 015 values computed over 380-780 nm are a little higher)
    assert 170 < spectra.luminous_efficacy_of_radiation("D65") < 210
    assert 100 < spectra.luminous_efficacy_of_radiation("A") < 170


def test_silicon_quantum_efficiency_shape():
    px = PixelResponse()
    qe = px.quantum_efficiency()
    wl = spectra.WAVELENGTHS_NM
    assert 0.5 < qe.max() < 0.9
    assert 450 <= wl[qe.argmax()] <= 650            # peak in the visible
    assert qe[wl == 400][0] < qe.max() * 0.8        # blue loss in the surface layer
    assert qe[wl == 800][0] < qe.max() * 0.5        # red/NIR photons pass the collection depth


def test_y_of_white_surface_is_sensible_and_linear():
    """100 lx on a white Lambertian surface: ~0.1-0.5 spikes per 25 us step; 1 lx: 1/100 of it."""
    exp = Exposure()
    for name in ("A", "D65", "FL2", "LED-B3"):
        y100 = exp.white_surface_y(100, name)
        assert 0.1 <= y100 <= 0.5, (name, y100)
        assert exp.white_surface_y(1, name) == pytest.approx(y100 / 100, rel=1e-12)


def test_exposure_chain_by_hand():
    """Recompute y for D65 daylight step by step from the formulas, independently of the class."""
    exp = Exposure(optics=Optics(f_number=2.0, transmittance=0.8), pixel=PixelResponse(pixel_pitch_m=10e-6),
                   readout_period_s=50e-6, threshold_electrons=500.0)
    wl = spectra.WAVELENGTHS_NM
    lux, rho = 50.0, 0.4
    spectral_irradiance = lux * spectra.light_spectrum("D65")                   # W m^-2 nm^-1
    photons = spectral_irradiance * wl * 1e-9 / (6.62607015e-34 * 299792458.0)  # photons s^-1 m^-2 nm^-1
    electrons_irr = np.sum(0.5 * (photons * exp.pixel.quantum_efficiency())[1:] + 0.5 * (photons * exp.pixel.quantum_efficiency())[:-1])
    radiance = rho * electrons_irr / math.pi                                    # Lambertian
    sensor_irr = radiance * math.pi * 0.8 / (4 * 2.0 ** 2)                      # camera equation
    electrons = sensor_irr * (10e-6) ** 2 * exp.pixel.fill_factor * 50e-6
    assert exp.white_surface_y(lux, "D65", reflectance=rho) == pytest.approx(electrons / 500.0, rel=1e-9)


def test_cos4_falloff_map():
    opt = Optics(cos4_falloff=True)
    m = opt.falloff(25, 40, x_fov_deg=60.0)
    assert m.max() < 1.0 and m.max() > 0.99                     # centre pixels
    corner_tan2 = (math.tan(math.radians(30)) * 39 / 40) ** 2 + (math.tan(math.radians(30)) * 25 / 40 * 24 / 25) ** 2
    assert m[0, 0] == pytest.approx(1 / (1 + corner_tan2) ** 2, rel=1e-5)
    assert np.all(Optics().falloff(25, 40, 60.0) == 1.0)


def test_rectangle_illuminance_matches_the_form_factor_formula():
    """Illuminance on the axis of a w x l Lambertian rectangle at distance h, per unit luminance:
    4 corner form factors (Howell's catalogue, C-11): E = L * pi * F."""
    w, l, h = 1.2, 0.6, 2.0
    em = parse_emitter(__import__("pathlib").Path("t.json"), "e",
                       {"id": "p", "type": "rectangle", "spectrum": "D65", "position": [0, 0, h],
                        "target": [0, 0, 0], "up": [0, 1, 0], "size": [w, l], "power": {"luminance_cd_m2": 1.0}})

    def corner(a: float, b: float) -> float:
        x, y = a / h, b / h
        return (x / math.sqrt(1 + x * x) * math.atan(y / math.sqrt(1 + x * x))
                + y / math.sqrt(1 + y * y) * math.atan(x / math.sqrt(1 + y * y))) / (2 * math.pi)

    expected = math.pi * 4 * corner(w / 2, l / 2)
    got = _rectangle_geometry(em, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert got == pytest.approx(expected, rel=1e-4)
    # one-sided: nothing reaches a point behind the emitter
    assert _rectangle_geometry(em, np.array([0, 0, 3.0]), np.array([0.0, 0.0, -1.0])) == 0.0


@pytest.mark.parametrize("variant", ["mono", "spectral"])
def test_uniformly_lit_plane_renders_the_analytic_y(make_scene, variant):
    """A directional light (uniform irradiance) on a grey Lambertian plane: every pixel has the
    analytic y; mono exactly (no Monte Carlo variance), spectral within its wavelength noise."""
    from spikesim.render import SceneRenderer

    rho, lux = 0.5, 100.0
    xml = make_scene(PLANE.format(reflectance=rho))
    r = SceneRenderer(xml, variant=variant, spp=16)
    y = r.render_step(0)
    expected = r.exposure.white_surface_y(lux, "D65", reflectance=rho)
    assert y.shape == (25, 40)
    if variant == "mono":
        np.testing.assert_allclose(y, expected, rtol=1e-4)
    else:
        assert y.mean() == pytest.approx(expected, rel=0.01)
        assert np.abs(y / expected - 1).max() < 0.1


def test_cos4_falloff_in_render(make_scene):
    from spikesim.render import SceneRenderer

    xml = make_scene(PLANE.format(reflectance=0.5), fov=60)
    r = SceneRenderer(xml, spp=4, optics=Optics(cos4_falloff=True))
    y = r.render_step(0)
    expected = r.exposure.white_surface_y(100, "D65", 0.5) * Optics(cos4_falloff=True).falloff(25, 40, 60.0)
    np.testing.assert_allclose(y, expected, rtol=1e-4)


@pytest.mark.parametrize("emitter", [
    {"id": "bulb", "type": "point", "spectrum": "A", "position": [0, 0, 2.0],
     "power": {"illuminance_lux": 40, "at": [0, 0, 0], "normal": [0, 0, 1]}},
    {"id": "spot", "type": "spot", "spectrum": "LED-B3", "position": [0.5, 0, 2.0], "target": [0, 0, 0],
     "cutoff_deg": 40, "beam_deg": 30, "power": {"illuminance_lux": 40, "at": [0, 0, 0], "normal": [0, 0, 1]}},
    {"id": "panel", "type": "rectangle", "spectrum": "FL2", "position": [1.0, 0, 2.0], "target": [1.0, 0, 0],
     "up": [0, 1, 0], "size": [1.2, 0.6], "power": {"illuminance_lux": 40, "at": [0, 0, 0], "normal": [0, 0, 1]}},
    {"id": "sky", "type": "sky", "spectrum": "D65", "power": {"illuminance_lux": 40}},
])
def test_each_emitter_type_delivers_its_stated_illuminance(make_scene, emitter):
    """The centre of the image sees the point where the light file says the illuminance is 40 lx."""
    from spikesim.render import SceneRenderer

    xml = make_scene(PLANE.format(reflectance=1.0), lights={"normal": {"emitters": [emitter]}}, fov=2.0,
                     width=8, height=5)
    r = SceneRenderer(xml, spp=256 if emitter["type"] in ("rectangle", "sky") else 4)
    y = r.render_step(0)
    expected = r.exposure.white_surface_y(40, emitter["spectrum"])
    assert y.mean() == pytest.approx(expected, rel=0.02)
