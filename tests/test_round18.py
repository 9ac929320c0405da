"""Round eighteen (docs/robustness.md): the tradeoff study's reference frames are keyed, no output
replaces a device or FIFO, a user's temporary-looking file is kept where no simulate was killed, and
the lock's and the export's lines name what they mean."""
from __future__ import annotations

import json
import logging
import os

import numpy as np
import pytest

from cli_testing import one_line, run_cli

SIMULATE = ["simulate", "--steps", "50", "--height", "16", "--width", "24", "--backend", "numpy", "--quiet"]


def test_frames_another_study_left_are_rendered_again_not_reused(tmp_path, caplog):
    """A study with other inputs, stopped while its reference's ground truth rendered, had written
    its frames under this study's reference: the runs that reuse them simulated its light, rc 0."""
    from pipelines import tradeoff_study as tradeoff

    cfg = tradeoff.StudyConfig.of(scenes=("ball",), lights=("low",), resolution=(16, 24), windows=1, ref_spp=2,
                                  gt_spp=4, knobs=("precision",), repeats=1)
    rows = tradeoff.run_study(cfg, tmp_path, progress=False)
    first = next(r for r in rows if r["run"] == "float32")
    assert first["render_reused"]
    folder = tmp_path / "runs" / "ball_low"
    with np.load(folder / "reference_frames.npz") as z:
        steps, frames = z["steps"], z["frames"]
    np.savez_compressed(folder / "reference_frames.npz", steps=steps, frames=frames * 3, key=np.array("another"))
    (folder / "float32.json").unlink()
    caplog.set_level(logging.WARNING)
    again = next(r for r in tradeoff.run_study(cfg, tmp_path, progress=False) if r["run"] == "float32")
    assert not again["render_reused"] and "cached for another study" in caplog.text
    for key in ("rate_err", "rate_bias", "tfp_psnr", "tfp_err", "isi_w1"):
        assert again[key] == pytest.approx(first[key], rel=1e-9, nan_ok=True), key  # the same light, rendered again


@pytest.mark.parametrize("command", ["simulate", "camera"])
def test_a_fifo_at_the_output_is_never_replaced_even_with_overwrite(tmp_path, capsys, command):
    fifo = tmp_path / ("out.dat" if command == "simulate" else "cam.toml")
    os.mkfifo(fifo)
    argv = [*SIMULATE, "-o", fifo] if command == "simulate" else ["camera", "--write", fifo]
    for extra in ([], ["--overwrite"]):
        rc, err = run_cli([*argv, *extra], capsys)
        line = one_line(err)
        assert rc == 2 and "is a FIFO (named pipe), not a regular file" in line and "pass --overwrite" not in line
        assert fifo.exists() and not fifo.is_file()  # still the FIFO
    assert not (tmp_path / "out.dat.json").exists()


@pytest.mark.skipif(os.geteuid() != 0, reason="making a device node needs root")
def test_a_device_at_the_output_is_never_replaced(tmp_path, capsys):
    import stat
    node = tmp_path / "null"
    os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    rc, err = run_cli([*SIMULATE, "-o", node, "--overwrite"], capsys)
    assert rc == 2 and "is a character device, not a regular file" in one_line(err)
    assert stat.S_ISCHR(os.lstat(node).st_mode) and not (tmp_path / "null.json").exists()


def test_a_users_temporary_looking_file_is_kept_where_no_simulate_was_killed(tmp_path, capsys):
    folder = tmp_path / "s12"
    folder.mkdir()
    notes = folder / ".a.dat.0123abcd.part"
    notes.write_text("notes")
    rc, err = run_cli([*SIMULATE, "-o", folder / "a.dat"], capsys)
    assert rc == 0, err
    assert notes.read_text() == "notes"
    assert sorted(p.name for p in folder.iterdir()) == [".a.dat.0123abcd.part", "a.dat", "a.dat.json"]


def test_a_folder_at_the_lock_is_named(tmp_path, capsys):
    folder = tmp_path / "s"
    (folder / ".a.dat.spikesim-lock").mkdir(parents=True)
    rc, err = run_cli([*SIMULATE, "-o", folder / "a.dat"], capsys)
    line = one_line(err)
    assert rc == 2 and ".a.dat.spikesim-lock: is a folder, not a regular file, where spikesim keeps the lock of a.dat" in line
    assert not (folder / "a.dat").exists()


def test_a_share_for_a_scene_not_listed_is_reported(tmp_path):
    from spikesim.dataset import _manifest_field_problems
    manifest = {"scenes": {"a": {}}, "gt_saturated_fraction": {"a": 0.1, "gone": 0.2}}
    assert _manifest_field_problems(manifest) == [
        "manifest.json: gt_saturated_fraction.gone: a share for a scene the manifest does not list"]


def test_a_runs_arrays_another_study_left_under_its_record_are_measured_again(tmp_path, capsys):
    """Every cached .npz is written before its .json: a study with other inputs stopped between the
    two left its arrays under this study's record. Each file now carries its run's key."""
    from pipelines import tradeoff_study as tradeoff

    cfg = tradeoff.StudyConfig.of(scenes=("ball",), lights=("low",), resolution=(16, 24), windows=1, ref_spp=2,
                                  gt_spp=4, knobs=("precision",), repeats=1)
    first = {r["run"]: r for r in tradeoff.run_study(cfg, tmp_path, progress=False)}
    npz = tmp_path / "runs" / "ball_low" / "float32.npz"
    with np.load(npz) as z:
        arrays = {k: z[k] for k in z.files if k != tradeoff.NPZ_KEY}
    tradeoff._save_npz(npz, "another study's key", **{**arrays, "packed": np.zeros_like(arrays["packed"])})
    with pytest.raises(ValueError, match="float32.npz: cached for another scene, seed or size"):
        tradeoff.collect_rows(cfg, tmp_path)  # what --report-only reads
    again = {r["run"]: r for r in tradeoff.run_study(cfg, tmp_path, progress=False)}
    assert again["float32"]["rate_err"] == pytest.approx(first["float32"]["rate_err"], rel=1e-9)
    assert tradeoff._npz_key(npz) == json.loads((npz.with_suffix(".json")).read_text())["key"]
