"""Files the commands read back: a damaged tradeoff cache or golden-statistics file ends in one line
naming it (exit status 2), a damaged cached run is measured again, and the cache is written whole."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pipelines import tradeoff_study as tradeoff
from pipelines.cli import main


def _report_only(out) -> list[str]:
    return ["tradeoff", "--scenes", "ball", "--light", "low", "--report-only", "-o", str(out), "--quiet"]


@pytest.mark.parametrize("damage", ["json", "not-an-object", "npz"])
def test_damaged_tradeoff_cache_is_one_line(damage, tmp_path, capsys):
    folder = tmp_path / "runs" / "ball_low"
    folder.mkdir(parents=True)
    (folder / "reference.json").write_text({"json": '{"render_s": 1.', "not-an-object": "[]"}.get(damage, "{}"))
    (folder / "reference.npz").write_bytes(b"PK\x03\x04 truncated")
    assert main(_report_only(tmp_path)) == 2
    err = capsys.readouterr().err
    damaged = "reference.npz" if damage == "npz" else "reference.json"
    assert len(err.strip().splitlines()) == 1 and damaged in err and "damaged cache file" in err, err


def test_damaged_cached_run_is_measured_again(tmp_path, caplog):
    row, npz = tmp_path / "spp=1.json", tmp_path / "spp=1.npz"
    tradeoff._save_npz(npz, "abc", packed=np.zeros((2, 3), np.uint8))
    tradeoff._write_json(row, {"key": "abc"})
    assert tradeoff._is_cached(row, npz, "abc") and not tradeoff._is_cached(row, npz, "other")
    row.write_text('{"key": "ab')  # cut short by a kill
    assert not tradeoff._is_cached(row, npz, "abc")
    assert "spp=1.json: damaged cache file" in caplog.text


def test_cache_files_are_replaced_whole(tmp_path):
    path = tmp_path / "reference.json"
    tradeoff._write_json(path, {"render_s": 1.0})

    def interrupted(f):
        f.write(b'{"render_s": ')
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        tradeoff.atomic_write_file(path, interrupted)  # the writer the study's caches use (spikesim.outputs)
    assert json.loads(path.read_text()) == {"render_s": 1.0}
    assert [p.name for p in tmp_path.iterdir()] == ["reference.json"]  # no .part left behind


@pytest.mark.parametrize("text, problem", [
    ("{not json", "not valid JSON"), ('{"stats": []}', "not a layout-2 golden reference"),
    ('{"layout": 2, "stats": []}', "no 'stats' object"),
    ('{"layout": 2, "stats": {"y=0": {"rate_per_step": {"value": 1}}}}', "'se'")])
def test_damaged_golden_file_is_one_line(text, problem, tmp_path, capsys):
    path = tmp_path / "golden.json"
    path.write_text(text)
    assert main(["golden", "--reference", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(path) in err and problem in err, err
