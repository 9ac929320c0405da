"""The Dr.Jit kernel's own contracts: its Philox is the standard one, its packing is the `.dat`
layout, launches and chunks do not change the stream, a batch of streams equals each stream
alone, frames on the device give what NumPy frames give, and the packed words reach torch."""
import numpy as np
import pytest

from spikesim.camera import SpikeCamera
from spikesim.simulate import BatchSimulator, Simulator
from spikesim.stream import SpikeStream

from sensor_testing import BACKENDS, FAST_BACKEND, requires_drjit

pytestmark = requires_drjit


def frames(n, h, w, seed=0, high=0.6):
    return np.random.default_rng(seed).uniform(0, high, size=(n, h, w)).astype(np.float32)


def _module():
    import drjit.cuda as cuda
    import drjit.llvm as llvm
    return cuda if FAST_BACKEND == "cuda" else llvm


def test_unrolled_philox_is_drjits_philox4x32():
    from spikesim.sensor_drjit import philox4x32
    m = _module()
    rng = np.random.default_rng(1)
    for seed in (0, 1, 0x123456789ABCDEF0, (1 << 64) - 1):
        c = [m.UInt32(rng.integers(0, 1 << 32, 257, dtype=np.uint32)) for _ in range(3)]
        ref = m.Philox4x32(m.UInt64(seed), c[0], c[1], c[2]).next_uint32x4()
        key = (m.UInt32(seed >> 32), m.UInt32(seed & 0xFFFFFFFF))
        mine = philox4x32(m, key, (c[0], c[1], c[2], m.UInt32(0)))
        for a, b in zip(ref, mine):
            assert np.array_equal(a.numpy(), b.numpy())


def test_numpy_philox_is_the_kernels():
    from spikesim.philox import philox4x32_numpy
    from spikesim.sensor_drjit import philox4x32
    m = _module()
    rng = np.random.default_rng(2)
    c = [rng.integers(0, 1 << 32, 300, dtype=np.uint32) for _ in range(4)]
    for key in ((0, 0), (0xDEADBEEF, 0x12345678), (0xFFFFFFFF, 0xFFFFFFFF)):
        mine = philox4x32(m, (m.UInt32(key[0]), m.UInt32(key[1])), tuple(m.UInt32(x) for x in c))
        for a, b in zip(philox4x32_numpy(key, tuple(c)), mine):
            assert np.array_equal(a, np.asarray(b.numpy(), np.uint32))


@pytest.mark.parametrize("n", [1, 2])
def test_popcount_normals_have_a_normals_mean_and_variance(n):
    # (popcount - 16 n) / sqrt(8 n) of 32 n uniform bits is Binomial(32 n, 1/2) standardised:
    # mean 0, variance 1 (tested on a million Philox words, within 5 standard errors), range
    # +-4 sqrt(2 n); the kernel's equals the NumPy twin's, which is the formula to float32 rounding.
    from spikesim.philox import philox4x32_numpy, popcount_normal_numpy
    from spikesim.sensor_drjit import popcount_normal
    m = _module()
    N = 1 << 20
    words = philox4x32_numpy((7, 9), (np.arange(N, dtype=np.uint32), 0, 0, 0))[:n]
    z = popcount_normal_numpy(*words).astype(np.float64)
    bits = sum(np.array([bin(int(v)).count("1") for v in w[:1000]]) for w in words)
    assert np.allclose(z[:1000], (bits - 16 * n) / np.sqrt(8 * n), rtol=1e-6, atol=0)
    assert abs(z.mean()) < 5 / np.sqrt(N) and abs(z.var() - 1) < 5 * np.sqrt(2 / N)
    assert z.min() >= -4 * np.sqrt(2 * n) - 1e-6 and z.max() <= 4 * np.sqrt(2 * n) + 1e-6
    kernel = np.asarray(popcount_normal(m, *[m.UInt32(w) for w in words]).numpy(), np.float32)
    assert np.array_equal(kernel, z.astype(np.float32))


def test_half_word_normals_are_binomial16_standardised():
    # Every 16-bit half, enumerated: (popcount - 8) / 2 has a normal's mean and variance exactly,
    # excess kurtosis -1/8, 17 levels in [-4, 4]; low half -> shot noise, high half -> comparator;
    # the kernel's equals the NumPy twin's.
    from spikesim.philox import half_word_normals_numpy
    from spikesim.sensor_drjit import half_word_normals
    m = _module()
    halves = np.arange(1 << 16, dtype=np.uint32)
    shot, comparator = half_word_normals_numpy(halves | (halves[::-1] << np.uint32(16)))
    assert np.array_equal(comparator, shot[::-1])
    z = shot.astype(np.float64)
    assert z.mean() == 0.0 and z.var() == 1.0
    assert np.mean(z ** 4) - 3 == pytest.approx(-1 / 8, abs=1e-12)
    assert set(np.unique(z)) == set(np.arange(-4, 4.5, 0.5))
    assert shot[0] == -4 and shot[0xFFFF] == 4 and shot[0b1011] == (3 - 8) / 2
    words = np.random.default_rng(3).integers(0, 1 << 32, 4096, dtype=np.uint32)
    for mine, twin in zip(half_word_normals(m, m.UInt32(words)), half_word_normals_numpy(words)):
        assert np.array_equal(np.asarray(mine.numpy(), np.float32), twin)


@pytest.mark.parametrize("camera", [SpikeCamera.realistic(height=6, width=21),
                                    SpikeCamera.realistic(height=6, width=21, precision="float64"),
                                    SpikeCamera.realistic(height=6, width=21, shot_noise="renewal"),
                                    SpikeCamera.realistic(height=6, width=21, shot_noise="renewal", comparator_noise=0.0,
                                                          precision="float64")],
                         ids=["gaussian", "gaussian-float64", "renewal", "renewal-no-comparator-float64"])
def test_temporal_noise_is_bit_identical_on_every_backend_for_any_chunking(camera):
    # The per-step normals are counted by (pixel, step // 4) and the renewal charges by (pixel,
    # spike index) in both backends: streams (and spike counts) agree bit for bit however the
    # steps are split into calls, the NumPy reference's included.
    f = frames(260, 6, 21, seed=8, high=0.7)
    ref = Simulator(camera, backend="numpy", seed=12)
    a = ref.run(f)
    chunked = Simulator(camera, backend="numpy", seed=12, chunk_steps=7)
    assert SpikeStream.concatenate([chunked.run(f[:5]), chunked.run(f[5:])]) == a
    fast = Simulator(camera, backend=FAST_BACKEND, seed=12, chunk_steps=37)
    assert fast.run(f) == a
    if camera.shot_noise == "renewal":
        counts = a.counts().reshape(-1).astype(np.uint64)
        assert np.array_equal(ref.get_state()["spike_count"], counts)
        assert np.array_equal(fast.get_state()["spike_count"].reshape(-1), counts)


@pytest.mark.parametrize("h,w", [(1, 1), (3, 7), (5, 13), (2, 64)])
def test_packing_is_the_dat_layout_for_any_size(h, w):
    # Bits are placed by the kernel's transpose; NumPy's packbits (LSB first) is the reference.
    cam = SpikeCamera.noiseless(height=h, width=w)
    f = frames(75, h, w, seed=h * w, high=1.0)   # 75 steps: two full words and a partial one
    ref = Simulator(cam, backend="numpy").run(f)
    out = Simulator(cam, backend=FAST_BACKEND).run(f)
    assert out == ref
    assert ref.counts().sum() > 0


@pytest.mark.parametrize("camera", [SpikeCamera.realistic(height=3, width=11),
                                    SpikeCamera.realistic(height=3, width=11, shot_noise="renewal"),
                                    SpikeCamera.noiseless(height=3, width=11, reset_loss=0.1)],
                         ids=["temporal-noise", "renewal", "deterministic"])
@pytest.mark.parametrize("chunk", [1, 2, 5, 6, 31, 33, 64])
def test_launch_and_chunk_boundaries_do_not_change_the_stream(camera, chunk):
    # Chunks starting inside a group of steps that share a Philox call (4) run it as a masked
    # piece; launches of 32 steps split long calls.
    f = frames(150, 3, 11, seed=4, high=0.5)
    whole = Simulator(camera, backend=FAST_BACKEND, seed=9, chunk_steps=1000).run(f)
    sim = Simulator(camera, backend=FAST_BACKEND, seed=9, chunk_steps=chunk)
    sim._sensor.steps_per_launch = 32
    parts = [sim.run(f[:3]), sim.run(f[3:70]), sim.run(f[70:])]
    assert SpikeStream.concatenate(parts) == whole


@pytest.mark.parametrize("shot", ["gaussian", "renewal"])
@pytest.mark.parametrize("boundary", [1 << 32, 1 << 33, 1 << 34])
def test_step_counter_carries_across_word_boundaries(boundary, shot):
    # Temporal noise is keyed by the absolute step pair (64 bits): the kernel carries into the
    # high word, so a call across 2^33 steps equals small chunks across it, and steps on either
    # side of the boundary get their own noise (not a wrapped repeat of step 0's).
    cam = SpikeCamera.realistic(height=2, width=32, shot_noise=shot)
    f = frames(12, 2, 32, seed=5, high=0.3)
    one = Simulator(cam, backend=FAST_BACKEND, seed=4)
    one.steps_done = boundary - 5
    s = one.run(f)
    assert one.steps_done == boundary + 7
    chunked = Simulator(cam, backend=FAST_BACKEND, seed=4, chunk_steps=3)
    chunked.steps_done = boundary - 5
    assert chunked.run(f) == s
    reference = Simulator(cam, backend="numpy", seed=4)
    reference.steps_done = boundary - 5
    assert reference.run(f) == s
    at_zero = Simulator(cam, backend=FAST_BACKEND, seed=4)
    at_zero.steps_done = 0
    low = at_zero.run(f[5:])
    assert low != s.slice(5)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("camera", [SpikeCamera.realistic(height=4, width=9),
                                    SpikeCamera.realistic(height=4, width=9, shot_noise="renewal"),
                                    SpikeCamera.realistic(height=4, width=9, shot_noise="off", comparator_noise=0.0)],
                         ids=["temporal-noise", "renewal", "fixed-pattern-only"])
@pytest.mark.parametrize("k", [1, 3])
def test_a_batch_of_streams_equals_each_stream_alone(backend, camera, k):
    seeds = [3, 0, 77]
    f = np.stack([frames(40, 4, 9, seed=s, high=0.5) for s in seeds], axis=1)   # (n, S, H, W)
    batch = BatchSimulator(camera, seeds, backend=backend, chunk_steps=13).run(f, keyframe_every=k)
    for i, seed in enumerate(seeds):
        alone = Simulator(camera, backend=backend, seed=seed, chunk_steps=13).run(f[:, i], keyframe_every=k)
        assert batch[i] == alone
    assert batch[0] != batch[2]


def test_device_frames_give_what_numpy_frames_give():
    m = _module()
    cam = SpikeCamera.realistic(height=5, width=6)
    f = frames(50, 5, 6, seed=2)
    ref = Simulator(cam, backend=FAST_BACKEND, seed=1, chunk_steps=16).run(f, keyframe_every=4)
    flat = [m.Float32(x.ravel()) for x in f]
    assert Simulator(cam, backend=FAST_BACKEND, seed=1, chunk_steps=16).run(flat, keyframe_every=4) == ref
    tensors = [m.TensorXf(x) for x in f]
    assert Simulator(cam, backend=FAST_BACKEND, seed=1, chunk_steps=16).run(tensors, keyframe_every=4) == ref
    # the NumPy reference reads device frames on the host
    det = cam.replace(shot_noise="off", comparator_noise=0.0)
    assert (Simulator(det, backend="numpy", seed=1).run(flat) ==
            Simulator(det, backend=FAST_BACKEND, seed=1).run(f))
    with pytest.raises(ValueError, match="mixed"):
        Simulator(cam, backend=FAST_BACKEND).run([f[0], flat[1]])


def test_an_invalid_device_frame_is_named_and_leaves_the_state_untouched():
    m = _module()
    cam = SpikeCamera.realistic(height=4, width=8)
    sim = Simulator(cam, backend=FAST_BACKEND, seed=2)
    sim.run(np.full((5, 4, 8), 0.2, np.float32))
    before = sim.get_state()
    bad = np.full((4, 8), 0.2, np.float32)
    bad[1, 2] = -1.0
    with pytest.raises(ValueError, match="frame 6: 1 negative"):
        sim.run([m.Float32(np.full(32, 0.2, np.float32)), m.Float32(bad.ravel())])
    after = sim.get_state()
    assert after["steps_done"] == before["steps_done"] == 5
    assert np.array_equal(after["accumulator"], before["accumulator"])


def test_packed_words_reach_torch_without_a_copy():
    torch = pytest.importorskip("torch")
    from spikesim.torch_interop import unpack_words
    cam = SpikeCamera.realistic(height=6, width=20)       # 120 pixels: 4 words per frame
    f = frames(70, 6, 20, seed=8)
    sim = BatchSimulator(cam, [5, 6], backend=FAST_BACKEND)
    parts = list(sim.stream_packed(f[:, None].repeat(2, axis=1)))
    part = parts[0]
    words = part.to_torch()
    assert words.shape == (2, 70, 4) and words.dtype == torch.uint32
    host = part.to_numpy()
    bits = unpack_words(words, 6, 20)                       # (S, n, H, W) bool, on the words' device
    for s in range(2):
        assert np.array_equal(bits[s].cpu().numpy(), SpikeStream(host[s], 6, 20).unpack())
    # DLPack shares the memory: a write through torch is seen by Dr.Jit
    words.view(torch.int32)[0, 0, 0] = 12345
    assert int(part.words.numpy()[0]) == 12345


@pytest.mark.parametrize("backend", BACKENDS)
def test_tiny_light_neither_stalls_nor_drifts_in_float32(backend):
    # A plain float32 sum stalls when y is below half an ulp of the accumulator (y = 1e-8 at
    # 0.25: it stayed 0.25 forever) and drifts for small y (y = 1e-4: one interval in two was
    # 9999). The compensated sum keeps both exact: intervals floor or ceil of 1/y.
    cam = SpikeCamera.noiseless(height=1, width=2)
    y = np.array([[1e-4, 1e-8]], np.float32)
    n = 40_001
    sim = Simulator(cam, backend=backend, chunk_steps=1 << 14)
    s = sim.run([y, y], keyframe_every=n - 1)
    times = np.flatnonzero(s.unpack()[:, 0, 0])
    isi = np.diff(times)
    expect = 1.0 / np.float64(y[0, 0])
    assert len(times) == 4 and set(isi) <= {int(np.floor(expect)), int(np.ceil(expect))}
    st = sim.get_state()
    total = st["accumulator"][1].astype(np.float64) - st["compensation"][1]
    assert abs(total - n * np.float64(y[0, 1])) < 1e-9           # 4e-4 integrated, not lost


@pytest.mark.parametrize("backend", BACKENDS)
def test_absurd_light_saturates_with_finite_state(backend):
    # y = 3.4e38 with shot noise and gain > 1 used to overflow to NaN accumulators (dead pixels).
    cam = SpikeCamera.realistic(height=2, width=16, gain_spread=0.2)
    f = np.full((64, 2, 16), 3.4e38, np.float32)
    f[:, 1, ::2] = 0.5
    sim = Simulator(cam, backend=backend, seed=1)
    s = sim.run(f)
    counts = s.counts()
    assert np.all(counts[0] == 64) and np.all(counts[1, 1::2] == 64)
    assert 0 < counts[1, ::2].mean() < 64
    assert np.all(np.isfinite(sim.get_state()["accumulator"]))


# A collection by Python's garbage collector while a frozen kernel records used to end the process
# (Dr.Jit: "RecordThreadState::enqueue_host_func(): this function cannot be recorded!", thrown from
# the destructor of an array that wraps NumPy memory). It killed a CI run of the suite at a test
# that simulated after others had left such arrays in reference cycles. The child forces it: inside
# the recording, it makes that garbage and allocates until the collector would run.
GC_DURING_RECORDING = """
import gc
import numpy as np
import drjit as dr
import drjit.llvm as L
from spikesim.camera import SpikeCamera
from spikesim.simulate import Simulator

class Holder:
    pass

loop = dr.while_loop
def while_loop(*args, **kwargs):
    h = Holder(); h.me = h; h.arr = L.Float32(np.ones(4096, np.float32)); dr.eval(h.arr)
    del h
    threshold = gc.get_threshold()
    gc.set_threshold(1)
    junk = [[] for _ in range(100)]
    gc.set_threshold(*threshold)
    return loop(*args, **kwargs)
dr.while_loop = while_loop
sim = Simulator(SpikeCamera(height=8, width=8), backend="llvm", seed=1)
print(sum(1 for _ in sim.stream(iter(np.full((300, 8, 8), 0.2, np.float32)))))
"""


def test_a_garbage_collection_while_a_frozen_kernel_records_does_not_end_the_process():
    import subprocess
    import sys
    from pathlib import Path
    from sensor_testing import HAS_LLVM
    if not HAS_LLVM:
        pytest.skip("Dr.Jit LLVM backend unavailable")
    repo = Path(__file__).resolve().parents[1]
    child = subprocess.run([sys.executable, "-c", GC_DURING_RECORDING], cwd=repo, capture_output=True, text=True,
                           timeout=300)
    assert child.returncode == 0, child.stderr[-2000:]
    assert int(child.stdout.split()[-1]) >= 1
