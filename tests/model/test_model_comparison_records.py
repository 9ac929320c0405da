"""model/comparison.py's kept records (a run's compute.json, a method's score cache): a malformed
one is set aside with one warning naming it and made again, never trusted or a traceback."""
from __future__ import annotations

import dataclasses
import json

import pytest

from model.comparison import _checkpoint_stamp, _read_scores, _write_scores, read_compute
from model.evaluation import Score

ROWS = [Score("ball_low", "tfp", 20.0, 0.5, 3, 20.0, 0.5, 1.0, 0.1, 14.0, 0.3),
        Score("ALL", "tfp", 20.0, 0.5, 3, 20.0, 0.5, 1.0, 0.1, 14.0, 0.3)]


def test_a_good_compute_record_reads_and_none_is_empty(tmp_path):
    assert read_compute(tmp_path) == {}
    (tmp_path / "compute.json").write_text(json.dumps({"cpu_seconds": 12.5, "wall_seconds": 7.0, "sessions": 1,
                                                       "steps": 4, "threads": [1]}))
    assert read_compute(tmp_path)["cpu_seconds"] == 12.5


@pytest.mark.parametrize("record", ['{"cpu_seconds": "abc"}', '{"cpu_seconds": -3}', '{"steps": 1.5}', '[1, 2]',
                                    '{"threads": ["x"]}', "not json"])
def test_a_malformed_compute_record_is_named_and_set_aside(tmp_path, record):
    (tmp_path / "compute.json").write_text(record)
    with pytest.warns(UserWarning, match="compute.json.*damaged"):
        assert read_compute(tmp_path) == {}


def test_a_score_cache_reads_back_for_its_checkpoint_and_test_set(tmp_path):
    path = tmp_path / "scores.json"
    _write_scores(path, [1, 2], ROWS)
    assert _read_scores(path, [1, 2], ["ball_low"]) == ROWS
    assert _read_scores(path, [1, 3], ["ball_low"]) is None  # another checkpoint: not this run's scores


def test_a_checkpoint_swapped_with_the_same_size_and_time_is_scored_again(tmp_path):
    """`cp -p` of other weights over a run's best.pt keeps its size and time: the kept scores were the
    old weights'. The stamp holds the content's hash, so they are not used."""
    import os
    ckpt, path = tmp_path / "best.pt", tmp_path / "scores.json"
    ckpt.write_bytes(b"weights A" * 100)
    _write_scores(path, _checkpoint_stamp(ckpt), ROWS)
    assert _read_scores(path, _checkpoint_stamp(ckpt), ["ball_low"]) == ROWS
    st = ckpt.stat()
    ckpt.write_bytes(b"weights B" * 100)
    os.utime(ckpt, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert ckpt.stat().st_size == st.st_size and ckpt.stat().st_mtime_ns == st.st_mtime_ns
    assert _read_scores(path, _checkpoint_stamp(ckpt), ["ball_low"]) is None


@pytest.mark.parametrize("edit", [
    lambda d: d["rows"][0].update(frames=-5), lambda d: d["rows"][0].update(psnr="x"), lambda d: d.update(rows=[]),
    lambda d: d["rows"][0].update(scene="unknown_scene"), lambda d: d["rows"][0].pop("psnr")])
def test_an_edited_score_cache_is_named_and_scored_again(tmp_path, edit):
    path = tmp_path / "scores.json"
    _write_scores(path, [1, 2], ROWS)
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    with pytest.warns(UserWarning, match="scores.json.*malformed score cache"):
        assert _read_scores(path, [1, 2], ["ball_low"]) is None


def test_a_score_cache_from_before_the_aligned_ssim_is_scored_again(tmp_path):
    """A cache without a metric the tables now show would print nan in its column."""
    import json
    path = tmp_path / "scores.json"
    _write_scores(path, [1, 2], ROWS)
    data = json.loads(path.read_text())
    for row in data["rows"]:
        del row["ssim_aligned"]
    path.write_text(json.dumps(data))
    assert _read_scores(path, [1, 2], ["ball_low"]) is None
