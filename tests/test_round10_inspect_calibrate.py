"""Round ten's defects of `inspect` and `calibrate`: the readout period a dataset scene's meta.json
records, a preview written into a dataset or over a file put there during the run, row and column
spreads fitted from a scene's texture, and fitted values the camera model does not take."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cli_testing import one_line, run_cli
from pipelines.cli import main
from spikesim.camera import SpikeCamera
from spikesim.simulate import Simulator
from spikesim.stream import SpikeStream, write_dat


def scene_folder(root, period=1e-4, steps=60, h=8, w=16):
    """A dataset scene as `generate` lays it out: spikes.dat with meta.json beside it (no sidecar)."""
    root.mkdir(parents=True)
    rng = np.random.default_rng(0)
    write_dat(root / "spikes.dat", SpikeStream.from_bool(rng.random((steps, h, w)) < 0.2))
    (root / "meta.json").write_text(json.dumps({"height": h, "width": w, "flip": True, "num_steps": steps,
                                                "camera": {"readout_period_s": period}}))
    return root / "spikes.dat"


def test_inspect_takes_the_period_a_dataset_scenes_meta_json_records(tmp_path, capsys):
    """A scene generated at 1e-4 s was shown as 1.5 ms at 40,000 Hz, and a contradicting
    --readout-period-s taken: inspect read the period from a sidecar only (round ten)."""
    dat = scene_folder(tmp_path / "ds" / "fan_normal")
    capsys.readouterr()
    assert main(["inspect", str(dat)]) == 0
    assert "60 x 8 x 16 (flip=True), 6 ms at 10,000 Hz" in capsys.readouterr().out
    assert main(["inspect", str(dat), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["readout_period_s"] == 1e-4
    code, err = run_cli(["inspect", dat, "--readout-period-s", "2.5e-5"], capsys)
    line = one_line(err)
    assert code == 2 and "record gives 0.0001 s" in line and "meta.json" in line and "drop the flag" in line
    assert run_cli(["inspect", dat, "--readout-period-s", "1e-4"], capsys)[0] == 0


def test_inspect_preview_inside_a_dataset_is_refused(tmp_path, capsys):
    """`inspect --preview DATASET/` wrote preview.png into the dataset, which verify then reported
    as an extra file (round ten)."""
    ds = tmp_path / "ds"
    dat = scene_folder(ds / "fan_normal")
    (ds / "manifest.json").write_text('{"scenes": {}}')
    for preview in (ds, ds / "fan_normal" / "p.png"):
        code, err = run_cli(["inspect", dat, "--preview", preview], capsys)
        line = one_line(err)
        assert code == 2 and "--preview" in line and "inside the dataset" in line, line
    assert sorted(p.name for p in ds.rglob("*.png")) == []
    assert run_cli(["inspect", dat, "--preview", tmp_path / "out" / "p.png"], capsys)[0] == 0


def test_inspect_preview_put_there_during_the_run_is_kept(tmp_path, capsys, monkeypatch):
    """Ownership of the preview's path was checked before the stream was read only: a file the
    user put there meanwhile was overwritten (round ten)."""
    import spikesim.imageio as imageio
    dat = scene_folder(tmp_path / "s")
    target = tmp_path / "p.png"
    real = imageio.auto_percentile

    def user_writes_meanwhile(tfp):  # runs after the first check, before the write
        target.write_bytes(b"the user's picture")
        return real(tfp)
    monkeypatch.setattr(imageio, "auto_percentile", user_writes_meanwhile)
    code, err = run_cli(["inspect", dat, "--preview", target], capsys)
    assert code == 2 and "p.png" in one_line(err) and "--preview" in err
    assert target.read_bytes() == b"the user's picture"


def _recording(cam: SpikeCamera, light: np.ndarray, steps: int, path, seed: int = 1):
    Simulator(cam, seed=seed).run_to_dat((light for _ in range(steps)), path)
    return path


def test_calibrate_does_not_read_a_scenes_texture_as_row_and_column_spreads(tmp_path, capsys):
    """A car scene of a camera without row or column patterns was fitted as 0.24 and 0.16, and a
    still textured frame refused as above the maximum 0.3 (round ten): texture that varies by row
    or column is in both halves of a recording as a fixed pattern is. None is fitted from a scene."""
    from pipelines.argtypes import load_camera
    cam = SpikeCamera.realistic(height=48, width=64)  # row_gain_spread = column_gain_spread = 0
    yy, xx = np.mgrid[0:48, 0:64]
    texture = (0.04 + 0.12 * ((yy // 12) % 2) + 0.06 * ((xx // 16) % 2)).astype(np.float32)  # bands by row and column
    scene = _recording(cam, texture, 1_200, tmp_path / "scene.dat")
    dark = _recording(cam, np.zeros((48, 64), np.float32), 1_200, tmp_path / "dark.dat")
    for argv in (["--scene", scene], ["--dark", dark, "--scene", scene]):
        out = tmp_path / f"c{len(argv)}.toml"
        code, err = run_cli(["calibrate", *argv, "-o", out], capsys)
        assert code == 0, err
        fitted = load_camera(str(out))
        assert fitted.row_gain_spread == 0 and fitted.column_gain_spread == 0
        text = out.read_text()
        assert "# not fitted: row_gain_spread and column_gain_spread from scene.dat" in text
        assert "cannot be told apart" in text and "row_gain_spread = 0.0  # fitted" not in text
    # a starting camera's own values are kept (and said so)
    base = tmp_path / "base.toml"
    assert main(["camera", "--write", str(base)]) == 0
    base.write_text(base.read_text().replace("row_gain_spread = 0.0", "row_gain_spread = 0.02"))
    code, err = run_cli(["calibrate", "--scene", scene, "--camera", base, "-o", tmp_path / "k.toml"], capsys)
    assert code == 0, err
    assert load_camera(str(tmp_path / "k.toml")).row_gain_spread == 0.02
    assert "starting camera's values (0.02 and 0)" in (tmp_path / "k.toml").read_text()


def test_a_fitted_value_outside_the_camera_model_names_the_recording_and_the_way_forward(tmp_path, capsys):
    """A valid camera of gain_spread 0.3 and threshold_offset 0.2 measures 0.36 on a flat; the
    error said only "gain_spread=0.36 is above the supported maximum 0.3" (round ten)."""
    cam = SpikeCamera.realistic(height=64, width=64, gain_spread=0.3, threshold_offset=0.2)
    dark = _recording(cam, np.zeros((64, 64), np.float32), 2_000, tmp_path / "dark.dat")
    flat = _recording(cam, np.full((64, 64), 0.1, np.float32), 2_000, tmp_path / "flat.dat")
    out = tmp_path / "c.toml"
    code, err = run_cli(["calibrate", "--dark", dark, "--flat", flat, "-o", out], capsys)
    line = one_line(err)
    assert code == 2 and not out.exists()
    for words in ("--flat flat.dat", "fitted gain_spread = 0.3", "outside the camera model's range",
                  "supported maximum 0.3", "calibrate without --flat", "threshold mismatch and offset together"):
        assert words in line, (words, line)
    # the way forward works: without the flat, the dark fit is written
    assert run_cli(["calibrate", "--dark", dark, "-o", out], capsys)[0] == 0


def test_calibrated_camera_names_the_field_of_any_value_out_of_range():
    from spikesim.calibrate import Fitted, calibrated_camera
    base = SpikeCamera.realistic(height=8, width=8)
    with pytest.raises(ValueError, match=r"--dark d\.dat .*dark_current_spread = 7 .*calibrate without --dark"):
        calibrated_camera(base, [Fitted("dark_current_spread", 7.0, 0.1, "d.dat (400 steps, dark)")])
