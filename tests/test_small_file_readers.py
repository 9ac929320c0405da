"""Bad inputs, round two: every small file the tools read (a stream's sidecar, a dataset's
meta.json, camera, config, light and motion files) is read only when it is a small regular file
and its fields have the right types and ranges; a --header-columns against the recorded geometry,
a camera file's absurd numbers, a scene's unreadable mesh or overflowing emitter and a --gt image
of the wrong kind are refused, each with one line naming the file and what is wrong."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from cli_testing import one_line, run_cli
from spikesim.config_io import read_config_file, read_json_object
from spikesim.stream import SpikeStream, write_dat, write_sidecar

H, W, N = 6, 16, 4
pytestmark = pytest.mark.timeout(60)  # a FIFO read that blocks fails the test instead of hanging it


def small_stream(tmp_path: Path, record: dict | None = None, dataset: bool = False) -> Path:
    """A 6 x 16 top-down stream of 4 frames and its record (a sidecar, or a dataset's meta.json)."""
    frames = np.random.default_rng(0).random((N, H, W)) < 0.3
    if dataset:
        folder = tmp_path / "ds" / "scene_normal"
        folder.mkdir(parents=True)
        path = write_dat(folder / "spikes.dat", SpikeStream.from_bool(frames), flip=False)
        (folder / "meta.json").write_text(json.dumps(record if record is not None else
                                                     {"height": H, "width": W, "flip": False, "num_steps": N}))
        return path
    path = write_dat(tmp_path / "s.dat", SpikeStream.from_bool(frames), flip=False)
    # written as a hand-edited record would be (json's Infinity included): write_sidecar writes standard JSON
    Path(f"{path}.json").write_text(json.dumps(record if record is not None else {"height": H, "width": W,
                                                                                  "flip": False}))
    return path


# ---- a sidecar's or meta.json's fields ----------------------------------------------------------
BAD_FIELDS = [
    ("readout_period_s", {"readout_period_s": -5}),
    ("camera.readout_period_s", {"camera": {"readout_period_s": -5}}),
    ("camera.readout_period_s", {"camera": {"readout_period_s": float("inf")}}),
    ("camera", {"camera": [1, 2]}),
    ("height", {"height": True}),
    ("height", {"height": 1_000_000}),
    ("height", {"height": 6.5}),
    ("width", {"width": "16"}),
    ("width", {"width": 0}),
    ("flip", {"flip": "no"}),
    ("flip", {"flip": 0}),
    ("header_columns", {"header_columns": -1}),
    ("header_columns", {"header_columns": True}),
    ("num_steps", {"num_steps": -3}),
    ("gt_steps", {"gt_steps": None}),   # was a TypeError traceback in evaluate and train
    ("gt_steps", {"gt_steps": "20"}),   # was "no ground-truth step is the centre ..."
    ("gt_steps", {"gt_steps": [1.5]}),
    ("gt_steps", {"gt_steps": [N]}),    # past the stream's last step
    ("gt_steps", {"gt_steps": [1, 1]}),
]


@pytest.mark.parametrize("dataset", [False, True], ids=["sidecar", "meta.json"])
@pytest.mark.parametrize("field, change", BAD_FIELDS, ids=[f"{f}={list(c.values())[0]!r}" for f, c in BAD_FIELDS])
def test_a_record_field_of_the_wrong_type_or_range_is_one_line_naming_it(tmp_path, capsys, field, change, dataset):
    record = {"height": H, "width": W, "flip": False, "num_steps": N, **change}
    path = small_stream(tmp_path, record, dataset)
    code, err = run_cli(["inspect", path, "--json"], capsys)
    line = one_line(err)
    source = "meta.json" if dataset else "s.dat.json"
    assert code == 2 and source in line and field in line, line


def test_a_good_record_still_reads(tmp_path, capsys):
    """Fields no reader uses are not judged: a record the tools wrote may hold an infinite
    measurement (json writes it as Infinity)."""
    path = small_stream(tmp_path, {"height": H, "width": W, "flip": False, "camera": {"readout_period_s": 5e-5},
                                   "irradiance": {"luminous_flux_lm": float("inf")}})
    code, err = run_cli(["inspect", path, "--json"], capsys)
    assert code == 0, err


def test_a_dataset_scene_record_is_checked_when_opened(tmp_path):
    from spikesim.dataset import SceneRecord
    path = small_stream(tmp_path, {"height": H, "width": W, "flip": "no", "num_steps": N, "gt_steps": []},
                        dataset=True)
    with pytest.raises(ValueError, match="meta.json: flip must be true or false"):
        SceneRecord.open(path.parent)


# ---- small files that are not small regular files ------------------------------------------------
def plant(path: Path, kind: str, limit: int = 1 << 20) -> None:
    """Put a FIFO, a link to /dev/zero, a file over `limit` bytes (1 MiB, a small file's limit) or
    a directory at `path`."""
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dev-zero":
        path.symlink_to("/dev/zero")
    elif kind == "large":
        path.write_bytes(b"{" + b" " * limit + b"}")
    else:
        path.mkdir()


WHAT = {"fifo": "FIFO", "dev-zero": "character device", "large": "larger than", "dir": "directory"}


@pytest.mark.parametrize("kind", list(WHAT))
def test_a_sidecar_that_is_not_a_small_regular_file_is_refused(tmp_path, capsys, kind):
    path = write_dat(tmp_path / "s.dat", SpikeStream.from_bool(np.zeros((N, H, W), bool)))
    plant(tmp_path / "s.dat.json", kind)
    code, err = run_cli(["inspect", path], capsys)
    line = one_line(err)
    assert code == 2 and "s.dat.json" in line and WHAT[kind] in line, line


@pytest.mark.parametrize("kind", list(WHAT))
def test_a_planted_meta_json_is_refused(tmp_path, capsys, kind):
    path = small_stream(tmp_path, dataset=True)
    (path.parent / "meta.json").unlink()
    plant(path.parent / "meta.json", kind, limit=16 << 20)  # a meta.json lists every ground-truth step
    code, err = run_cli(["inspect", path], capsys)
    line = one_line(err)
    assert code == 2 and "meta.json" in line and WHAT[kind] in line, line


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "large"])
def test_every_small_file_reader_refuses_what_is_not_a_small_regular_file(tmp_path, kind):
    from model.config import load_config
    from spikesim.camera import SpikeCamera
    from spikesim.golden import load_reference
    from spikesim.render.errors import LightError, read_json
    from spikesim.render_settings import RenderSettings

    readers = [
        ("c.json", read_config_file, ValueError),
        ("c.toml", read_config_file, ValueError),
        ("cam.json", SpikeCamera.from_file, ValueError),
        ("settings.json", RenderSettings.from_file, ValueError),
        ("cfg.json", load_config, ValueError),
        ("ref.json", load_reference, ValueError),
        ("lights.json", lambda p: read_json(p, LightError, "light file"), LightError),
        ("x.json", lambda p: read_json_object(p, "cache file"), ValueError),
    ]
    for name, read, error in readers:
        path = tmp_path / name
        plant(path, kind)
        with pytest.raises(error, match=WHAT[kind]) as info:
            read(path)
        assert name in str(info.value)


# ---- --header-columns against the record --------------------------------------------------------
@pytest.mark.parametrize("dataset", [False, True], ids=["sidecar", "meta.json"])
@pytest.mark.parametrize("flags", [["--header-columns", 16], ["--header-columns", 8, "--height", H],
                                   ["--header-columns", 16, "--width", W]], ids=["alone", "with-height", "with-width"])
def test_header_columns_that_contradict_the_record_are_refused(tmp_path, capsys, flags, dataset):
    """48 bytes are 4 frames of 6 x 16 or 2 of 6 x 32: read with 16 header columns they were garbage."""
    path = small_stream(tmp_path, dataset=dataset)
    source = "meta.json" if dataset else "s.dat.json"
    for argv in (["inspect", path, *flags], ["panel", path, "-o", tmp_path / "p.png", "--window", 1, "--methods", "tfp", *flags],
                 ["reconstruct", path, "--out", tmp_path / "o", *flags]):
        code, err = run_cli(argv, capsys)
        line = one_line(err)
        assert code == 2 and source in line and "--header-columns" in line, (argv, line)
    assert not (tmp_path / "o").exists() and not (tmp_path / "p.png").exists()


def test_header_columns_that_agree_with_the_record_or_a_whole_geometry_are_read(tmp_path, capsys):
    path = small_stream(tmp_path)
    code, err = run_cli(["inspect", path, "--header-columns", 0], capsys)
    assert code == 0, err
    # the whole geometry given: the user reads the file otherwise on purpose
    code, err = run_cli(["inspect", path, "--header-columns", 16, "--height", H, "--width", W], capsys)
    assert code == 0, err


def test_evaluate_dat_refuses_header_columns_against_the_record(tmp_path, capsys):
    path = small_stream(tmp_path, {"height": H, "width": W, "flip": False})
    np.save(tmp_path / "gt.npy", np.full((H, W), 0.2, np.float32))
    code, err = run_cli(["evaluate", "--dat", path, "--gt", tmp_path / "gt.npy", "--center", 1, "--window", 1,
                         "--methods", "tfp", "--header-columns", 16, "-o", tmp_path / "e"], capsys)
    line = one_line(err)
    assert code == 2 and "s.dat.json" in line and "--header-columns" in line, line


# ---- golden --camera: numbers a camera file may hold ---------------------------------------------
BIG = 10 ** 400
CAMERA_CASES = [
    ("threshold_electrons", '{"threshold_electrons": %d}' % BIG, "json"),
    ("gain_spread", '{"gain_spread": -%d}' % BIG, "json"),
    ("height", '{"height": %d}' % BIG, "json"),
    ("dark_current_hz", "dark_current_hz = %d\n" % BIG, "toml"),
    ("readout_period_s", "readout_period_s = inf\n", "toml"),
    ("gain_spread", '{"gain_spread": NaN}', "json"),
    ("height", '{"height": 1000000}', "json"),
    ("height", '{"height": true}', "json"),
    ("width", '{"width": 400.0}', "json"),
    ("height", '{"height": 1000, "width": 400}', "json"),  # in range, but golden would not use it
]


@pytest.mark.parametrize("field, text, suffix", CAMERA_CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CAMERA_CASES)])
def test_golden_refuses_a_camera_file_number_naming_the_field(tmp_path, capsys, field, text, suffix):
    cam = tmp_path / f"cam.{suffix}"
    cam.write_text(text)
    code, err = run_cli(["golden", "--camera", cam], capsys)
    line = one_line(err)
    assert code == 2 and field in line and len(line) < 400, line


def test_a_camera_refuses_huge_numbers_without_overflowing():
    from spikesim.camera import SpikeCamera
    for field in ("threshold_electrons", "dark_current_hz", "readout_period_s", "height"):
        with pytest.raises(ValueError, match=f"{field} must be .*about 401 digits"):
            SpikeCamera(**{field: BIG})


def test_golden_accepts_a_saved_camera_and_the_test_scenes_size(tmp_path):
    import argparse

    from pipelines.golden_stats import _camera
    from spikesim import golden
    from spikesim.camera import SpikeCamera
    for camera in (SpikeCamera.realistic(), golden.golden_camera()):
        path = tmp_path / "cam.json"
        camera.save(path)
        assert _camera(argparse.Namespace(camera=path)) == camera


# ---- scene inputs --------------------------------------------------------------------------------
SCENE = """<scene version="3.0.0">
  <integrator type="direct"/>
  <sensor type="perspective" id="camera">
    <float name="fov" value="2"/><string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="5"/></film>
  </sensor>
  {body}
</scene>
"""
PLANE = """<shape type="rectangle" id="plane"><transform name="to_world"><scale value="50"/></transform>
    <bsdf type="diffuse"><spectrum name="reflectance" value="0.5"/></bsdf></shape>"""
LAMP = '<emitter type="point" id="lamp"><point name="position" value="0, 0, 3"/>{value}</emitter>'


def scene_folder(tmp_path: Path, body: str) -> Path:
    folder = tmp_path / "sc"
    folder.mkdir(exist_ok=True)
    (folder / "scene.xml").write_text(SCENE.format(body=body))
    return folder / "scene.xml"


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "dir"])
def test_a_mesh_that_is_not_a_regular_file_is_named_as_such(tmp_path, kind):
    """It was reported as a file that 'does not exist'."""
    from spikesim.render.errors import SceneError
    from spikesim.render.scene_files import referenced_files
    xml = scene_folder(tmp_path, '<shape type="ply" id="m"><string name="filename" value="mesh.ply"/></shape>')
    plant(xml.parent / "mesh.ply", kind)
    with pytest.raises(SceneError, match="mesh.ply") as info:
        referenced_files(xml)
    assert "not a regular file" in str(info.value) and "does not exist" not in str(info.value)
    assert str(info.value).startswith(str(xml))


@pytest.mark.parametrize("what", ["scene.xml", "motion.json", "lights.json"])
@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_scene_files_that_are_not_regular_files_are_refused(tmp_path, what, kind):
    """A scene XML, or a motion or light file planted beside it: a FIFO was 'missing' (or, beside
    the XML, silently no motion at all)."""
    from spikesim.render.errors import SceneError
    from spikesim.render.scene_files import SceneFiles
    xml = scene_folder(tmp_path, PLANE)
    target = xml.parent / what
    if target.exists():
        target.unlink()
    plant(target, kind)
    with pytest.raises(SceneError, match=WHAT[kind]) as info:
        SceneFiles.resolve(xml)
    assert what in str(info.value)


def _needs_mitsuba():
    pytest.importorskip("mitsuba")
    from spikesim._drjit import has_llvm
    if not has_llvm():
        pytest.skip("Dr.Jit's LLVM backend is unavailable")


@pytest.mark.parametrize("value", ['<spectrum name="intensity" value="1e38"/>', '<rgb name="intensity" value="1e38"/>'])
def test_an_overflowing_emitter_is_refused_naming_the_xml_and_the_emitter(tmp_path, capsys, value):
    """1e38 per nm rendered infinite pixels, reported without the XML (simulate) or the emitter."""
    _needs_mitsuba()
    xml = scene_folder(tmp_path, PLANE + LAMP.format(value=value))
    for argv in (["simulate", "--scene", xml, "--steps", 2, "-o", tmp_path / "o.dat"],
                 ["render", xml, "--steps", 1, "-o", tmp_path / "r"]):
        code, err = run_cli(argv, capsys)
        line = one_line(err)
        assert code == 2 and str(xml) in line and "'lamp'" in line and "intensity" in line, (argv, line)
    assert not (tmp_path / "o.dat").exists()


def test_an_infinite_frame_names_the_xml_and_its_brightest_emitters(tmp_path, capsys, monkeypatch):
    """Below the emission bound a render can still overflow (a lamp a hair from a surface): the
    sensor's refusal of the frame names the XML and the emitters to look at."""
    _needs_mitsuba()
    from spikesim.render import scene_emitters
    monkeypatch.setattr(scene_emitters, "MAX_EMISSION_PER_NM", float("inf"))
    xml = scene_folder(tmp_path, PLANE + LAMP.format(value='<spectrum name="intensity" value="1e38"/>'))
    for argv in (["simulate", "--scene", xml, "--steps", 2, "-o", tmp_path / "o.dat"],
                 ["render", xml, "--steps", 1, "-o", tmp_path / "r"]):
        code, err = run_cli(argv, capsys)
        line = one_line(err)
        assert code == 2 and str(xml) in line and "brightest first: 'lamp' (point" in line, (argv, line)


# ---- evaluate --gt: the kinds of image it takes ---------------------------------------------------
GH, GW = 12, 16  # SSIM's window needs 11 x 11


def gt_pair(tmp_path, capsys, gt: Path):
    """evaluate --dat (a 12 x 16 stream, 4 steps) against `gt`, TFP over one step."""
    frames = np.random.default_rng(0).random((N, GH, GW)) < 0.3
    path = write_dat(tmp_path / "g.dat", SpikeStream.from_bool(frames), flip=False)
    write_sidecar(path, {"height": GH, "width": GW, "flip": False})
    return run_cli(["evaluate", "--dat", path, "--gt", gt, "--center", 1, "--window", 1, "--methods", "tfp",
                    "--json"], capsys)


@pytest.mark.parametrize("mode", ["LA", "RGBA", "P", "1", "I;16"])
def test_evaluate_takes_grey_alpha_palette_and_16_bit_pngs(tmp_path, capsys, mode):
    """A grey+alpha PNG failed with numpy's matmul message; alpha is dropped, a palette is read as
    the colours it stands for (its indices are not light)."""
    from PIL import Image
    half = GW // 2  # two values: evaluate refuses a constant ground truth
    grey = np.full((GH, GW), 128, np.uint8)
    grey[:, half:] = 64
    if mode == "LA":
        img = Image.fromarray(np.dstack([grey, np.full_like(grey, 7)]), "LA")
    elif mode == "RGBA":
        img = Image.fromarray(np.dstack([grey, grey, grey, np.full_like(grey, 7)]), "RGBA")
    elif mode == "P":
        idx = np.zeros((GH, GW), np.uint8)
        idx[:, half:] = 1
        img = Image.fromarray(idx, "P")
        img.putpalette([128, 128, 128, 64, 64, 64] * 128)
    elif mode == "1":
        bits = np.ones((GH, GW), bool)
        bits[:, half:] = False
        img = Image.fromarray(bits)
    else:
        img = Image.fromarray(np.where(grey == 128, 32896, 16448).astype(np.uint16))
    img.save(tmp_path / "gt.png")
    code, err = gt_pair(tmp_path, capsys, tmp_path / "gt.png")
    assert code == 0, err
    from spikesim.imageio import read_image_y
    y = read_image_y(tmp_path / "gt.png")
    left, right = (1.0, 0.0) if mode == "1" else (128 / 255, 64 / 255)
    assert y.shape == (GH, GW) and np.allclose(y[:, :half], left, atol=1e-3), (mode, y[0, 0])
    assert np.allclose(y[:, half:], right, atol=1e-3), (mode, y[0, -1])


def test_evaluate_refuses_a_picture_mode_that_is_not_grey_or_rgb(tmp_path, capsys):
    from PIL import Image
    Image.new("CMYK", (GW, GH), (0, 0, 0, 40)).save(tmp_path / "gt.tif")
    code, err = gt_pair(tmp_path, capsys, tmp_path / "gt.tif")
    line = one_line(err)
    assert code == 2 and "gt.tif" in line and "CMYK" in line, line


@pytest.mark.parametrize("values, words", [
    (np.full((GH, GW), 0.3 + 0.1j), "complex"),
    (np.ones((GH, GW), bool), "bool"),
    (np.array([["a"] * GW] * GH), "<U1"),
    (np.where(np.eye(GH, GW, dtype=bool), -0.5, 0.3), "negative"),
    (np.where(np.eye(GH, GW, dtype=bool), np.nan, 0.3), "NaN or infinite"),
])
def test_evaluate_refuses_an_npy_of_the_wrong_kind_naming_it(tmp_path, capsys, values, words):
    np.save(tmp_path / "gt.npy", values)
    code, err = gt_pair(tmp_path, capsys, tmp_path / "gt.npy")
    line = one_line(err)
    assert code == 2 and "gt.npy" in line and words in line, line


@pytest.mark.parametrize("bad, words", [(-0.25, "negative pixel(s) (min -0.25)"), (np.inf, "1 NaN or infinite"),
                                        (np.nan, "1 NaN or infinite")])
def test_evaluate_refuses_negative_or_non_finite_exr_values(tmp_path, capsys, bad, words):
    pytest.importorskip("OpenEXR")
    from spikesim.imageio import write_exr
    y = np.full((GH, GW), 0.3, np.float32)
    y[2, 3] = bad
    write_exr(tmp_path / "gt.exr", y)
    code, err = gt_pair(tmp_path, capsys, tmp_path / "gt.exr")
    line = one_line(err)
    assert code == 2 and "gt.exr" in line and words in line, line


def test_verify_refuses_a_manifest_that_is_a_fifo(tmp_path, capsys):
    """It blocked (a link to /dev/zero is already refused: it leads out of the dataset root)."""
    root = tmp_path / "data"
    root.mkdir()
    plant(root / "manifest.json", "fifo")
    code, err = run_cli(["verify", root], capsys)
    line = one_line(err)
    assert code == 2 and "manifest.json" in line and "FIFO" in line, line


def test_a_render_record_that_is_a_fifo_is_refused_not_read(tmp_path):
    from pipelines.render_folder import read_record
    plant(tmp_path / "render.json", "fifo")
    with pytest.raises(ValueError, match=r"render.json: not a render record \(is a FIFO"):
        read_record(tmp_path)


@pytest.mark.parametrize("record", [{"readout_period_s": 5e-5}, {"camera": {"readout_period_s": 5e-5}}])
def test_a_checked_readout_period_is_used_wherever_the_sidecar_gives_it(tmp_path, capsys, record):
    from pipelines.cli import main
    path = small_stream(tmp_path, {"height": H, "width": W, "flip": False, **record})
    capsys.readouterr()
    assert main(["inspect", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["readout_period_s"] == 5e-5
