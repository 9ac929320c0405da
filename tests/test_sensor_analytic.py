"""The sensor against analytic expectations (docs/design.md section 2)."""
import math

import numpy as np
import pytest

from spikesim.camera import SpikeCamera
from spikesim.patterns import constant_frames
from spikesim.simulate import Simulator
from spikesim.stats import firing_rate, inter_spike_intervals

from sensor_testing import BACKENDS



@pytest.mark.parametrize("backend", BACKENDS)
def test_noiseless_rate_and_isi_are_exact(backend):
    # Constant light, no noise: the count after N steps is floor(N (y + d)) and every
    # inter-spike interval is floor or ceil of 1 / (y + d).
    d_hz = 94.0
    cam = SpikeCamera.noiseless(height=1, width=8, dark_current_hz=d_hz)
    d = np.float32(d_hz * cam.readout_period_s)
    y = np.array([[0.0, 0.001, 0.013, 0.1, 0.3333, 0.5, 0.77, 0.999]], np.float32)
    n = 6000
    s = Simulator(cam, backend=backend).run(constant_frames(y, n, 1, 8))
    e = np.minimum((y + d).astype(np.float64)[0], 1.0)  # saturation: at most one spike per step
    counts = s.counts()[0]
    assert np.all(np.abs(counts - np.floor(n * e)) <= 1)
    isi = inter_spike_intervals(s)
    bits = s.unpack()[:, 0, :]
    for px in range(8):
        t = np.flatnonzero(bits[:, px])
        if t.size > 2:
            gaps = np.diff(t)
            assert set(gaps) <= {math.floor(1 / e[px]), math.ceil(1 / e[px])}, (px, set(gaps))
    assert isi.size == sum(max(0, np.count_nonzero(bits[:, p]) - 1) for p in range(8))


@pytest.mark.parametrize("backend", BACKENDS)
def test_dark_current_alone_gives_its_rate_per_pixel(backend):
    cam = SpikeCamera.noiseless(height=16, width=32, dark_current_hz=2000.0, dark_current_spread=0.39)
    n = 8000
    sim = Simulator(cam, backend=backend, seed=3)
    s = sim.run(constant_frames(0.0, n, 16, 32))
    want = sim.params.dark_per_step.reshape(16, 32).astype(np.float64)
    assert np.all(np.abs(s.counts() - n * want) <= 1)
    # and the fixed pattern has the configured spread (lognormal, CV 0.39), to sampling error
    cv = want.std() / want.mean()
    assert abs(cv - 0.39) < 4 * 0.39 / np.sqrt(2 * want.size)


@pytest.mark.parametrize("backend", BACKENDS)
def test_fixed_patterns_give_the_analytic_rate_per_pixel(backend):
    # rate = (g y + d) / theta for every pixel, with gain, dark and threshold patterns on.
    cam = SpikeCamera.realistic(height=8, width=32, shot_noise="off", comparator_noise=0.0, reset_loss=0.0)
    sim = Simulator(cam, backend=backend, seed=5)
    y = 0.21
    n = 5000
    s = sim.run(constant_frames(y, n, 8, 32))
    p = sim.params
    rate = (p.gain.astype(np.float64) * y + p.dark_per_step) / p.threshold
    assert np.all(np.abs(s.counts().ravel() - n * rate) <= 2)


@pytest.mark.parametrize("backend", BACKENDS)
def test_reset_loss_rate(backend):
    # Losing r of the step after each spike: the rate R solves R = e (1 - r R) for e < 1.
    r, e = 0.2, 0.5
    cam = SpikeCamera.noiseless(height=1, width=32, reset_loss=r)
    n = 4000
    s = Simulator(cam, backend=backend).run(constant_frames(e, n, 1, 32))
    # Charge balance: each spike costs one threshold, and each spike loses r e of the next step.
    rate = firing_rate(s).mean()
    assert abs(rate - e / (1 + r * e)) < 2 / n


def _shot_noise_count_variance(mean: float, var: float) -> float:
    """Var of C = floor(phi + X) - floor(phi), phi ~ U[0,1), X ~ N(mean, var):
    Var(X) + E[frac(X)(1 - frac(X))] (the readout quantisation of a uniform phase)."""
    x = np.linspace(mean - 8 * np.sqrt(var), mean + 8 * np.sqrt(var), 20001)
    w = np.exp(-0.5 * (x - mean) ** 2 / var)
    w /= w.sum()
    f = x - np.floor(x)
    return var + float((w * f * (1 - f)).sum())


@pytest.mark.parametrize("backend,model", [("numpy", "gaussian"), ("numpy", "poisson"), ("numpy", "renewal")]
                         + [(b, m) for b in BACKENDS[1:] for m in ("gaussian", "renewal")])
def test_shot_noise_count_mean_and_variance(backend, model):
    # Charge after T steps has mean yT and variance yT / N_e (Poisson electrons); with a uniform
    # initial phase the window count has mean yT and the variance above. The renewal model draws
    # each interval's charge instead (Gamma, variance 1 / N_e): a renewal count of mean yT has
    # the same variance to O(1 / N_e).
    ne, y, T = 200.0, 0.2, 200
    cam = SpikeCamera.noiseless(height=64, width=64, shot_noise=model, threshold_electrons=ne,
                                random_initial_state=True)
    s = Simulator(cam, backend=backend, seed=9).run(constant_frames(y, T, 64, 64))
    c = s.counts().ravel().astype(np.float64)
    want_var = _shot_noise_count_variance(y * T, y * T / ne)
    n = c.size
    assert abs(c.mean() - y * T) < 5 * np.sqrt(want_var / n)
    # the sample variance of n normal-ish values has relative sd sqrt(2 / (n - 1))
    assert abs(c.var(ddof=1) / want_var - 1) < 5 * np.sqrt(2 / (n - 1))
    assert want_var > 2 * _shot_noise_count_variance(y * T, 1e-12)  # the test sees the shot noise


@pytest.mark.parametrize("backend", BACKENDS)
def test_comparator_noise_keeps_the_mean_rate(backend):
    # Noise on the comparison moves spikes in time but charge is conserved by the reset.
    cam = SpikeCamera.noiseless(height=16, width=32, comparator_noise=0.2, random_initial_state=True)
    n = 3000
    y = 0.137
    s = Simulator(cam, backend=backend, seed=1).run(constant_frames(y, n, 16, 32))
    assert abs(firing_rate(s).mean() - y) < 2.0 / n
    quiet = Simulator(cam.without("comparator_noise"), backend=backend, seed=1).run(constant_frames(y, n, 16, 32))
    # ... and widens the interval distribution beyond floor/ceil of 1/y.
    assert set(np.unique(inter_spike_intervals(quiet))) == {7, 8}
    assert inter_spike_intervals(s).std() > 2 * inter_spike_intervals(quiet).std()
