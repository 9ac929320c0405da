"""The backends implement one model: bit-identical, temporal noise included (both draw it from
Philox counted by pixel and step); chunked simulation equals one call; compiled kernels are reused."""
import dataclasses

import numpy as np
import pytest

from spikesim.camera import SpikeCamera
from spikesim.simulate import Simulator

from sensor_testing import FAST_BACKEND, drjit_backends, requires_drjit

pytestmark = requires_drjit

H, W = 20, 44  # 880 pixels: not a multiple of 32, exercises the padded last lane


def frames(n, seed=0, high=1.3):
    return np.random.default_rng(seed).uniform(0, high, size=(n, H, W)).astype(np.float32)


MODELS = {
    "noiseless": SpikeCamera.noiseless(height=H, width=W),
    "dark+fixed-patterns": SpikeCamera.realistic(height=H, width=W, shot_noise="off", comparator_noise=0.0),
    "reset-loss": SpikeCamera.noiseless(height=H, width=W, reset_loss=0.05, random_initial_state=True),
    "float64": SpikeCamera.realistic(height=H, width=W, shot_noise="off", comparator_noise=0.0, precision="float64"),
    "measured-fixed-patterns": SpikeCamera.measured(height=H, width=W, shot_noise="off", comparator_noise=0.0),
    # temporal noise: the per-step normals and the renewal charges are counted by (pixel, step)
    # and (pixel, spike) in both backends
    "realistic": SpikeCamera.realistic(height=H, width=W),
    "realistic-float64": SpikeCamera.realistic(height=H, width=W, precision="float64"),
    "strong-noise": SpikeCamera.realistic(height=H, width=W, threshold_electrons=30.0, comparator_noise=0.05),
    "comparator-only": SpikeCamera.realistic(height=H, width=W, shot_noise="off"),
    "renewal": SpikeCamera.realistic(height=H, width=W, shot_noise="renewal"),
    "measured": SpikeCamera.measured(height=H, width=W),
    # SCSim's camera: normal dark-current law, reset by the level the comparator fired at
    "scsim": SpikeCamera.scsim(height=H, width=W),
    "reset-fired-renewal": SpikeCamera.realistic(height=H, width=W, shot_noise="renewal", reset_rule="fired",
                                                 comparator_noise=0.05),
}


@pytest.mark.parametrize("backend", drjit_backends())
@pytest.mark.parametrize("name", list(MODELS))
@pytest.mark.parametrize("k", [1, 4])
def test_every_model_is_bit_identical(backend, name, k):
    cam = MODELS[name]
    f = frames(120 if k == 1 else 30, seed=3)
    ref = Simulator(cam, backend="numpy", seed=7).run(f, keyframe_every=k)
    out = Simulator(cam, backend=backend, seed=7).run(f, keyframe_every=k)
    assert ref.num_steps == (len(f) if k == 1 else (len(f) - 1) * k + 1)
    assert ref.counts().sum() > 0
    assert out == ref


def test_temporal_noise_differs_between_seeds_and_from_the_noiseless_stream():
    # Bit-identity across backends must not come from a noise that is not drawn: other seeds
    # (same fixed patterns, pixel parameters held) and the camera without temporal noise differ.
    cam = MODELS["realistic"]
    f = frames(200, seed=3, high=0.5)
    a = Simulator(cam, backend="numpy", seed=7)
    quiet = dataclasses.replace(cam, shot_noise="off", comparator_noise=0.0)
    b = Simulator(quiet, backend="numpy", seed=7)
    assert np.array_equal(b.pixel_parameters[0].gain, a.pixel_parameters[0].gain)
    sa, sb = a.run(f), b.run(f)
    assert sa != sb
    assert abs(int(sa.counts().sum()) - int(sb.counts().sum())) < 0.02 * sb.counts().sum()
    assert Simulator(cam, backend="numpy", seed=8).run(f) != sa


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


@pytest.mark.gpu
@pytest.mark.skipif("cuda" not in drjit_backends(), reason="needs a CUDA GPU")
@pytest.mark.parametrize("name", ["realistic", "renewal", "strong-noise", "realistic-float64"])
def test_cuda_is_bit_identical_to_the_reference_with_temporal_noise(name):
    # The GPU campaign's check (`-m gpu`) that CUDA rounds as LLVM and NumPy do (no fused
    # multiply-adds): the noisy models, keyframes interpolated.
    cam = MODELS[name]
    f = frames(30, seed=5)
    ref = Simulator(cam, backend="numpy", seed=11).run(f, keyframe_every=4)
    assert Simulator(cam, backend="cuda", seed=11).run(f, keyframe_every=4) == ref
