"""The three metric conventions (ours, the authors' 8-bit one, light-normalised) and evaluate's
tables by light condition."""
from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import uniform_filter

sys.path.insert(0, str(Path(__file__).parent / "model"))  # modeltest_fakes

from model.metrics import (METRICS, light_level, psnr, psnr_8bit, psnr_norm, quantise_8bit, ssim,  # noqa: E402
                           ssim_8bit, ssim_norm)
from modeltest_fakes import make_scene  # noqa: E402


def test_8bit_quantisation_truncates_after_clipping():
    y = np.array([-0.5, 0.0, 0.0039, 1 / 255, 0.5, 0.999, 1.0, 7.0])
    np.testing.assert_array_equal(quantise_8bit(y), [0, 0, 0, 1, 127, 254, 255, 255])
    assert quantise_8bit(y).dtype == np.uint8


def test_8bit_psnr_by_hand():
    gt = np.full((8, 8), 0.5)          # -> 127
    pred = np.full((8, 8), 0.52)       # -> 132
    assert psnr_8bit(pred, gt) == pytest.approx(10 * math.log10(255 ** 2 / 25))
    assert psnr_8bit(gt + 0.001, gt) == math.inf  # the same 8-bit image


def _ssim_7x7_reference(a: np.ndarray, b: np.ndarray) -> float:
    """Wang et al.'s SSIM with a 7x7 uniform window, sample covariance, data range 255, averaged
    over the windows that lie inside the image: scikit-image's defaults, written out."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    n = 49
    mu_a, mu_b = uniform_filter(a, 7), uniform_filter(b, 7)
    cov = n / (n - 1)
    va = cov * (uniform_filter(a * a, 7) - mu_a ** 2)
    vb = cov * (uniform_filter(b * b, 7) - mu_b ** 2)
    vab = cov * (uniform_filter(a * b, 7) - mu_a * mu_b)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    s = ((2 * mu_a * mu_b + c1) * (2 * vab + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (va + vb + c2))
    return float(s[3:-3, 3:-3].mean())


def test_8bit_ssim_is_the_7x7_uniform_window_on_8_bit_images():
    rng = np.random.default_rng(1)
    gt = rng.uniform(0, 1, (20, 24))
    pred = np.clip(gt + rng.normal(0, 0.05, gt.shape), 0, 1.2)
    want = _ssim_7x7_reference(quantise_8bit(pred), quantise_8bit(gt))
    assert ssim_8bit(pred, gt) == pytest.approx(want, abs=1e-9)
    with pytest.raises(ValueError, match="7x7"):
        ssim_8bit(gt[:6], gt[:6])


def test_an_all_black_image_scores_high_on_a_dark_scene_except_light_normalised():
    rng = np.random.default_rng(2)
    dark = rng.uniform(0, 0.006, (32, 32))   # low light: y of a few thousandths
    black = np.zeros_like(dark)
    assert psnr_8bit(black, dark) > 45 and psnr(black, dark) > 45
    assert psnr_norm(black, dark) < 10
    assert ssim_norm(black, dark) < 0.1 < ssim(black, dark)


def test_light_normalised_scores_do_not_depend_on_the_light_level():
    rng = np.random.default_rng(3)
    gt = rng.uniform(0, 0.8, (24, 24))
    pred = np.clip(gt + rng.normal(0, 0.03, gt.shape), 0, 1)
    s = 0.01  # the same scene with 100 times less light
    assert psnr_norm(pred * s, gt * s) == pytest.approx(psnr_norm(pred, gt), abs=1e-6)
    assert ssim_norm(pred * s, gt * s) == pytest.approx(ssim_norm(pred, gt), abs=1e-6)
    assert psnr(pred * s, gt * s) > psnr(pred, gt) + 30  # ours is not normalised
    assert light_level(gt) == pytest.approx(np.percentile(gt, 99.5))
    assert light_level(np.zeros((4, 4))) > 0


def test_every_metric_is_listed_for_evaluate():
    assert list(METRICS) == ["psnr", "ssim", "psnr_8bit", "ssim_8bit", "psnr_norm", "ssim_norm", "psnr_aligned",
                             "ssim_aligned"]


def test_evaluate_reports_low_then_normal_then_all(tmp_path):
    from model.methods import MapMethod
    from pipelines import evaluate as ev
    scenes = [make_scene("ball_low", 12, 16, 7 * 3, brightness=0.01, seed=1),
              make_scene("ball_normal", 12, 16, 7 * 3, brightness=0.3, seed=2),
              make_scene("fan_low", 12, 16, 7 * 2, brightness=0.02, seed=3)]
    methods = [MapMethod("TFP", "tfp", 7), MapMethod("TFI", "tfi", 7)]
    rows = ev.evaluate(scenes, methods, 7, progress=False)
    by = {(r.scene, r.method): r for r in rows}
    assert [r.scene for r in rows[-6:]] == ["ALL_low"] * 2 + ["ALL_normal"] * 2 + ["ALL"] * 2
    low = [by[("ball_low", "TFP")], by[("fan_low", "TFP")]]
    assert by[("ALL_low", "TFP")].frames == 3 + 2 and by[("ALL", "TFP")].frames == 8
    for key in METRICS:
        want = sum(r.value(key) * r.frames for r in low) / 5
        assert by[("ALL_low", "TFP")].value(key) == pytest.approx(want)
    table = ev.markdown_table(rows, ["TFP", "TFI"])
    i_low, i_normal, i_all = (table.index(t) for t in ("**Low light** (5 frames)", "**Normal light** (3 frames)",
                                                       "**All scenes** (8 frames)"))
    assert i_low < i_normal < i_all
    assert "| PSNR 8-bit |" in table and "| SSIM light-norm. |" in table and "floor(255 y)" in table
    csv_path, _ = ev.write_results(rows, ["TFP", "TFI"], tmp_path)
    head = next(csv.reader(csv_path.open()))
    assert head == ["scene", "method", "psnr", "ssim", "psnr_8bit", "ssim_8bit", "psnr_norm", "ssim_norm", "psnr_aligned",
                    "ssim_aligned", "frames"]
    assert ev.light_condition("rllr_0001") is None and ev.light_condition("car_normal") == "normal"


def test_aligned_psnr_floor_is_shared_by_every_image_without_structure():
    rng = np.random.default_rng(3)
    gt = rng.random((32, 48)) * 0.01
    from model.metrics import light_level, psnr_aligned
    floor = 20 * np.log10(light_level(gt) / gt.std())
    for flat in (np.zeros_like(gt), np.full_like(gt, 0.3), np.full_like(gt, gt.mean())):
        assert psnr_aligned(flat, gt) == pytest.approx(floor, abs=1e-9)
    # any image correlated with the ground truth scores 10 log10(1 / (1 - rho^2)) above the floor,
    # whatever its gain or offset
    noisy = 5.0 * (gt + rng.normal(0, 0.01, gt.shape)) + 0.1
    rho = np.corrcoef(np.clip(noisy, 0, 1).ravel(), gt.ravel())[0, 1]
    assert psnr_aligned(noisy, gt) == pytest.approx(floor + 10 * np.log10(1 / (1 - rho ** 2)), rel=1e-9)


@pytest.mark.parametrize("light", [1e-4, 1e-2, 1.0])
def test_aligned_ssim_gives_every_image_without_structure_zero_at_every_light_level(light):
    from model.metrics import ssim, ssim_aligned
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:40, 0:56]
    gt = light * (0.2 + 0.6 * (np.sin(xx / 3.0) * np.cos(yy / 5.0) > 0) + 0.1 * rng.random((40, 56)))
    gt[:, :20] = light * 0.05  # a flat region, where plain SSIM rewards anything flat
    noisy = np.clip(gt + rng.normal(0, 0.1 * light, gt.shape), 0, 1)
    black, const = np.zeros_like(gt), np.full_like(gt, 0.37)
    assert ssim_aligned(black, gt) == pytest.approx(0.0, abs=1e-9)
    assert ssim_aligned(const, gt) == pytest.approx(0.0, abs=1e-9)
    assert abs(ssim_aligned(rng.random(gt.shape), gt)) < 0.05  # uncorrelated: the fit maps it near the constant
    assert ssim_aligned(gt, gt) == pytest.approx(1.0)
    assert ssim_aligned(gt * 0.3 + 0.1, gt) == pytest.approx(1.0, abs=1e-6)  # gain and offset are not structure
    assert 0.1 < ssim_aligned(noisy, gt) < 1.0
    if light <= 1e-4:  # the failure it fixes: in low light plain SSIM gives black nearly full marks
        assert ssim(black, gt) > 0.95


@pytest.mark.parametrize("light", [1e-3, 0.3])
def test_a_negative_of_the_truth_scores_the_floor_not_the_truth(light):
    """A free gain sign mapped an inverted image onto the truth: psnr_aligned inf and ssim_aligned
    1.0 for max + min - gt (round eight). The gain is at least 0, so it scores as the constant."""
    from scipy.ndimage import gaussian_filter

    from model.metrics import light_level, psnr_aligned, ssim_aligned
    gt = light * gaussian_filter(np.random.default_rng(1).uniform(0.1, 0.5, (32, 32)), 2)
    negative = gt.max() + gt.min() - gt
    floor = 20 * np.log10(light_level(gt) / gt.std())
    assert psnr_aligned(negative, gt) == pytest.approx(floor, abs=1e-9)
    assert ssim_aligned(negative, gt) == pytest.approx(0.0, abs=1e-12)
    noisy_negative = negative + np.random.default_rng(2).normal(0, 0.02 * light, gt.shape)
    assert psnr_aligned(noisy_negative, gt) == pytest.approx(floor, abs=1e-9)
    assert ssim_aligned(noisy_negative, gt) == pytest.approx(0.0, abs=1e-12)
    assert psnr_aligned(gt, gt) == math.inf and ssim_aligned(gt, gt) == pytest.approx(1.0)


def test_aligned_ssim_of_a_flat_ground_truth_is_one():
    from model.metrics import ssim_aligned
    assert ssim_aligned(np.random.default_rng(0).random((16, 16)), np.full((16, 16), 0.2)) == 1.0


def test_affine_ssim_equals_scikit_image_on_the_aligned_image():
    from skimage.metrics import structural_similarity
    from model.metrics import AffineSSIM, light_level
    rng = np.random.default_rng(5)
    gt = rng.random((30, 37)) * 0.2
    pred = np.clip(gt + rng.normal(0, 0.05, gt.shape), 0, 1)
    fast = AffineSSIM(pred, gt, light_level(gt))
    for gain in (0.0, 0.4, 1.3, -0.7):
        aligned = gt.mean() + gain * (pred - pred.mean())
        want = structural_similarity(aligned, gt, data_range=light_level(gt), gaussian_weights=True, sigma=1.5,
                                     use_sample_covariance=False)
        assert fast(gain) == pytest.approx(want, abs=1e-10)


def test_aligned_ssim_never_scores_a_noisy_image_below_the_floor():
    from model.metrics import ssim_aligned
    rng = np.random.default_rng(8)
    gt = 1e-3 * (0.5 + 0.5 * np.sin(np.mgrid[0:48, 0:64][1] / 4.0))
    for noise in (1e-4, 1e-3, 1e-2):  # from faithful to no structure left
        pred = np.clip(gt + rng.normal(0, noise, gt.shape), 0, 1)
        assert ssim_aligned(pred, gt) >= 0.0
    faithful = ssim_aligned(np.clip(gt + rng.normal(0, 1e-4, gt.shape), 0, 1), gt)
    drowned = ssim_aligned(np.clip(gt + rng.normal(0, 1e-2, gt.shape), 0, 1), gt)
    assert faithful > 0.5 > drowned
