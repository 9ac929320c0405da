"""Round seventeen: the writers' caches, records and temporary files.

- `tradeoff --report-only` reported figures cached for another scene, seed or size, rc 0;
- an export stopped by SIGKILL could not be rerun: its own temporary file was refused;
- `evaluate --spikezoo` on a spikezoo.json with height 0 (or a height or rate of another type)
  ended in a traceback or a message naming no file;
- a `simulate` stopped by SIGKILL left its partial stream beside -o for good;
- a re-export deleted or replaced an exported file the user had changed;
- a second SIGTERM during the clean-up of nested `sigterm_raises` blocks raised again."""
from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import threading
import time

import numpy as np
import pytest

from cli_testing import one_line, run_cli


# ---- tradeoff --report-only ---------------------------------------------------------------------
def _stale_reference(out, cfg, scene, light="low"):
    """A reference cached under the key `cfg` gives (with stand-in arrays): the cache a study of
    `cfg` leaves, as far as the key goes."""
    from pipelines import tradeoff_study as tradeoff
    folder = out / "runs" / f"{tradeoff.scene_label(scene)}_{light}"
    folder.mkdir(parents=True)
    ref = tradeoff.plan_runs(cfg)[0]
    key = tradeoff._digest({**tradeoff._scene_key(cfg, scene, light), **ref.to_dict()})
    h, w = cfg.resolution
    (folder / "reference.json").write_text(json.dumps(
        {"key": key, "session": "1", "render_s": 1.0, "simulate_s": 1.0, "renders": 41, "render_reused": False,
         "gt_render_s": 1.0}))
    np.savez(folder / "reference.npz", packed=np.zeros((41, h * w // 8), np.uint8),
             y_centres=np.zeros((1, h, w), np.float32), gt=np.full((1, h, w), 0.01, np.float32))
    return folder


def _tradeoff_args(scene_flag, out, *extra):
    return ["tradeoff", *scene_flag, "--light", "low", "--height", "11", "--width", "16", "--windows", "1",
            "--ref-spp", "1", "--gt-spp", "2", "--gt-error-spp", "--knobs", "precision", "--repeats", "1",
            "--threads", "1", "--backend", "numpy", "--quiet", "--report-only", "-o", out, *extra]


def _cfg(scene, seed=0, height=11):
    from pipelines import tradeoff_study as tradeoff
    return tradeoff.StudyConfig.of(scenes=(scene,), lights=("low",), resolution=(height, 16), windows=1, ref_spp=1,
                                   gt_spp=2, seed=seed, knobs=("precision",), repeats=1, gt_error_spp=(),
                                   threads=1, backend="numpy")


@pytest.mark.parametrize("change", ["seed", "height"])
def test_report_only_refuses_a_cache_of_another_seed_or_size(change, tmp_path, capsys):
    """--report-only --seed 9 reported seed 0's figures, rc 0; --height 13 failed on the old size's
    streams ("packed frames have 17 bytes")."""
    from pipelines import tradeoff_study as tradeoff
    out = tmp_path / "to"
    _stale_reference(out, _cfg("ball"), "ball")
    extra = ["--seed", "9"] if change == "seed" else ["--height", "13"]
    rc, err = run_cli(_tradeoff_args(["--scenes", "ball"], out, *extra), capsys)
    line = one_line(err)
    assert rc == 2 and "reference.json: cached for another scene, seed or size" in line, err
    assert "without --report-only" in line
    assert not (out / "tradeoff.md").exists()
    other = _cfg("ball", seed=9) if change == "seed" else _cfg("ball", height=13)
    for collect in (tradeoff.collect_rows, tradeoff.collect_gt_rows):  # the library's readers too
        with pytest.raises(ValueError, match="cached for another scene, seed or size"):
            collect(other, out)


def test_report_only_refuses_a_cache_of_the_scene_before_its_edit(tmp_path, capsys):
    """The scene's lights.json edited since the study: --report-only still printed the old scene's
    figures, rc 0 (round sixteen's content keys were made, and never compared)."""
    from scenes import ROOT
    scene = tmp_path / "myball"
    shutil.copytree(ROOT / "ball", scene, ignore=shutil.ignore_patterns("__pycache__"))
    xml = str(scene / "scene.xml")
    out = tmp_path / "to"
    folder = _stale_reference(out, _cfg(xml), xml)
    lights = scene / "lights.json"
    lights.write_text(lights.read_text().replace('"illuminance_lux": 10,', '"illuminance_lux": 1000,'))
    rc, err = run_cli(_tradeoff_args(["--xml", xml], out), capsys)
    assert rc == 2 and f"{folder / 'reference.json'}: cached for another scene" in one_line(err), err


# ---- Spike-Zoo exports --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_data(tmp_path_factory):
    """Two 16 x 24 scenes of 100 steps, ground truth at steps 20 and 61: a 41-step window fits both."""
    pytest.importorskip("OpenEXR", reason="the dataset layout stores ground truth as EXR")
    from spikesim.dataset import write_manifest, write_scene
    from spikesim.stream import SpikeStream
    root = tmp_path_factory.mktemp("r17") / "data"
    rng = np.random.default_rng(17)
    for i, name in enumerate(("sa_low", "sb_low")):
        y = rng.uniform(0.05, 0.2, size=(16, 24)).astype(np.float32)
        spikes = rng.random((100, 16, 24)) < y
        write_scene(root, name, SpikeStream.from_bool(spikes), {20: y, 61: y * (1 + i)}, meta={})
    write_manifest(root, {"kind": "test"})
    return root


def _export(capsys, data, out, *extra):
    rc, err = run_cli(["export", data, "--format", "spikezoo", "--steps", "41", "-o", out, *extra], capsys)
    assert rc == 0, err
    return err


def test_a_killed_exports_temporary_files_are_removed_by_its_rerun(small_data, tmp_path, capsys):
    """A SIGKILL left `.NAME.dat.XXXXXXXX.part` in train/spike, and every rerun was refused ("not
    written by an earlier export"); the rerun removes the temporary files of the files the export
    record lists, saying so, and still refuses any other file there."""
    out = tmp_path / "exk"
    _export(capsys, small_data, out, "--split", "train")
    record = json.loads((out / "spikezoo.json").read_text())
    record["splits"]["train"]["complete"] = False  # as the kill leaves it
    (out / "spikezoo.json").write_text(json.dumps(record))
    spike, gt = out / "train" / "spike", out / "train" / "gt"
    killed = [spike / ".sa_low_step000061.dat.c0569a34.part", gt / ".sb_low_step000020.png.0123abcd.part",
              out / ".spikezoo.json.deadbeef.part"]
    for path in killed:
        path.write_bytes(b"\0" * 10)
    err = _export(capsys, small_data, out, "--split", "train")
    assert not any(p.exists() for p in killed)
    for path in killed:
        # named by its place in the export (round eighteen: the bare name, beside the export's root)
        assert f"{out}: removed {path.relative_to(out)}, a temporary file an interrupted export left" in err
    assert json.loads((out / "spikezoo.json").read_text())["splits"]["train"]["complete"]
    # a file of that form whose name no export wrote is not the export's: refused, kept
    theirs = spike / ".mine.dat.c0569a34.part"
    theirs.write_bytes(b"mine")
    rc, err = run_cli(["export", small_data, "--format", "spikezoo", "--steps", "41", "--split", "train", "-o", out],
                      capsys)
    assert rc == 2 and ".mine.dat.c0569a34.part: not written by an earlier export" in one_line(err)
    assert theirs.read_bytes() == b"mine"


@pytest.mark.parametrize("scenes", [["sb_low"], ["sa_low", "sb_low"]])
def test_a_reexport_keeps_an_exported_file_the_user_changed(scenes, small_data, tmp_path, capsys):
    """A png the user edited was deleted by a re-export of other scenes (or replaced by one of the same),
    rc 0, although spikezoo.json's sha256 showed it changed."""
    out = tmp_path / "exe"
    _export(capsys, small_data, out, "--scenes", "sa_low")
    png = out / "test" / "gt" / "sa_low_step000061.png"
    edited = png.read_bytes() + b"my edit"
    png.write_bytes(edited)
    rc, err = run_cli(["export", small_data, "--format", "spikezoo", "--steps", "41", "--scenes", *scenes, "-o", out],
                      capsys)
    line = one_line(err)
    assert rc == 2 and f"{png}: changed since the export wrote it" in line, err
    assert "move it away or choose another folder" in line
    assert png.read_bytes() == edited
    png.unlink()  # moved away: the rerun goes on
    _export(capsys, small_data, out, "--scenes", *scenes)


@pytest.fixture(scope="module")
def exported(small_data, tmp_path_factory):
    out = tmp_path_factory.mktemp("r17x") / "ex"
    from pipelines.cli import main
    assert main(["export", str(small_data), "--format", "spikezoo", "--steps", "41", "-o", str(out)]) == 0
    return out


def _edit_record(folder, edit):
    path = folder / "spikezoo.json"
    record = json.loads(path.read_text())
    edit(record)
    path.write_text(json.dumps(record))


def _first_pair(record):
    return next(iter(record["splits"]["test"]["pairs"].values()))


@pytest.mark.parametrize("edit, field", [
    (lambda r: r.update(height=0), '"height" is 0'),
    (lambda r: r.pop("height"), '"height" is missing'),
    (lambda r: r.update(height="x"), "\"height\" is 'x'"),
    (lambda r: r.update(height=16.0), '"height" is 16.0'),
    (lambda r: r.update(width=-24), '"width" is -24'),
    (lambda r: _first_pair(r).update(rate="x"), "\"rate\" is 'x'"),
    (lambda r: _first_pair(r).update(rate=0), '"rate" is 0'),
    (lambda r: _first_pair(r).update(rate=float("inf")), '"rate" is inf'),
    (lambda r: _first_pair(r).update(steps="41"), "\"steps\" is '41'"),
], ids=["height0", "no-height", "height-text", "height-float", "width-negative", "rate-text", "rate0", "rate-inf",
        "steps-text"])
def test_a_bad_size_or_rate_in_spikezoo_json_is_named(edit, field, exported, tmp_path, capsys):
    """height 0 ended in a ZeroDivisionError (rc 1); a missing one said "error: height", a text one
    "invalid literal for int()", a rate of text "could not convert string to float"; 16.0 was taken
    as 16, and rate 0 was blamed on --gt."""
    folder = tmp_path / "z"
    shutil.copytree(exported, folder)
    _edit_record(folder, edit)
    rc, err = run_cli(["evaluate", "--spikezoo", folder, "--methods", "tfp", "--threads", "1", "-o", tmp_path / "ev"],
                      capsys)
    line = one_line(err)
    assert rc == 2 and f"{folder / 'spikezoo.json'}:" in line and field in line, err


# ---- simulate -----------------------------------------------------------------------------------
SIMULATE = ["simulate", "--steps", "100", "--height", "16", "--width", "24", "--backend", "numpy", "--quiet"]


def test_a_killed_simulates_partial_stream_is_removed_by_its_rerun(tmp_path, capsys, caplog):
    """`.long.dat.c393f90f.part` (GBs) stayed beside -o after a SIGKILL, whatever reran there."""
    caplog.set_level(logging.INFO)
    folder = tmp_path / "sk"
    folder.mkdir()
    stale = [folder / ".long.dat.c393f90f.part", folder / ".long.dat.json.0123abcd.part"]
    for path in stale:
        path.write_bytes(b"\0" * 100)
    kept = [folder / ".long.dat.notmine.part", folder / ".other.dat.c393f90f.part", folder / "long.dat.c393f90f.part"]
    for path in kept:
        path.write_bytes(b"x")
    (folder / ".long.dat.deadbeef.part").symlink_to(kept[0])  # a link is never removed through
    # what the killed run left beside them: its lock, holding its pid and command (round eighteen:
    # only then are they a killed simulate's)
    (folder / ".long.dat.spikesim-lock").write_text("pid 4242: spikesim simulate -o long.dat\n")
    rc, err = run_cli([*SIMULATE, "-o", folder / "long.dat"], capsys)
    assert rc == 0, err
    assert not any(p.exists() for p in stale)
    assert all(p.read_bytes() == b"x" for p in kept) and (folder / ".long.dat.deadbeef.part").is_symlink()
    for path in stale:
        assert f"removed {path.name}, a temporary file an interrupted simulate left" in caplog.text
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        ["long.dat", "long.dat.json", ".long.dat.deadbeef.part", *(p.name for p in kept)])  # no lock left


def test_simulate_waits_for_another_writer_of_its_output_and_leaves_its_temporary(tmp_path, capsys):
    """Another simulate writing the same -o holds its lock: this one waits, and removes no temporary
    file while that writer may still be writing it."""
    from spikesim.outputs import output_file_lock
    folder = tmp_path / "sk"
    folder.mkdir()
    out = folder / "long.dat"
    live = folder / ".long.dat.abcdef01.part"
    result = {}
    with output_file_lock(out):
        live.write_bytes(b"being written")
        worker = threading.Thread(target=lambda: result.update(rc=run_cli([*SIMULATE, "-o", out], capsys)[0]))
        worker.start()
        time.sleep(2.0)
        assert worker.is_alive() and live.read_bytes() == b"being written" and not out.exists()
        live.unlink()  # that writer renames its temporary file into place and lets go
    worker.join(120)
    assert result.get("rc") == 0 and out.is_file()


# ---- SIGTERM ------------------------------------------------------------------------------------
def test_a_second_sigterm_during_the_clean_up_of_nested_blocks_is_ignored():
    from spikesim.signals import Terminated, sigterm_raises
    before = signal.getsignal(signal.SIGTERM)
    cleaned = []
    with pytest.raises(Terminated):
        with sigterm_raises():
            try:
                with sigterm_raises():  # the CLI's block, with results_writing's inside it
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(5)
            finally:  # the outer block's clean-up: a second SIGTERM is ignored
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.2)
                cleaned.append(True)
    assert cleaned == [True]
    assert signal.getsignal(signal.SIGTERM) == before
    with pytest.raises(Terminated):  # the next block turns SIGTERM into Terminated again
        with sigterm_raises():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
    assert signal.getsignal(signal.SIGTERM) == before
