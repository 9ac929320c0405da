"""Each finished scene of a generation is logged with its time, the estimate's, and the time left at
the measured pace: the only progress a run logged to a file shows (bars need a terminal)."""
from __future__ import annotations

import logging

import pytest

from spikesim.generation import PRESETS, generate, plan_rllr
from spikesim.generation.pace import Pace


def test_the_time_left_is_the_estimates_remaining_work_at_the_measured_pace():
    pace = Pace(total=4, workers=2, estimated_s={"a": 100.0, "b": 50.0, "c": 200.0, "d": 100.0})
    assert pace.left_s() is None  # nothing finished: no pace yet
    line = pace.finished({"name": "a", "seconds": 150.0})
    assert line.startswith("a done in 150.0 s (estimated 100.0 s); 1 of 4 scene(s) done")
    # 1.5x the estimate so far: (50 + 200 + 100) x 1.5 over 2 workers
    assert pace.left_s() == pytest.approx(350 * 1.5 / 2)
    assert "about 4.4 min left on 2 worker(s)" in line and "x 1.50" in line
    line = pace.finished({"name": "b", "seconds": 25.0})  # (150 + 25) / (100 + 50)
    assert "about 2.9 min left" in line  # (200 + 100) x 175 / 150 over 2 workers: 175 s
    pace.finished({"name": "c", "seconds": 200.0})
    # one scene left: it runs on one worker, whatever the count
    assert pace.left_s() == pytest.approx(100 * (375 / 350))
    last = pace.finished({"name": "d", "seconds": 90.0})
    assert last == "d done in 90.0 s (estimated 100.0 s); 4 of 4 scene(s) done"


def test_without_an_estimate_a_scene_says_its_time_and_the_count():
    pace = Pace(total=2)
    assert pace.finished({"name": "x", "seconds": 3.25}) == "x done in 3.2 s; 1 of 2 scene(s) done"
    assert pace.left_s() is None
    short = Pace(total=2, estimated_s={"a": 10.0, "b": 20.0})
    assert "about 20 s left" in short.finished({"name": "a", "seconds": 10.0})  # under a minute: seconds
    with pytest.raises(ValueError, match="workers 0"):
        Pace(total=1, workers=0)


@pytest.mark.parametrize("workers", [1, 2])
def test_generate_logs_each_finished_scene_with_the_estimates_figure(tmp_path, caplog, workers):
    preset = PRESETS["small"].replace(height=12, width=32, rllr_steps=82, rllr_gt_stride=41)
    jobs = plan_rllr(preset, seed=1, count=2, source="pattern")
    with caplog.at_level(logging.INFO, logger="spikesim.generate"):
        generate(jobs, tmp_path, workers=workers, show_progress=False, estimate_time=True)
    done = [r.getMessage() for r in caplog.records if " done in " in r.getMessage()]
    assert sorted(m.split()[0] for m in done) == ["rllr_0000", "rllr_0001"]
    assert all("(estimated " in m for m in done)
    assert done[-1].endswith("2 of 2 scene(s) done") and " left on " in done[0]
