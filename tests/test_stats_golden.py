"""Stream statistics against hand-computed values, and the realistic preset against its stored
golden statistics (tolerances: 5 combined standard errors from batch means)."""
import json

import numpy as np
import pytest

from pipelines import golden_stats
from spikesim.stats import (dark_count_rate_hz, dark_pixel_fraction, fano_factor, firing_rate,
                            fixed_pattern_spread, inter_spike_intervals, isi_histogram, summary)
from spikesim.stream import SpikeStream

from sensor_testing import BACKENDS


def hand_stream():
    # pixel (0,0): spikes at 0, 3, 7; pixel (0,1): at 5; pixel (1,*): none.  10 steps, 2x2.
    s = np.zeros((10, 2, 2), bool)
    s[[0, 3, 7], 0, 0] = True
    s[5, 0, 1] = True
    return SpikeStream.from_bool(s)


def test_hand_computed_statistics():
    s = hand_stream()
    assert np.array_equal(firing_rate(s), [[0.3, 0.1], [0.0, 0.0]])
    assert sorted(inter_spike_intervals(s, chunk=4)) == [3, 4]  # chunking must not lose intervals
    assert isi_histogram(s, max_isi=3).tolist() == [0, 0, 0, 2]
    assert dark_pixel_fraction(s) == 0.5
    assert dark_pixel_fraction(s, window=5) == pytest.approx((3 / 4 + 2 / 4) / 2)
    assert dark_count_rate_hz(s, 25e-6) == pytest.approx(0.1 / 25e-6)
    c = np.array([[2, 0], [1, 1]], float)  # window counts of the two firing pixels, windows of 5
    assert fano_factor(s, 5) == pytest.approx(np.mean(c.var(axis=0, ddof=1) / c.mean(axis=0)))
    assert fixed_pattern_spread(s) == pytest.approx(np.std([0.3, 0.1, 0, 0]) / 0.1)
    summ = summary(s, window=5)
    assert summ["spikes"] == 4 and summ["isi_steps"]["count"] == 2 and summ["isi_steps"]["max"] == 4


def test_golden_file_is_consistent_with_its_config():
    g = golden_stats.load_golden()
    assert g["config"]["camera"] == golden_stats.golden_camera().to_dict()
    assert g["config"]["num_steps"] == golden_stats.NUM_STEPS
    # dark band: mean dark count rate close to the configured 94 Hz, spread close to 39 %
    dark = g["stats"]["y=0"]
    assert dark["rate_per_step"]["value"] / 25e-6 == pytest.approx(94.0, rel=0.05)
    assert dark["rate_cv"]["value"] == pytest.approx(0.39, abs=4 * dark["rate_cv"]["se"])


@pytest.mark.parametrize("backend", BACKENDS)
def test_realistic_preset_matches_golden_statistics(backend):
    problems = golden_stats.compare(golden_stats.measure(backend), golden_stats.load_golden())
    assert not problems, "\n".join(problems)


def test_compare_detects_a_moved_statistic():
    g = golden_stats.load_golden()
    moved = json.loads(json.dumps(g))
    e = moved["stats"]["y=0.03"]["rate_per_step"]
    e["value"] += 10 * e["se"]
    assert any("rate_per_step" in p for p in golden_stats.compare(moved, g))
