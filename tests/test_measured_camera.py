"""The fixed-pattern terms measured on a real recording (SpikeCamera.measured): their maps, their
effect on the stream, their validation, and the identity of cameras without them."""
from __future__ import annotations

import math

import numpy as np
import pytest

from spikesim.camera import LATER_TERMS, MEASURED_TERMS, SpikeCamera
from spikesim.fixed_pattern import draw_pixel_parameters
from spikesim.quality import noise_effect
from spikesim.simulate import Simulator

H, W = 120, 160


def _gain(**terms) -> np.ndarray:
    cam = SpikeCamera.noiseless(height=H, width=W, **terms)
    return draw_pixel_parameters(cam, seed=3).gain.astype(np.float64).reshape(H, W)


def _sd_bound(sigma: float, n: int) -> float:
    """5 standard errors of a sample standard deviation of n normal draws: sigma / sqrt(2 (n - 1))."""
    return 5 * sigma / math.sqrt(2 * (n - 1))


def test_row_gain_is_one_factor_per_row():
    g = _gain(row_gain_spread=0.1)
    assert np.allclose(g, g[:, :1])  # constant along each row
    assert abs(g[:, 0].std(ddof=1) - 0.1) < _sd_bound(0.1, H) and abs(g.mean() - 1) < 5 * 0.1 / math.sqrt(H)


def test_column_gain_is_one_factor_per_column():
    g = _gain(column_gain_spread=0.1)
    assert np.allclose(g, g[:1, :])
    assert abs(g[0].std(ddof=1) - 0.1) < _sd_bound(0.1, W)


def test_outlier_pixels_fraction_and_spread():
    f, sigma = 0.12, 0.4
    g = _gain(outlier_pixel_fraction=f, outlier_gain_spread=sigma)
    moved = g != 1.0
    n = g.size
    assert abs(moved.mean() - f) < 5 * math.sqrt(f * (1 - f) / n)
    # clipped at 0: with sigma 0.4 that is 0.6 % of the outliers, a negligible bias of the spread
    assert abs(g[moved].std(ddof=1) - sigma) < _sd_bound(sigma, int(moved.sum())) + 0.01


def test_terms_multiply_the_published_gain():
    """With PRNU on, each new term multiplies it: the published gain map is the one drawn without them."""
    base = draw_pixel_parameters(SpikeCamera.realistic(height=H, width=W), seed=5).gain.astype(np.float64)
    both = draw_pixel_parameters(SpikeCamera.realistic(height=H, width=W, row_gain_spread=0.05), seed=5).gain
    ratio = (both / base).reshape(H, W)
    assert np.allclose(ratio, ratio[:, :1], rtol=1e-5)


def test_row_gain_changes_each_rows_rate_as_analysed():
    """An integrate-and-fire pixel without noise fires at rate g y: a row's rate is y times its gain."""
    cam = SpikeCamera.noiseless(height=16, width=24, row_gain_spread=0.2)
    y, steps = 0.2, 2000
    stream = Simulator(cam, backend="numpy", seed=1).run(np.full((steps, 16, 24), y, np.float32))
    rate = stream.counts().reshape(16, 24).mean(axis=1) / steps
    gain = draw_pixel_parameters(cam, seed=1).gain.reshape(16, 24)[:, 0]
    assert np.allclose(rate, y * gain, atol=1.0 / steps)  # one spike of quantisation per pixel


def test_measured_preset_and_round_trips():
    m = SpikeCamera.measured()
    for k, v in MEASURED_TERMS.items():
        assert getattr(m, k) == v
    assert SpikeCamera.from_dict(m.to_dict()) == m
    assert SpikeCamera.from_dict({"preset": "measured", "height": 10}) == SpikeCamera.measured(height=10)
    assert SpikeCamera.preset("measured") == m


def test_cameras_without_the_terms_keep_their_dictionary():
    """Recorded only when on: a camera made before them has the same dictionary (dataset identity)."""
    d = SpikeCamera.realistic().to_dict()
    assert not set(LATER_TERMS) & set(d)
    assert set(LATER_TERMS) <= set(SpikeCamera.measured().to_dict())


def test_without_switches_the_outlier_pair_together():
    cam = SpikeCamera.measured().without("outlier_gain_spread")
    assert cam.outlier_pixel_fraction == 0 and cam.outlier_gain_spread == 0
    assert SpikeCamera.measured().without(*LATER_TERMS).to_dict().keys() == SpikeCamera.realistic().to_dict().keys()


@pytest.mark.parametrize("fields, message", [
    ({"row_gain_spread": -0.1}, "row_gain_spread"),
    ({"column_gain_spread": 0.5}, "column_gain_spread"),
    ({"outlier_pixel_fraction": 0.1}, "go together"),
    ({"outlier_gain_spread": 0.1}, "go together"),
    ({"outlier_pixel_fraction": 1.5, "outlier_gain_spread": 0.1}, "fraction of the pixels"),
    ({"outlier_pixel_fraction": float("nan"), "outlier_gain_spread": 0.1}, "outlier_pixel_fraction"),
])
def test_bad_values_are_named(fields, message):
    with pytest.raises(ValueError, match=message):
        SpikeCamera(**fields)


def test_noise_effect_of_the_new_terms():
    m = SpikeCamera.measured()
    d = m.dark_per_step
    y = 0.3
    assert noise_effect(m, "row_gain_spread", y) == pytest.approx(0.015 * y / (y + d))
    assert noise_effect(m, "outlier_pixel_fraction", y) == pytest.approx(math.sqrt(0.12) * 0.4 * y / (y + d))
    assert noise_effect(SpikeCamera.realistic(), "row_gain_spread", y) == 0.0


@pytest.mark.parametrize("fields, message", [
    ({"threshold_electrons": 1e-300}, "not a pixel's threshold"),
    ({"threshold_electrons": 5.0}, "10 to 1e\\+08"),
    ({"threshold_electrons": 1e9}, "not a pixel's threshold"),
    ({"readout_period_s": 1e-9}, "not a sensor readout period"),
    ({"readout_period_s": 2.0}, "not a sensor readout period"),
])
def test_physical_ranges_of_the_cameras_scales(fields, message):
    """A threshold of 1e-300 electrons passed and made every pixel fire once and stop (rc 0)."""
    with pytest.raises(ValueError, match=message):
        SpikeCamera(**fields)
    SpikeCamera(threshold_electrons=10.0, readout_period_s=1e-7)  # the ends are physical


def test_golden_says_an_undefined_statistic_in_words():
    from pipelines.golden_stats import UNDEFINED, _table
    from spikesim.golden import Row

    text = _table([Row("dark", "isi_cv", math.nan, 0.5, math.inf, False)], 3.0)
    assert "undefined" in text and UNDEFINED in text and "nan" not in text and "inf" not in text
