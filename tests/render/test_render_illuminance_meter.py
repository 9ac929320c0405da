"""The metered illuminance at the subject (spikesim/render/illuminance_meter.py): it equals the
inverse-square law where there is nothing but a lamp and a plane, it counts bounced light where the
direct light is shadowed, and it finds the surface a nominal subject point lies under.

Every comparison allows 4 standard errors of the meter (its own spread over independent renders)
plus 1 % for the disk's offset and Mitsuba's float32 geometry."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from render_testing import PLANE
from spikesim.render import SceneRenderer
from spikesim.render.illuminance_meter import PhotopicResponse, meter_illuminance
from spikesim.render.renderer import SUBJECT_DIRECT, SUBJECT_METERED
from spikesim.render import spectra

LAMP = {"id": "lamp", "type": "point", "spectrum": "A", "position": [0.3, 0.0, 2.0], "power": {"intensity_cd": 40.0}}


def _close(measured: float, se: float, expected: float) -> bool:
    return abs(measured - expected) <= 4 * se + 0.01 * expected


def test_photopic_response_reads_lumens():
    """A light of 1 lm per unit gives 1 unit per second: the meter's scene is in lux."""
    for name in ("A", "D65", "FL2"):
        assert PhotopicResponse().electrons_per_lumen_second(name) == pytest.approx(1.0, rel=1e-3)
    assert spectra.K_M == pytest.approx(683.002)


def test_open_plane_reads_the_inverse_square_law(make_scene):
    """A point lamp over a grey plane seen from above: nothing reflects onto the plane, so the
    metered total and direct illuminance both equal I cos(theta) / d^2 at the view centre."""
    xml = make_scene(PLANE.format(reflectance=0.5), lights={"normal": {"emitters": [LAMP]}}, integrator="path")
    r = SceneRenderer(xml, variant="mono", spp=1, resolution=(5, 8))
    assert r.lighting.subject_from == "view centre"
    d2 = 0.3 ** 2 + 2.0 ** 2
    expected = 40.0 * (2.0 / math.sqrt(d2)) / d2
    assert r.lighting.subject_illuminance_lux() == pytest.approx(expected, rel=1e-4)
    m = r.metered_illuminance()
    assert _close(m.total_lux, m.total_se_lux, expected), m
    assert _close(m.direct_lux, m.direct_se_lux, expected), m
    lux, kind = r.subject_illuminance()
    assert kind == SUBJECT_METERED and lux == m.total_lux
    subject = r.describe()["light"]["subject"]
    assert subject["illuminance_lux"] == m.total_lux and subject["illuminance"] == SUBJECT_METERED
    assert subject["total_illuminance_se_lux"] == m.total_se_lux


def test_light_power_factor_scales_the_meter(make_scene):
    xml = make_scene(PLANE.format(reflectance=0.5), lights={"normal": {"emitters": [LAMP]}}, integrator="path")
    one = SceneRenderer(xml, variant="mono", spp=1, resolution=(5, 8)).metered_illuminance()
    tenth = SceneRenderer(xml, variant="mono", spp=1, resolution=(5, 8), light_power_factor=0.1).metered_illuminance()
    assert tenth.total_lux == pytest.approx(0.1 * one.total_lux, rel=1e-4)  # same seeds: the same samples, summed in any order


#: A plain scene (its own emitter): a ball's front under a lamp straight above it, in a corner whose
#: floor and wall reflect. The view centre gets no direct light at all.
BOUNCE = Path(__file__).resolve().parents[1] / "data" / "bounce_scene" / "scene.xml"


def test_bounced_light_only_is_metered_not_zero():
    """The issue's scene: the analytic figure and the metered direct light are 0 (the lamp is
    behind the surface's horizon), while the bounced light is not."""
    r = SceneRenderer(BOUNCE, variant="mono", spp=1, resolution=(5, 8))
    at, normal = map(np.asarray, r.lighting.subject)
    assert normal[2] > 0.99 and r.lighting.subject_illuminance_lux() == 0.0
    m = r.metered_illuminance()
    assert m.direct_lux == 0.0
    assert m.total_lux > 10 * m.total_se_lux > 0  # floor and wall light the front, well above the meter's noise
    assert r.subject_illuminance() == (m.total_lux, SUBJECT_METERED)


def test_a_light_files_subject_keeps_its_computed_figure_and_is_not_metered(make_scene):
    """A light file's subject is a nominal point (here 5 mm inside a table top, as the LLR files put
    theirs): a meter there reads nothing, so the scene keeps the figure its powers are stated by."""
    slab = """
  <shape type="cube" id="table"><transform name="to_world"><scale x="1" y="1" z="0.01"/><translate z="-0.01"/>
    </transform><bsdf type="diffuse"><spectrum name="reflectance" value="0.5"/></bsdf></shape>"""
    lamp = {**LAMP, "position": [0.0, 0.0, 2.0]}
    lights = {"normal": {"emitters": [lamp], "subject": {"at": [0.0, 0.0, -0.005], "normal": [0, 0, 1]}}}
    xml = make_scene(slab, lights=lights, integrator="path")
    r = SceneRenderer(xml, variant="mono", spp=1, resolution=(5, 8))
    assert meter_illuminance(xml, r.lighting, [0.0, 0.0, -0.005], [0, 0, 1]).total_lux == 0.0  # inside the slab
    assert r.subject_illuminance() == (pytest.approx(40.0 / 2.005 ** 2), SUBJECT_DIRECT)
    subject = r.describe()["light"]["subject"]
    assert subject["illuminance"] == SUBJECT_DIRECT and "total_illuminance_lux" not in subject


def test_a_view_centre_on_a_lamp_is_no_subject(make_scene):
    """The camera looks straight at an area light: the light on the lamp's own face means nothing (it
    recorded 0 lx while the frame saturated), so there is no subject to meter."""
    panel = """
  <shape type="rectangle" id="panel"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"""
    xml = make_scene(panel, lights={"normal": {"emitters": [{"id": "panel"}]}})
    r = SceneRenderer(xml, variant="mono", spp=1, resolution=(5, 8))
    assert r.lighting.subject is None and r.subject_illuminance() == (None, "none")


def test_area_lamp_matches_its_form_factor(make_scene):
    """A rectangle lamp (hit by rays as well as sampled): the metered direct light equals the
    lighting's numerical form factor."""
    rect = {"id": "panel", "type": "rectangle", "spectrum": "D65", "position": [0.8, 0.0, 1.0], "target": [0.8, 0.0, 0.0],
            "size": [0.6, 0.4], "power": {"luminance_cd_m2": 500.0}}
    xml = make_scene(PLANE.format(reflectance=0.0), lights={"normal": {"emitters": [rect]}}, integrator="path")
    r = SceneRenderer(xml, variant="mono", spp=1, resolution=(5, 8))
    expected = r.lighting.subject_illuminance_lux()
    assert expected > 0
    m = r.metered_illuminance()
    assert _close(m.direct_lux, m.direct_se_lux, expected), (m, expected)


def test_meter_refuses_a_bad_subject(make_scene):
    xml = make_scene(PLANE.format(reflectance=0.5), lights={"normal": {"emitters": [LAMP]}})
    r = SceneRenderer(xml, variant="mono", spp=1, resolution=(5, 8))
    with pytest.raises(ValueError, match="non-zero normal"):
        meter_illuminance(xml, r.lighting, [0, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match="at least one"):
        meter_illuminance(xml, r.lighting, [0, 0, 0], [0, 0, 1], samples=0)
