"""A plain Mitsuba 3 scene lit by its own emitters, in Mitsuba's radiometric units.

The scenes are written the way Mitsuba's documentation writes them (an `<emitter>` inside a
`<shape>`, a `point` with a `position`, a `spot` with a `lookat`, a `constant` environment),
with no lights.json. Expected values are computed here from first principles (Planck's
constant, the CIE V(lambda) table, the pixel's QE), not through the code under test.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from render_testing import BALL, CAMERA, PLANE
from spikesim.render import LightError, SceneError
from spikesim.render import spectra

CBOX = Path(__file__).resolve().parents[1] / "data" / "mitsuba_cbox" / "scene.xml"


def _renderer(xml, **kw):
    from spikesim.render import SceneRenderer
    return SceneRenderer(xml, **kw)


@pytest.fixture
def plain_scene(tmp_path):
    """Write a Mitsuba scene (camera 5 m above a plane, looking down) with these shapes and
    emitters, and no lights.json; return its path."""

    def make(body: str, fov: float = 2.0, width: int = 8, height: int = 5, name: str = "plain") -> Path:
        folder = tmp_path / name
        folder.mkdir(exist_ok=True)
        xml = ('<scene version="3.0.0">\n  <integrator type="direct"/>'
               + CAMERA.format(fov=fov, origin="0, 0, 5", target="0, 0, 0", width=width, height=height)
               + body + "\n</scene>\n")
        (folder / "scene.xml").write_text(xml)
        return folder / "scene.xml"

    return make


def _white_y(r, electrons_per_s_per_m2: float) -> float:
    """y of a white Lambertian surface receiving this electron-weighted irradiance:
    L_q = E_q / pi, then the exposure chain (docs/scenes.md section 4)."""
    return electrons_per_s_per_m2 / math.pi * r.exposure.y_per_radiance


def _equal_energy_integrals(pixel) -> tuple[float, float]:
    """For 1 W nm^-1 (per sr, per m^2...) at every wavelength of 360-830 nm: the photometric
    quantity K_m integral V and the electron rate integral QE lambda / (h c), by hand."""
    from colour.colorimetry import SDS_LEFS_PHOTOPIC

    wl = np.arange(360.0, 831.0)
    v = SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    v = np.interp(wl, v.wavelengths, v.values, left=0, right=0)
    photons_per_joule = wl * 1e-9 / (6.62607015e-34 * 299792458.0)
    qe = pixel.quantum_efficiency(wl)
    return 683.002 * np.trapezoid(v, wl), float(np.trapezoid(qe * photons_per_joule, wl))


# ---- point: the inverse-square law through the exposure model ------------------------------------
@pytest.mark.parametrize("variant", ["mono", "spectral"])
def test_point_light_gives_the_inverse_square_law_in_y(plain_scene, variant):
    """A point light of spectral intensity c W sr^-1 nm^-1 (equal energy) at (1, 0, 2) over a white
    plane: the centre sees E = I cos(theta) / d^2, in lux and in y."""
    c = 2e-4
    xml = plain_scene(PLANE.format(reflectance=1.0) + f"""
  <emitter type="point">
    <point name="position" value="1.0, 0.0, 2.0"/>
    <spectrum name="intensity" value="{c}"/>
  </emitter>""")
    r = _renderer(xml, variant=variant, spp=4)
    lum_per_w, electrons_per_j = _equal_energy_integrals(r.exposure.pixel)
    geometry = (2.0 / math.sqrt(5.0)) / 5.0  # cos(theta) / d^2
    assert r.lighting.emitters[0].photometric == pytest.approx(c * lum_per_w, rel=2e-3)
    assert r.lighting.subject_illuminance_lux() == pytest.approx(c * lum_per_w * geometry, rel=2e-3)
    assert r.lighting.subject_from == "view centre"
    np.testing.assert_allclose(r.lighting.subject[0], [0, 0, 0], atol=1e-6)
    y = r.render_step(0)
    expected = _white_y(r, c * electrons_per_j * geometry)
    assert y.mean() == pytest.approx(expected, rel=0.005 if variant == "mono" else 0.02)


def test_rgb_white_is_mitsubas_d65_at_its_luminance(plain_scene):
    """<rgb value="1"/> means what Mitsuba's spectral variants make of it: D65 whose CIE Y
    (integral I ybar / integral ybar) is 1 W sr^-1 nm^-1, i.e. 683.002 x 106.857 cd."""
    xml = plain_scene(PLANE.format(reflectance=1.0) + """
  <emitter type="point"><point name="position" value="0, 0, 2"/><rgb name="intensity" value="1"/></emitter>""")
    r = _renderer(xml, spp=1)
    em = r.lighting.emitters[0]
    assert em.photometric == pytest.approx(683.002 * 106.857, rel=0.005)
    pixel = r.exposure.pixel
    assert pixel.electrons_per_lumen_second(em.spectrum) == pytest.approx(pixel.electrons_per_lumen_second("D65"), rel=0.01)


def test_blackbody_intensity_is_plancks_law(plain_scene):
    """<spectrum type="blackbody"> is Planck's spectral radiance per nm: its luminous quantity
    is K_m integral B(lambda, T) V dlambda, computed here from Planck's law."""
    xml = plain_scene(PLANE.format(reflectance=1.0) + """
  <emitter type="point"><point name="position" value="0, 0, 2"/>
    <spectrum name="intensity" type="blackbody"><float name="temperature" value="2856"/></spectrum></emitter>""")
    r = _renderer(xml, spp=1)
    from colour.colorimetry import SDS_LEFS_PHOTOPIC
    wl = np.arange(360.0, 831.0)
    lam = wl * 1e-9
    h, c, k = 6.62607015e-34, 299792458.0, 1.380649e-23
    planck = 2 * h * c ** 2 / lam ** 5 / np.expm1(h * c / (lam * k * 2856.0)) * 1e-9  # W m^-2 sr^-1 nm^-1
    v = SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    v = np.interp(wl, v.wavelengths, v.values, left=0, right=0)
    assert r.lighting.emitters[0].photometric == pytest.approx(683.002 * np.trapezoid(planck * v, wl), rel=0.01)
    # a blackbody at 2856 K has CIE illuminant A's shape
    pixel = r.exposure.pixel
    assert pixel.electrons_per_lumen_second(r.lighting.emitters[0].spectrum) == pytest.approx(
        pixel.electrons_per_lumen_second("A"), rel=0.01)


# ---- area lights: linearity and the form factor -----------------------------------------------------
_PANEL = """
  <shape type="rectangle" id="panel">
    <transform name="to_world"><scale x="0.6" y="0.3"/><rotate x="1" angle="180"/><translate x="1" z="2"/></transform>
    <emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter>
  </shape>"""


def test_area_light_illuminance_is_the_form_factor_and_doubling_radiance_doubles_y(plain_scene):
    from spikesim.render.lights import EmitterSpec, _rectangle_geometry

    xml1 = plain_scene(PLANE.format(reflectance=1.0) + _PANEL.format(radiance="0.001, 0.002, 0.001"), name="one")
    xml2 = plain_scene(PLANE.format(reflectance=1.0) + _PANEL.format(radiance="0.002, 0.004, 0.002"), name="two")
    r1, r2 = _renderer(xml1, spp=64, seed=3), _renderer(xml2, spp=64, seed=3)
    em = r1.lighting.emitters[0]
    assert em.id == "panel" and em.type == "area" and em.area_m2 == pytest.approx(1.2 * 0.6)
    # the sampled integral against the rectangle code of the light files (a 1.2 x 0.6 m panel facing down)
    rect = EmitterSpec(id="p", type="rectangle", spectrum="D65", power={}, photometric=1.0, position=(1.0, 0, 2.0),
                       target=(1.0, 0, 0), up=(0, 1, 0), size=(1.2, 0.6))
    per_unit = _rectangle_geometry(rect, np.zeros(3), np.array([0, 0, 1.0]))
    assert r1.lighting.subject_illuminance_lux() == pytest.approx(em.photometric * per_unit, rel=1e-3)
    assert em.luminous_flux_lm() == pytest.approx(math.pi * em.photometric * 0.72, rel=1e-6)
    assert r2.lighting.emitters[0].photometric == pytest.approx(2 * em.photometric, rel=1e-6)
    y1, y2 = r1.render_step(0), r2.render_step(0)
    np.testing.assert_allclose(y2, 2 * y1, rtol=1e-5)  # same samples: linear in the radiance
    expected = r1.exposure.white_surface_y(r1.lighting.subject_illuminance_lux(), em.spectrum)
    assert y1.mean() == pytest.approx(expected, rel=0.03)


def test_sphere_area_light_illuminance_matches_the_analytic_value(plain_scene):
    """A Lambertian sphere of radius a and luminance L lights a facing point at distance d from
    its centre with E = pi L a^2 / d^2."""
    xml = plain_scene(PLANE.format(reflectance=1.0) + """
  <shape type="sphere" id="globe"><point name="center" value="0, 0.5, 1.5"/><float name="radius" value="0.2"/>
    <emitter type="area"><spectrum name="radiance" value="1e-3"/></emitter></shape>""")
    r = _renderer(xml, spp=1)
    em = r.lighting.emitters[0]
    d = math.sqrt(0.5 ** 2 + 1.5 ** 2)
    e_normal = em.illuminance_at((0, 0, 0), (0, 0.5 / d, 1.5 / d))
    assert e_normal == pytest.approx(math.pi * em.photometric * 0.04 / d ** 2, rel=3e-3)


def test_spot_and_constant_emitters(plain_scene):
    """A spot's beam gives I / d^2 on its axis and nothing outside its cutoff; a constant
    environment gives E = pi L on the plane."""
    spot = plain_scene(PLANE.format(reflectance=1.0) + """
  <emitter type="spot" id="torch">
    <transform name="to_world"><lookat origin="0, 0, 2" target="0, 0, 0" up="0, 1, 0"/></transform>
    <float name="cutoff_angle" value="30"/>
    <rgb name="intensity" value="0.002"/>
  </emitter>""", name="spot")
    r = _renderer(spot, spp=4)
    em = r.lighting.emitters[0]
    assert (em.type, em.cutoff_deg, em.beam_deg) == ("spot", 30.0, 22.5)
    assert r.lighting.subject_illuminance_lux() == pytest.approx(em.photometric / 4, rel=1e-9)
    assert em.illuminance_at((2.0, 0, 0), (0, 0, 1)) == 0.0  # 45 deg off axis: outside the cutoff
    assert r.render_step(0).mean() == pytest.approx(r.exposure.white_surface_y(em.photometric / 4, em.spectrum), rel=0.005)

    sky = plain_scene(PLANE.format(reflectance=1.0) + """
  <emitter type="constant"><rgb name="radiance" value="1e-4"/></emitter>""", name="sky")
    r = _renderer(sky, spp=256)
    em = r.lighting.emitters[0]
    assert em.type == "sky" and r.lighting.subject_illuminance_lux() == pytest.approx(math.pi * em.photometric)
    assert r.render_step(0).mean() == pytest.approx(r.exposure.white_surface_y(math.pi * em.photometric, em.spectrum),
                                                    rel=0.03)


def test_the_cornell_box_as_mitsuba_writes_it_renders_with_its_own_light():
    r = _renderer(CBOX, spp=2, resolution=(16, 16))
    assert r.files.lights is None and [e.id for e in r.lighting.emitters] == ["light"]
    assert r.variant == "mono"  # one emitter, one spectrum
    meta = r.describe()
    subject = meta["light"]["subject"]
    assert subject["from"] == "view centre" and subject["direct_illuminance_lux"] > 0
    assert meta["light"]["emitters"][0]["xml"].startswith("<rgb")
    y = r.render_step(0)
    assert np.all(np.isfinite(y)) and y.mean() > 0
    json.dumps(meta)  # JSON-ready


# ---- a light file overrides the scene's emitters --------------------------------------------------
_LAMP = """
  <emitter type="point" id="lamp"><point name="position" value="0, 0, 2"/><rgb name="intensity" value="0.01"/></emitter>"""
_SIDE = """
  <emitter type="point" id="side"><point name="position" value="1, 0, 1"/><rgb name="intensity" value="0.05"/></emitter>"""


def test_light_file_conditions_replace_the_scene_emitters(plain_scene):
    xml = plain_scene(PLANE.format(reflectance=1.0) + _LAMP + _SIDE)
    own = _renderer(xml, spp=1)
    assert sorted(e.id for e in own.lighting.emitters) == ["lamp", "side"]
    lamp_spectrum = next(e.spectrum for e in own.lighting.emitters if e.id == "lamp")
    (xml.parent / "lights.json").write_text(json.dumps({
        "normal": {"emitters": [{"id": "lamp"}]},  # the XML's lamp as it is; 'side' off
        "low": {"emitters": [{"id": "lamp", "power": {"illuminance_lux": 5, "at": [0, 0, 0], "normal": [0, 0, 1]}}]},
        "sky": {"emitters": [{"id": "sky", "type": "sky", "spectrum": "D65", "power": {"illuminance_lux": 40}}]},
    }))
    normal = _renderer(xml, spp=4, seed=1)
    assert [e.id for e in normal.lighting.emitters] == ["lamp"]
    lamp_lux = normal.lighting.subject_illuminance_lux()
    assert lamp_lux == pytest.approx(own.lighting.emitters[0].photometric / 4)
    assert normal.render_step(0).mean() == pytest.approx(normal.exposure.white_surface_y(lamp_lux, lamp_spectrum), rel=0.005)

    low = _renderer(xml, light="low", spp=4, seed=1)
    assert low.lighting.subject_illuminance_lux() == pytest.approx(5.0)
    assert low.lighting.emitters[0].spectrum == lamp_spectrum  # the power changes, not the colour
    assert low.render_step(0).mean() == pytest.approx(low.exposure.white_surface_y(5.0, lamp_spectrum), rel=0.005)

    sky = _renderer(xml, light="sky", spp=256, seed=1)
    assert [e.id for e in sky.lighting.emitters] == ["sky"]  # both XML lamps off
    assert sky.render_step(0).mean() == pytest.approx(sky.exposure.white_surface_y(40.0, "D65"), rel=0.03)


def test_light_file_reference_errors(plain_scene):
    xml = plain_scene(PLANE.format(reflectance=1.0) + _LAMP)
    lights = xml.parent / "lights.json"
    lights.write_text(json.dumps({"normal": {"emitters": [{"id": "lampp"}]}}))
    with pytest.raises(LightError, match=r"no emitter with id 'lampp' \(its emitters: \['lamp'\]\)") as info:
        _renderer(xml)
    assert str(info.value).startswith(str(lights))
    lights.write_text(json.dumps({"normal": {"emitters": [{"id": "lamp", "position": [0, 0, 1]}]}}))
    with pytest.raises(LightError, match=r"unknown key\(s\) \['position'\].*only 'power' can be set"):
        _renderer(xml)
    lights.write_text(json.dumps({"normal": {"emitters": [{"id": "lamp", "power": {"luminance_cd_m2": 5}}]}}))
    with pytest.raises(LightError, match="luminance_cd_m2 is not defined for a point emitter"):
        _renderer(xml)


# ---- what is refused ----------------------------------------------------------------------------------
def test_neither_emitters_nor_light_file_is_refused_naming_both(plain_scene):
    xml = plain_scene(PLANE.format(reflectance=1.0))
    with pytest.raises(SceneError, match="has no <emitter> and there is no light file") as info:
        _renderer(xml)
    assert str(info.value).startswith(str(xml)) and str(xml.parent / "lights.json") in str(info.value)


def test_other_condition_without_a_light_file(plain_scene):
    xml = plain_scene(PLANE.format(reflectance=1.0) + _LAMP)
    with pytest.raises(LightError, match="has no lighting 'low': without a lights.json") as info:
        _renderer(xml, light="low")
    assert str(info.value).startswith(str(xml))


@pytest.mark.parametrize("emitter, message", [
    ('<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>', "only area, point, spot, constant"),
    ('<shape type="rectangle"><emitter type="area"><texture type="checkerboard" name="radiance"/></emitter></shape>',
     "a textured emitter is not supported"),
    ('<emitter type="point"><spectrum name="intensity" value="0"/></emitter>', "emits no visible light"),
    ('<emitter type="point"><spectrum name="intensity" value="-1"/></emitter>', "must be finite and non-negative"),
    ('<emitter type="point"><rgb name="intensity" value="0"/></emitter>', "Mitsuba cannot read its intensity.*no probability mass"),
    ('<emitter type="point" id="a"/><emitter type="spot" id="a"/>', r"emitter id\(s\) \['a'\] are used twice"),
    ('<emitter type="point"><spectrum name="intensity" value="banana"/></emitter>', "Mitsuba cannot read its intensity"),
])
def test_bad_scene_emitters(plain_scene, tmp_path, emitter, message):
    if "sky.exr" in emitter:
        (tmp_path / "plain").mkdir(exist_ok=True)
        (tmp_path / "plain" / "sky.exr").write_bytes(b"")
    xml = plain_scene(PLANE.format(reflectance=1.0) + emitter)
    with pytest.raises(SceneError, match=message) as info:
        _renderer(xml)
    assert str(info.value).startswith(str(xml))


# ---- motion with the scene's own light ----------------------------------------------------------------
def test_motion_file_moves_objects_under_the_scene_emitters(plain_scene):
    xml = plain_scene(BALL + """
  <emitter type="point"><point name="position" value="0, 0, 3"/><rgb name="intensity" value="1e-3"/></emitter>""",
                      fov=30.0, width=40, height=25)
    (xml.parent / "motion.json").write_text(json.dumps({"version": 1, "objects": [
        {"targets": ["ball"], "motions": [{"type": "translation", "velocity_mps": [1000, 0, 0]}]}]}))
    r = _renderer(xml, spp=4, substeps=1)
    assert r.files.motion is not None

    def centroid_x(y):
        w = y.sum(axis=0)
        return float((w * np.arange(y.shape[1])).sum() / w.sum())

    x0, x1 = centroid_x(r.render_step(0)), centroid_x(r.render_step(20))
    # 20 steps x 25 us x 1 km/s = 0.5 m, 7.5 px at this field of view
    assert x1 - x0 == pytest.approx(7.5, abs=1.0)


def test_directional_emitter_gives_its_irradiance(plain_scene):
    """A directional light of c W m^-2 nm^-1 along -z: E_v = K_m c integral V on the plane."""
    c = 1e-4
    xml = plain_scene(PLANE.format(reflectance=1.0) + f"""
  <emitter type="directional"><vector name="direction" value="0, 0, -1"/>
    <spectrum name="irradiance" value="{c}"/></emitter>""")
    r = _renderer(xml, spp=1)
    lum_per_w, electrons_per_j = _equal_energy_integrals(r.exposure.pixel)
    em = r.lighting.emitters[0]
    assert em.type == "directional" and np.allclose(em.direction, [0, 0, -1])
    assert r.lighting.subject_illuminance_lux() == pytest.approx(c * lum_per_w, rel=2e-3)
    assert r.render_step(0).mean() == pytest.approx(_white_y(r, c * electrons_per_j), rel=0.005)


def test_area_emitter_on_a_mesh_matches_the_same_rectangle(plain_scene):
    """An area light on an OBJ quad (two triangles) gives the illuminance of the same rectangle."""
    xml = plain_scene(PLANE.format(reflectance=1.0) + """
  <shape type="obj" id="quad"><string name="filename" value="quad.obj"/>
    <emitter type="area"><rgb name="radiance" value="0.001"/></emitter></shape>""" + _PANEL.format(radiance="0.001"))
    # the panel of _PANEL: 1.2 x 0.6 m centred at (1, 0, 2), facing down (counter-clockwise seen from below)
    (xml.parent / "quad.obj").write_text("v 0.4 -0.3 2\nv 1.6 -0.3 2\nv 1.6 0.3 2\nv 0.4 0.3 2\nf 1 4 3\nf 1 3 2\n")
    r = _renderer(xml, spp=1)
    quad, panel = r.lighting.emitters
    assert quad.area_m2 == pytest.approx(0.72, rel=1e-6)
    for at, normal in (((0, 0, 0), (0, 0, 1)), ((1, 0.2, 1), (0, 0, 1)), ((-1, 0, 1.5), (1, 0, 0))):
        assert quad.illuminance_at(at, normal) == pytest.approx(panel.illuminance_at(at, normal), rel=2e-3)


def test_command_line_names_the_scene_with_no_light_at_all(plain_scene, capsys):
    from cli_testing import one_line, run_cli

    xml = plain_scene(PLANE.format(reflectance=1.0))
    rc, err = run_cli(["render", xml, "--steps", "0"], capsys)
    assert rc == 2
    assert one_line(err).endswith(f"{xml}: has no <emitter> and there is no light file {xml.parent / 'lights.json'}: "
                                  "add an area, point, spot, constant or directional emitter (Mitsuba's units) or a "
                                  "lights.json (docs/scenes.md section 2)")


def test_the_readmes_plain_scene_renders_to_the_inverse_square_law() -> None:
    """tests/data/plain_scene (the README's first job): a flat 0.001 W/sr/nm point lamp 1 m above a
    0.5 grey floor gives E = K_m integral(V) 0.001 / 1^2 lux there, and y through the exposure model."""
    from spikesim.render import SceneRenderer

    plain = Path(__file__).resolve().parents[1] / "data" / "plain_scene" / "scene.xml"
    r = SceneRenderer(plain, spp=4)
    lux = spectra.K_M * spectra.integrate(spectra.photopic_v()) * 0.001
    # Mitsuba tabulates the integral of y-bar as 106.857 nm, ours of V is 0.1 % larger
    assert r.lighting.subject_illuminance_lux() == pytest.approx(lux, rel=3e-3)
    assert (r.height, r.width) == (25, 40)  # the scene's own film
    y = next(iter(r.frames(0, 1)))
    centre = float(y[11:13, 19:21].mean())
    assert centre == pytest.approx(r.exposure.white_surface_y(lux, "D65", 0.5), rel=0.01)
