"""Numerical stability at the extremes (issue 6): light from 0 to far past saturation, streams
chunked up to 10^7 steps, float32 against float64, extreme light powers through the renderer,
interpolation over long keyframe intervals, and the model's representations and input
normalisation on all-zero and all-one streams. Each extreme is a test; tiny pixel counts keep
them fast (long streams use two keyframes far apart on the LLVM backend)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from spikesim.camera import SpikeCamera
from spikesim.simulate import Simulator

from sensor_testing import HAS_LLVM, requires_llvm

#: 31 light levels from 1e-6 to 1e6 spikes per step plus a dark pixel: one 32-pixel SIMD lane.
LEVELS = np.concatenate([[0.0], np.logspace(-6, 6, 31)]).astype(np.float32)[None, :]
BACKEND = "llvm" if HAS_LLVM else "numpy"


def _constant(camera: SpikeCamera, y: np.ndarray, n: int, seed: int = 0, chunk: int = 1 << 16,
              pieces: int = 1) -> tuple[np.ndarray, Simulator]:
    """Counts after n steps of constant light y: keyframes n / pieces apart, streamed in pieces
    with final=False (a chunked stream), as a long recording would be simulated."""
    sim = Simulator(camera, backend=BACKEND, seed=seed, chunk_steps=chunk)
    k = n // pieces
    counts = np.zeros(y.shape, np.int64)
    steps = 0
    for p in range(pieces):
        frames = [y, y] if p == 0 else [y]
        for part in sim.stream(frames, keyframe_every=k, final=False):
            counts += part.counts()
            steps += part.num_steps
    for part in sim.stream([], keyframe_every=k, final=True):  # the last keyframe's own step
        counts += part.counts()
        steps += part.num_steps
    assert steps == n + 1
    return counts, sim


@requires_llvm
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_noiseless_rate_is_min_y_plus_d_from_dark_to_1e6(precision):
    # docs/design.md section 2: with constant light and no noise the long-run rate is exactly y + d,
    # at most one spike per step (saturation). 10^5 steps, 0 to 1e6 spikes/step.
    n = 100_000
    cam = SpikeCamera.noiseless(height=1, width=32, dark_current_hz=94.0, precision=precision)
    counts, sim = _constant(cam, LEVELS, n)
    expected = np.floor((n + 1) * np.minimum(LEVELS.astype(np.float64) + cam.dark_per_step, 1.0))
    # float64: within one spike; float32: plus the rounding of n additions of <= 2^-24 relative
    tol = 1 if precision == "float64" else 1 + (n + 1) * 2.0 ** -24 * 2
    assert np.all(np.abs(counts - expected) <= tol), np.abs(counts - expected).max()
    acc = sim.get_state()["accumulator"]
    assert np.all(np.isfinite(acc)) and acc.max() <= 2.0 + 1e-6 and acc.min() >= -1.0 - 1e-6


@requires_llvm
@pytest.mark.slow
def test_ten_million_steps_chunked_match_floor_n_y():
    # 10^7 steps in ten chunked pieces (final=False between them): no drift, no overflow; the
    # counts stay floor(N (y + d)) within the float32 tolerance above.
    n = 10_000_000
    cam = SpikeCamera.noiseless(height=1, width=32, dark_current_hz=94.0, precision="float32")
    counts, sim = _constant(cam, LEVELS, n, chunk=1 << 20, pieces=10)
    expected = np.floor((n + 1) * np.minimum(LEVELS.astype(np.float64) + cam.dark_per_step, 1.0))
    assert sim.steps_done == n + 1
    assert np.all(np.abs(counts - expected) <= 1 + (n + 1) * 2.0 ** -24 * 2)
    assert counts.max() == n + 1  # saturated pixels fired at every step


@requires_llvm
def test_a_million_chunked_steps_realistic_rate_matches_the_pixel_parameters():
    # Realistic camera, 10^6 steps chunked: every pixel's rate is set by its own gain g, dark
    # current d and threshold theta (drawn per pixel). With the reset loss r (the step after a
    # spike integrates (1 - r) e), the charge per step is e (1 - r rate), so
    # rate = x / (1 + r x), x = (g y + d) / theta, capped at 1 (docs/sensor.md's update). Shot and
    # comparator noise conserve charge, so they leave the mean; the count's spread is the charge's:
    # Poisson, variance (N rate) / N_e thresholds^2 (N_e electrons per threshold). Tolerance: 6 of
    # those standard deviations + 2 (the comparator's and the initial state's residual). Without
    # the reset-loss term the mid-range pixels miss by r x^2 N ~ 500 spikes at x = 0.5: caught.
    n = 1_000_000
    cam = SpikeCamera.realistic(height=1, width=32)
    counts, sim = _constant(cam, LEVELS, n, pieces=4)
    p = sim.params
    y = LEVELS[0].astype(np.float64)
    x = (p.gain * y + p.dark_per_step) / p.threshold
    rate = np.minimum(x / (1 + cam.reset_loss * x), 1.0)
    expected = (n + 1) * rate
    assert np.all(np.isfinite(counts))
    tol = 6 * np.sqrt((n + 1) * rate / cam.threshold_electrons) + 2
    assert np.all(np.abs(counts[0] - expected) <= tol), (counts[0] - expected)[np.abs(counts[0] - expected) > tol]


@requires_llvm
@pytest.mark.parametrize("shot", ["gaussian", "renewal"])
def test_float32_within_two_spikes_of_float64_over_a_million_noisy_steps(shot):
    # Same seed: identical fixed patterns and temporal noise; the accumulator's rounding can move
    # a spike across a step boundary but charge is conserved, so the counts differ by at most
    # 1 + N * 2^-24 * |A|max (A in [-1, 2]) = 1.1 -> 2 spikes over 10^6 steps. The renewal model
    # counts its threshold charges by spike, not by step, so a moved spike keeps every later
    # interval's charge.
    n = 1_000_000
    c32, _ = _constant(SpikeCamera.realistic(height=1, width=32, precision="float32", shot_noise=shot), LEVELS, n, seed=3)
    c64, _ = _constant(SpikeCamera.realistic(height=1, width=32, precision="float64", shot_noise=shot), LEVELS, n, seed=3)
    assert np.abs(c32 - c64).max() <= 2
    assert c64.max() == n + 1 and c64.min() > 0  # the sweep reaches saturation and fires in the dark


@pytest.mark.parametrize("k", [1_000, 1_000_000])
def test_interpolated_ramp_counts_its_integral(k):
    # A linear ramp from y = 0 to 2 over k steps (two keyframes): the sensor integrates
    # min(y_n, 1) per step (charge above one spike per step is dropped), so the count is that sum
    # within two spikes; the interpolation weight (n mod k) / k stays exact at k = 10^6.
    if k > 10_000 and not HAS_LLVM:
        pytest.skip("long interpolation needs the LLVM backend to stay fast")
    cam = SpikeCamera.noiseless(height=1, width=32, precision="float32")
    sim = Simulator(cam, backend=BACKEND, chunk_steps=1 << 16)
    lo, hi = np.zeros((1, 32), np.float32), np.full((1, 32), 2.0, np.float32)
    s = sim.run([lo, hi], keyframe_every=k)
    assert s.num_steps == k + 1
    y = 2.0 * np.arange(k + 1, dtype=np.float64) / k
    expected = np.minimum(y, 1.0).sum()
    counts = s.counts()
    assert np.all(np.abs(counts - expected) <= 2), (counts.min(), counts.max(), expected)
    assert np.all(np.isfinite(sim.get_state()["accumulator"]))


def test_interpolation_between_extremes_is_finite_and_saturates():
    # From darkness to 1e6 spikes/step in 100 steps: no overflow in the weights, the pixel fires
    # at every step from the first step whose light reaches the threshold.
    cam = SpikeCamera.noiseless(height=1, width=32)
    sim = Simulator(cam, backend=BACKEND)
    s = sim.run([np.zeros((1, 32), np.float32), np.full((1, 32), 1e6, np.float32)], keyframe_every=100)
    bits = s.unpack()[:, 0, :]
    assert s.num_steps == 101 and bits[1:].all() and not bits[0].any()
    assert np.all(np.isfinite(sim.get_state()["accumulator"]))


# ---- the renderer at extreme light powers -----------------------------------------------------
_XML = """<scene version="3.0.0">
  <integrator type="direct"/>
  <sensor type="perspective" id="camera">
    <float name="fov" value="30"/><string name="fov_axis" value="x"/>
    <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="10"/><integer name="height" value="8"/></film>
  </sensor>
  <shape type="rectangle" id="plane"><transform name="to_world"><scale value="50"/></transform>
    <bsdf type="diffuse"><spectrum name="reflectance" value="0.9"/></bsdf></shape>
</scene>
"""


@requires_llvm
@pytest.mark.parametrize("variant", ["mono", "spectral"])
def test_renderer_output_finite_from_starlight_to_the_maximum_power(tmp_path, variant):
    # 1e-6 lx (far below starlight) to 150 klx (the loader's ceiling, above full sunlight): y is
    # finite and >= 0 and scales with the illuminance; the sensor saturates cleanly at the top.
    from spikesim.render import SceneRenderer

    (tmp_path / "scene.xml").write_text(_XML)
    sun = {"id": "sun", "type": "directional", "spectrum": "D65", "direction": [0, 0, -1]}
    lux = {"starlight": 1e-6, "sun": 1.5e5}
    (tmp_path / "lights.json").write_text(json.dumps(
        {name: {"emitters": [{**sun, "power": {"illuminance_lux": v}}]} for name, v in lux.items()}))
    ys = {}
    for name in lux:
        r = SceneRenderer(tmp_path / "scene.xml", light=name, variant=variant, spp=4, seed=0)
        y = r.render_step(0)
        assert y.shape == (8, 10) and np.all(np.isfinite(y)) and y.min() >= 0
        ys[name] = float(y.mean())
    ratio = ys["sun"] / ys["starlight"]
    assert ratio == pytest.approx(1.5e11, rel=1e-3)
    cam = SpikeCamera.realistic(height=8, width=10)
    bright = SceneRenderer(tmp_path / "scene.xml", light="sun", variant=variant, spp=4).render_step(0)
    assert bright.min() > 100  # y ~ 0.29 per 100 lx (docs/scenes.md section 4)
    s = Simulator(cam, backend=BACKEND).run(np.broadcast_to(bright, (50, 8, 10)).copy())
    assert s.counts().min() == 50


# ---- representations and the model's input normalisation on all-zero / all-one streams ---------
@pytest.mark.parametrize("fill", [0, 1])
def test_representations_on_constant_streams(fill):
    torch = pytest.importorskip("torch")
    from model.representations import gisi, lisi, tfi, tfp, tfp_windows, transform_interval

    k, t, h, w = 3, 41, 4, 5
    s = torch.full((k, t, h, w), bool(fill))
    maps = {"tfp": tfp(s[0]), "tfi": tfi(s[0]), "lisi": lisi(s[0]), "tfp_windows": tfp_windows(s)}
    g, last, nxt = gisi(s)
    maps["gisi"] = g
    for name, m in maps.items():
        assert torch.isfinite(m).all(), name
    if fill == 0:
        # no spike: TFP 0, TFI 1 / (T + 1), LISI T + 1, GISI K T + 1 (docs in model.representations)
        assert maps["tfp"].max() == 0 and torch.allclose(maps["tfi"], torch.tensor(1 / (t + 1)))
        assert (maps["lisi"] == t + 1).all() and (g == k * t + 1).all()
    else:
        # a spike at every step: rate 1, every interval one step
        assert (maps["tfp"] == 1).all() and (maps["tfi"] == 1).all()
        assert (maps["lisi"] == 1).all() and (g == 1).all()
    for mode in ("raw", "inverse"):
        x = transform_interval(g, mode)
        assert torch.isfinite(x).all() and x.min() > 0
        if mode == "inverse":
            assert x.max() <= 1
