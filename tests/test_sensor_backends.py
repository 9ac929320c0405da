"""The backends implement one model: bit-identical without temporal noise, statistically equal
with it; chunked simulation equals one call; compiled kernels are reused."""
import numpy as np
import pytest

from spikesim.camera import SpikeCamera
from spikesim.simulate import Simulator
from spikesim.stats import firing_rate

from sensor_testing import FAST_BACKEND, drjit_backends, requires_drjit

pytestmark = requires_drjit

H, W = 20, 44  # 880 pixels: not a multiple of 32, exercises the padded last lane


def frames(n, seed=0, high=1.3):
    return np.random.default_rng(seed).uniform(0, high, size=(n, H, W)).astype(np.float32)


DETERMINISTIC = {
    "noiseless": SpikeCamera.noiseless(height=H, width=W),
    "dark+fixed-patterns": SpikeCamera.realistic(height=H, width=W, shot_noise="off", comparator_noise=0.0),
    "reset-loss": SpikeCamera.noiseless(height=H, width=W, reset_loss=0.05, random_initial_state=True),
    "float64": SpikeCamera.realistic(height=H, width=W, shot_noise="off", comparator_noise=0.0, precision="float64"),
    "measured-fixed-patterns": SpikeCamera.measured(height=H, width=W, shot_noise="off", comparator_noise=0.0),
}


@pytest.mark.parametrize("backend", drjit_backends())
@pytest.mark.parametrize("name", list(DETERMINISTIC))
@pytest.mark.parametrize("k", [1, 4])
def test_deterministic_models_are_bit_identical(backend, name, k):
    cam = DETERMINISTIC[name]
    f = frames(120 if k == 1 else 30, seed=3)
    ref = Simulator(cam, backend="numpy", seed=7).run(f, keyframe_every=k)
    out = Simulator(cam, backend=backend, seed=7).run(f, keyframe_every=k)
    assert ref.num_steps == (len(f) if k == 1 else (len(f) - 1) * k + 1)
    assert ref.counts().sum() > 0
    assert out == ref


@pytest.mark.parametrize("backend", drjit_backends())
def test_noisy_model_statistics_agree(backend):
    cam = SpikeCamera.realistic(height=32, width=64, threshold_electrons=300.0, comparator_noise=0.05)
    y = np.tile(np.linspace(0.002, 0.6, 64, dtype=np.float32), (32, 1))
    n = 1500
    ref = firing_rate(Simulator(cam, backend="numpy", seed=1).run([y] * n))
    out = firing_rate(Simulator(cam, backend=backend, seed=1).run([y] * n))
    # Same fixed patterns (same seed), independent temporal noise: per-pixel rates differ by the
    # sampling error of a renewal count, sd ~ sqrt(rate * CV^2 / n) with CV^2 ~ 1/N_e + comparator.
    diff = out - ref
    sd = np.sqrt(2 * np.maximum(ref, 1e-3) * (1 / cam.threshold_electrons + 0.05 ** 2 * 4) / n) + 1.0 / n
    assert np.abs(diff.mean()) < 5 * sd.mean() / np.sqrt(diff.size)
    assert np.mean(np.abs(diff) < 4 * sd) > 0.99


@pytest.mark.parametrize("backend", ["numpy"] + drjit_backends())
def test_chunked_equals_one_call(backend):
    cam = SpikeCamera.realistic(height=H, width=W)
    f = frames(90, seed=5, high=0.4)
    whole = Simulator(cam, backend=backend, seed=11).run(f)
    sim = Simulator(cam, backend=backend, seed=11, chunk_steps=16)
    parts = [sim.run(f[:7]), sim.run(f[7:40]), sim.run(iter(f[40:]))]
    assert sum(p.num_steps for p in parts) == 90
    from spikesim.stream import SpikeStream
    assert SpikeStream.concatenate(parts) == whole


@pytest.mark.parametrize("backend", ["numpy"] + drjit_backends())
def test_chunked_keyframes_equal_one_call(backend):
    cam = SpikeCamera.realistic(height=H, width=W)
    f = frames(13, seed=6, high=0.5)
    whole = Simulator(cam, backend=backend, seed=2).run(f, keyframe_every=5)
    sim = Simulator(cam, backend=backend, seed=2, chunk_steps=7)
    a = sim.run(f[:4], keyframe_every=5, final=False)
    b = sim.run(f[4:9], keyframe_every=5, final=False)
    c = sim.run(f[9:], keyframe_every=5, final=True)
    assert (a.num_steps, b.num_steps, c.num_steps) == (15, 25, 21)
    from spikesim.stream import SpikeStream
    assert SpikeStream.concatenate([a, b, c]) == whole


def test_interpolation_is_linear_between_keyframes():
    cam = SpikeCamera.noiseless(height=1, width=32)
    y0 = np.zeros((1, 32), np.float32)
    y1 = np.full((1, 32), 0.5, np.float32)
    s = Simulator(cam, backend="numpy").run([y0, y1], keyframe_every=1000)
    # integral of a ramp 0 -> 0.5 over steps 0..1000: sum_{n} 0.5 n / 1000 = 250.25
    assert np.all(np.abs(s.counts() - 250.25) <= 1)


def test_kernel_is_compiled_once_per_configuration():
    from spikesim._drjit import dr
    cam = SpikeCamera.realistic(height=H, width=W)
    sim = Simulator(cam, backend=FAST_BACKEND, seed=0, chunk_steps=64)
    sim.run(frames(10))  # compile
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clear
    try:
        sim.run(frames(64, seed=1))
        sim.run(frames(37, seed=2))
        sim.run(frames(5, seed=3), keyframe_every=3)  # k > 1 is a different (interpolating) kernel
        sim.run(frames(9, seed=4), keyframe_every=7)
        hist = [h for h in dr.kernel_history() if h.get("type") == dr.KernelType.JIT and h.get("operation_count", 0) > 500]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    misses = [h for h in hist if not h["cache_hit"]]
    assert len(hist) >= 4
    assert len(misses) <= 1, f"{len(misses)} kernel compilations where at most 1 (the interpolating kernel) is expected"


def test_backend_errors():
    with pytest.raises(ValueError, match="unknown backend"):
        Simulator(SpikeCamera.noiseless(height=4, width=4), backend="tpu")
    with pytest.raises(ValueError, match="poisson"):
        Simulator(SpikeCamera.noiseless(height=4, width=4, shot_noise="poisson"), backend=FAST_BACKEND)


@pytest.mark.parametrize("backend", ["numpy"] + drjit_backends())
def test_adaptive_keyframes_equal_uniform_ones_where_they_coincide(backend):
    cam = SpikeCamera.realistic(height=H, width=W)
    f = frames(5, seed=8, high=0.5)
    uniform = Simulator(cam, backend=backend, seed=3).run(f, keyframe_every=6)
    sim = Simulator(cam, backend=backend, seed=3)
    parts = list(sim.stream_keyframes([(0, f[0]), (6, f[1]), (12, f[2])], final=False))
    parts += list(sim.stream_keyframes([(18, f[3]), (24, f[4])], final=True))
    from spikesim.stream import SpikeStream
    assert SpikeStream.concatenate(parts) == uniform
    # irregular spacing: steps 0..9 from keyframes at 0, 1, 9
    irregular = Simulator(cam, backend=backend, seed=3).stream_keyframes([(0, f[0]), (1, f[1]), (9, f[2])])
    assert sum(p.num_steps for p in irregular) == 10
    with pytest.raises(ValueError, match="increase"):
        list(Simulator(cam, backend=backend).stream_keyframes([(0, f[0]), (0, f[1])]))
