"""No-reference measures (model/noref.py) against images whose noise and sharpness are known."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from model.noref import edge_mask, edge_sharpness, flat_blocks, flat_noise, no_reference_scores


def _scene(h: int = 96, w: int = 128) -> np.ndarray:
    """A flat bright left half, a flat darker right half: one vertical edge."""
    img = np.full((h, w), 0.2)
    img[:, w // 2:] = 0.05
    return img


def test_flat_noise_is_the_coefficient_of_variation_of_added_noise():
    ref = _scene()
    rng = np.random.default_rng(0)
    noisy = ref * (1 + 0.1 * rng.standard_normal(ref.shape))
    blocks = flat_blocks(ref, block=16, fraction=0.5)
    assert flat_noise(noisy, blocks) == pytest.approx(0.1, rel=0.1)
    assert flat_noise(ref, blocks) == pytest.approx(0.0, abs=1e-12)
    # brightness scale does not matter
    assert flat_noise(7 * noisy, blocks) == pytest.approx(flat_noise(noisy, blocks))


def test_flat_blocks_avoid_the_edge_and_the_dark():
    ref = _scene()
    ref[:32, :32] = 0.0  # a black corner: flat, but nothing there to measure
    for ys, xs in flat_blocks(ref, block=16, fraction=0.3):
        assert not (xs.start < 64 <= xs.stop - 1) and ref[ys, xs].mean() > 0


def test_sharpness_falls_with_blur_and_ignores_scale():
    ref = _scene()
    mask = edge_mask(ref, fraction=0.05)
    sharp = [edge_sharpness(gaussian_filter(ref, s), mask) for s in (0.5, 1.5, 3.0)]
    assert sharp[0] > sharp[1] > sharp[2] > 0
    assert edge_sharpness(3 * ref, mask) == pytest.approx(edge_sharpness(ref, mask))
    scores = no_reference_scores(gaussian_filter(ref, 1.0) * (1 + 0.05 * np.random.default_rng(1).standard_normal(ref.shape)), ref)
    assert scores["edge_to_noise"] == pytest.approx(scores["edge_sharpness"] / scores["flat_noise"])


def test_bad_reference_is_refused():
    with pytest.raises(ValueError, match="2-D image"):
        flat_blocks(np.zeros((8, 8)), block=16)
    with pytest.raises(ValueError, match="fraction"):
        flat_blocks(_scene(), fraction=0)


def test_a_reference_without_light_is_refused_and_one_without_edges_gives_nan_quietly():
    """An all-zero recording gave flat noise inf, edge sharpness NaN and NumPy warnings in `panel`
    (round eight)."""
    import warnings

    from model.noref import no_reference_scores
    black = np.zeros((32, 32))
    with pytest.raises(ValueError, match="holds no spike"):
        no_reference_scores(black, black)
    flat = np.full((32, 32), 0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scores = no_reference_scores(flat + np.random.default_rng(0).normal(0, 0.01, flat.shape), flat)
    assert np.isnan(scores["edge_sharpness"]) and scores["flat_noise"] > 0


def test_the_floors_get_no_score_rather_than_a_winning_one():
    """panel gave the constant `mean` floor an edge/noise of inf, above every real method (round nine)."""
    ref = _scene()
    for floor in (np.zeros_like(ref), np.full_like(ref, 0.1)):
        scores = no_reference_scores(floor, ref)
        assert np.isnan(scores["edge_to_noise"])
    noisy = ref + np.random.default_rng(0).normal(0, 0.01, ref.shape)
    assert np.isfinite(no_reference_scores(noisy, ref)["edge_to_noise"])
