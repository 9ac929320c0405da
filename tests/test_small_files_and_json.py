"""Round three (issue 30): one bounded parser for every small file (a file nested ~1000 deep gave a
RecursionError traceback in camera, inspect, train --config, verify and generate), standard JSON,
and the small surfaces that were silently wrong or a traceback (each test says which)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from spikesim.config_io import MAX_NESTING, nesting_depth, parse_text

DEEP_JSON = '{"a":' * 1000 + "1" + "}" * 1000
DEEP_TOML = "a = " + "[" * 1000 + "]" * 1000 + "\n"


def run(*args):
    return subprocess.run([sys.executable, "-m", "pipelines.cli", *args], capture_output=True, text=True, timeout=300)


def test_parse_text_bounds_nesting():
    assert nesting_depth({"a": [1, {"b": 2}]}) == 3 and nesting_depth(5) == 0
    for text, toml in ((DEEP_JSON, False), (DEEP_TOML, True), ("[" * (MAX_NESTING + 1) + "]" * (MAX_NESTING + 1), False)):
        with pytest.raises(ValueError, match="nested deeper than"):
            parse_text(text, "x", toml=toml)
    assert parse_text("[" * MAX_NESTING + "]" * MAX_NESTING, "x") is not None


@pytest.mark.parametrize("suffix, text", [(".json", DEEP_JSON), (".toml", DEEP_TOML)])
def test_camera_and_train_name_a_deep_config(tmp_path, suffix, text):
    f = tmp_path / f"deep{suffix}"
    f.write_text(text)
    r = run("camera", str(f))
    assert r.returncode == 2 and "nested deeper than" in r.stderr and "Traceback" not in r.stderr
    if suffix == ".json":
        r = run("train", "--config", str(f), "--data", str(tmp_path), "-o", str(tmp_path / "r"))
        assert r.returncode == 2 and "nested deeper than" in r.stderr and "Traceback" not in r.stderr


def test_inspect_verify_and_generate_name_deep_records(tmp_path):
    ds = tmp_path / "ds"
    assert run("generate", "rllr", "--pattern", "--count", "1", "--quiet", "-o", str(ds)).returncode == 0
    dat = tmp_path / "s.dat"
    assert run("simulate", "--steps", "41", "--height", "8", "--width", "16", "-o", str(dat)).returncode == 0
    (tmp_path / "s.dat.json").write_text(DEEP_JSON)
    r = run("inspect", str(dat))
    assert r.returncode == 2 and "nested deeper than" in r.stderr and "Traceback" not in r.stderr
    (ds / "manifest.json").write_text(DEEP_JSON)
    r = run("verify", str(ds))
    assert r.returncode in (1, 2) and "Traceback" not in r.stderr
    (ds / "rllr_0000" / "meta.json").write_text(DEEP_JSON)
    r = run("generate", "rllr", "--pattern", "--count", "1", "--quiet", "-o", str(ds))
    assert "Traceback" not in r.stderr and "RecursionError" not in r.stderr


def test_standard_json_has_no_nan_or_infinity():
    import json

    from spikesim.config_io import standard_json

    text = standard_json({"scores": {"TFP": {"psnr": float("inf"), "ssim": 0.5}}, "rows": [float("nan"), 1.0]})
    doc = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    assert doc["scores"]["TFP"]["psnr"] is None and doc["rows"] == [None, 1.0]
    assert doc["non_finite"] == {"scores.TFP.psnr": "inf", "rows[0]": "nan"}


def test_panel_json_is_standard(tmp_path):
    """panel --json printed Infinity for the black floor's edge/noise; now null with the reason."""
    import json

    dat = tmp_path / "s.dat"
    assert run("simulate", "--steps", "82", "--height", "16", "--width", "24", "--peak-y", "0.01", "-o",
               str(dat)).returncode == 0
    r = run("panel", str(dat), "--methods", "tfp", "black", "--json", "-o", str(tmp_path / "p.png"))
    assert r.returncode == 0, r.stderr
    json.loads(r.stdout, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))


def test_small_surface_refusals(tmp_path):
    """panel with two methods of one label, evaluate --dat against a constant truth, camera --write
    with a file, tfp:1_23 and a 30-digit seed: each one line, rc 2 (they were silently wrong or a
    traceback before)."""
    import numpy as np

    dat = tmp_path / "s.dat"
    assert run("simulate", "--steps", "123", "--height", "16", "--width", "24", "-o", str(dat)).returncode == 0
    r = run("panel", str(dat), "--methods", "tfp", "TFP=tfi", "-o", str(tmp_path / "p.png"))
    assert r.returncode == 2 and "two methods are labelled 'TFP'" in r.stderr
    np.save(tmp_path / "gt.npy", np.zeros((16, 24), np.float32))
    r = run("evaluate", "--dat", str(dat), "--gt", str(tmp_path / "gt.npy"), "--center", "61", "--methods", "tfp")
    assert r.returncode == 2 and "one value everywhere" in r.stderr
    r = run("camera", "--write", str(tmp_path / "c.toml"), "measured")
    assert r.returncode == 2 and "not both" in r.stderr and not (tmp_path / "c.toml").exists()
    r = run("evaluate", "--dat", str(dat), "--gt", str(tmp_path / "gt.npy"), "--center", "61", "--methods", "tfp:1_23")
    assert r.returncode == 2 and "digits 0-9" in r.stderr
    r = run("simulate", "--steps", "41", "--height", "8", "--width", "8", "--seed", "1" * 30, "-o", str(tmp_path / "x.dat"))
    assert r.returncode == 2 and "a seed is at most" in r.stderr


def test_a_checkpoint_path_holding_an_equals_sign_is_a_path(tmp_path):
    import shutil

    from model.methods import method_from_spec
    from model.pretrained import pretrained_path

    ckpt = tmp_path / "lr=3e-4" / "best.pt"
    ckpt.parent.mkdir()
    shutil.copy(pretrained_path("lrrep"), ckpt)
    assert method_from_spec(str(ckpt)).name == "lr=3e-4"
    assert method_from_spec(f"mine={ckpt}").name == "mine"


def test_checkpoint_errors_name_the_real_cause(tmp_path):
    """A FIFO given as --init said "not found"; a CUDA load on a CPU machine blamed the shipped file."""
    import os

    import torch

    from model.checkpoint import load_checkpoint
    from model.pretrained import load_pretrained

    fifo = tmp_path / "w.pt"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="not a regular file"):
        load_checkpoint(fifo)
    if not torch.cuda.is_available():
        from spikesim.errors import UnavailableError
        with pytest.raises((ValueError, UnavailableError), match="no CUDA device"):  # the machine, not the file
            load_pretrained("lrrep", "cuda")


def test_duplicate_json_keys_are_refused():
    with pytest.raises(ValueError, match="'a' is given twice"):
        parse_text('{"a": 1, "b": {"a": 2}, "a": 3}', "x")
    assert parse_text('{"a": 1, "b": {"a": 2}}', "x") == {"a": 1, "b": {"a": 2}}


def test_a_longest_legal_output_name_can_be_written(tmp_path):
    """A 255-byte name failed: its temporary name (dot, random part, suffix) was longer than that."""
    from spikesim.outputs import atomic_write_text

    target = tmp_path / ("n" * 251 + ".txt")
    atomic_write_text(target, "ok")
    assert target.read_text() == "ok" and [p.name for p in tmp_path.iterdir()] == [target.name]


def test_a_damaged_campaign_state_starts_afresh(tmp_path, capsys):
    from pipelines.gpu_campaign import runner

    work = tmp_path / "w"
    work.mkdir()
    (work / "state.json").write_text('{"schema": ')
    o = type("O", (), {"work": work, "fresh": False, "profile": type("P", (), {"name": "cpu"})(), "seed": 0})()
    assert runner._load_state(o) == {}
    assert "is damaged" in capsys.readouterr().err
    (work / "state.json").write_text('{"schema": %d, "mode": "cpu", "seed": 0, "stages": [1]}' % runner.SCHEMA_VERSION)
    assert runner._load_state(o) == {}


def test_a_deadline_beyond_a_day_is_refused():
    import argparse

    from pipelines.gpu_campaign.cmd import minutes_in_a_day
    with pytest.raises(argparse.ArgumentTypeError, match="at most a day"):
        minutes_in_a_day("1e307")


def test_a_full_disk_during_an_exr_write_is_an_oserror_naming_the_file(tmp_path, monkeypatch):
    """OpenEXR reports a full disk as RuntimeError: `generate` gave its traceback, not rc 2."""
    import errno

    import numpy as np
    import OpenEXR

    from spikesim.imageio import write_exr

    def full(self, path):
        raise RuntimeError(f'Failed to write pixel data to image file "{path}". No space left on device.')

    monkeypatch.setattr(OpenEXR.File, "write", full)
    with pytest.raises(OSError) as info:
        write_exr(tmp_path / "gt.exr", np.zeros((4, 4), np.float32))
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(tmp_path / "gt.exr")
    assert list(tmp_path.iterdir()) == []  # no partial file left
