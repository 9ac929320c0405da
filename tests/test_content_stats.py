"""The content statistics of docs/scenes.md: normal flow, edge density, brightness."""
from __future__ import annotations

import numpy as np
import pytest

from pipelines.content_stats import dataset_summary, edge_density, image_statistics, normal_flow_px


def _edge_image(shift: float = 0.0) -> np.ndarray:
    """Smooth vertical bars (a sine along x) moved right by `shift` pixels."""
    x = np.arange(96)[None, :] - shift
    return np.repeat(0.3 + 0.2 * np.sin(2 * np.pi * x / 24.0), 64, axis=0)


def test_normal_flow_of_a_known_shift():
    """A pattern moved by d pixels over n steps flows at d / n pixels per step (to first order in d)."""
    flow = normal_flow_px(_edge_image(0.0), _edge_image(0.5), 41)
    assert flow == pytest.approx(0.5 / 41, rel=0.1)
    assert normal_flow_px(_edge_image(), _edge_image(), 41) == 0.0
    assert normal_flow_px(np.zeros((16, 16)), np.zeros((16, 16)), 41) == 0.0


def test_edge_density_ignores_the_light_level():
    rng = np.random.default_rng(0)
    from scipy.ndimage import gaussian_filter
    img = gaussian_filter(rng.random((96, 96)), 3) + 0.1
    assert edge_density(img) == pytest.approx(edge_density(img * 0.01), rel=0.02)
    assert edge_density(np.full((64, 64), 0.2)) == 0.0
    assert edge_density(img) > 0.005


def test_image_statistics_and_summary():
    y = np.linspace(0, 2, 100 * 100).reshape(100, 100)
    s = image_statistics(y)
    assert s["p99_y"] == 1.0  # clipped at saturation, as every score is
    assert 0.7 < s["mean_y"] < 0.8
    summary = dataset_summary([{**s, "motion_px_per_step": 0.1}, {**s, "motion_px_per_step": float("nan")}])
    assert summary["motion_px_per_step"] == {"median": 0.1, "min": 0.1, "max": 0.1}


def test_lit_textured_fraction_counts_the_textured_lit_share_of_the_frame_whatever_its_light():
    from pipelines.content_stats import lit_textured_fraction
    rng = np.random.default_rng(0)
    img = np.zeros((64, 64))
    img[:, :32] = 0.5 * (1 + 0.5 * rng.standard_normal((64, 32)))  # lit, textured: half the blocks
    assert lit_textured_fraction(img) == pytest.approx(0.5)
    assert lit_textured_fraction(img * 1e-3) == pytest.approx(0.5)  # no dependence on the light level
    flat = np.full((64, 64), 0.3)
    assert lit_textured_fraction(flat) == 0.0  # lit but flat
    assert lit_textured_fraction(np.zeros((64, 64))) == 0.0
