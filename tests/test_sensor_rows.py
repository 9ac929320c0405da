"""The CPU's frame-per-step kernel (each step's frame its own input array, read with packet loads)
is an optimisation, not a model: it must give the general kernel's stream bit for bit, whatever
the frames' source (NumPy, device arrays), their alignment, the chunking and the streams per
launch; and it must actually run where it applies, or its speed-up is silently lost."""
import numpy as np
import pytest

from spikesim.camera import SpikeCamera
from spikesim.sensor_drjit import WORD_STEPS, DrJitSensor
from spikesim.simulate import FRAME_ALIGNMENT, BatchSimulator, Simulator, aligned_empty

from sensor_testing import requires_llvm

pytestmark = requires_llvm

H, W = 12, 40  # 480 pixels: 15 words, a multiple of 16 pixels, so rows keep their alignment
CAMERAS = {
    "noiseless": SpikeCamera.noiseless(height=H, width=W),
    "realistic": SpikeCamera.realistic(height=H, width=W),
    "reset-loss": SpikeCamera.noiseless(height=H, width=W, reset_loss=0.05, random_initial_state=True),
    "renewal": SpikeCamera.realistic(height=H, width=W, shot_noise="renewal"),
    "float64": SpikeCamera.realistic(height=H, width=W, precision="float64"),
}


def frames(n, seed=0, high=0.8):
    return np.random.default_rng(seed).uniform(0, high, size=(n, H, W)).astype(np.float32)


def count_row_launches(sim):
    """Counts the frame-per-step kernel's launches of `sim` (a list, one entry per launch)."""
    calls = []
    frozen = sim._sensor._integrate_rows

    def counted(*args):
        calls.append(1)
        return frozen(*args)
    sim._sensor._integrate_rows = counted
    return calls


def general_only(monkeypatch):
    monkeypatch.setattr(DrJitSensor, "row_kernel", property(lambda self: False))


@pytest.mark.parametrize("name", list(CAMERAS))
def test_the_row_kernel_gives_the_general_kernels_stream(name, monkeypatch):
    cam = CAMERAS[name]
    f = frames(101, seed=4)  # 3 whole words and a 5-step tail for the general kernel
    ref = Simulator(cam, backend="numpy", seed=9).run(f)
    rows = Simulator(cam, backend="llvm", seed=9).run(f)
    general_only(monkeypatch)
    general = Simulator(cam, backend="llvm", seed=9).run(f)
    assert general == ref
    assert rows == ref


def test_the_row_kernel_runs_for_whole_words_with_a_frame_every_step():
    cam = CAMERAS["realistic"]
    sim = Simulator(cam, backend="llvm", seed=1)
    launches = count_row_launches(sim)
    sim.run(frames(3 * WORD_STEPS + 5))
    assert len(launches) == 3                      # the 5-step tail runs in the general kernel
    sim = Simulator(cam, backend="llvm", seed=1)
    launches = count_row_launches(sim)
    sim.run(frames(30), keyframe_every=4)          # keyframes: the general kernel interpolates
    assert not launches


def test_aligned_and_unaligned_frames_give_one_stream():
    """A frozen kernel is recorded per input alignment (64-byte aligned loads differ from
    unaligned ones in the compiled code); frames of either kind, and both in turn in one
    stream, must read the same values."""
    cam = CAMERAS["realistic"]
    f = frames(4 * WORD_STEPS, seed=6)
    aligned = aligned_empty(f.shape)
    aligned[:] = f
    off = aligned_empty((f.size + 1,))[1:].reshape(f.shape)   # 4 bytes off: every row unaligned
    off[:] = f
    assert aligned.ctypes.data % FRAME_ALIGNMENT == 0 and off.ctypes.data % FRAME_ALIGNMENT != 0
    ref = Simulator(cam, backend="numpy", seed=2).run(f)
    assert Simulator(cam, backend="llvm", seed=2).run(aligned) == ref
    assert Simulator(cam, backend="llvm", seed=2).run(off) == ref
    mixed = Simulator(cam, backend="llvm", seed=2)
    a = mixed.run(aligned[:2 * WORD_STEPS], final=False)
    b = mixed.run(off[2 * WORD_STEPS:])
    assert np.array_equal(np.concatenate([a.packed, b.packed]), ref.packed)


def test_device_frames_feed_the_row_kernel():
    import drjit.llvm as m
    cam = CAMERAS["realistic"]
    f = frames(2 * WORD_STEPS + 3, seed=7)
    ref = Simulator(cam, backend="numpy", seed=3).run(f)
    sim = Simulator(cam, backend="llvm", seed=3)
    launches = count_row_launches(sim)
    assert sim.run([m.Float32(x.ravel()) for x in f]) == ref
    assert len(launches) == 2
    # chunks of 45 steps cut the 4-step Philox groups: masked pieces read their own frames too
    chunked = Simulator(cam, backend="llvm", seed=3, chunk_steps=45)
    assert chunked.run([m.Float32(x.ravel()) for x in f]) == ref


@pytest.mark.parametrize("chunk", [32, 45, 256])
def test_batches_and_chunks_give_each_stream_alone(chunk):
    cam = CAMERAS["realistic"]
    f = np.stack([frames(100, seed=s) for s in (1, 2)], axis=1)  # (n, S, H, W)
    batch = BatchSimulator(cam, [5, 6], backend="llvm", chunk_steps=chunk).run(f)
    for i, seed in enumerate((5, 6)):
        assert batch[i] == Simulator(cam, backend="numpy", seed=seed).run(f[:, i])


def test_an_invalid_frame_in_a_whole_word_is_named_and_leaves_the_state_untouched():
    cam = CAMERAS["noiseless"]
    sim = Simulator(cam, backend="llvm", seed=2)
    sim.run(frames(WORD_STEPS), final=False)
    before = sim._sensor.get_state()
    bad = frames(WORD_STEPS, seed=3)
    bad[17, 3, 5] = np.nan
    with pytest.raises(ValueError, match="frame 49"):
        sim.run(bad)
    after = sim._sensor.get_state()
    for key in before:
        assert np.array_equal(before[key], after[key])


@pytest.mark.parametrize("shape", [(3, 5), (7, 16, 16), (1,)])
def test_aligned_empty_is_aligned_and_shaped(shape):
    a = aligned_empty(shape)
    assert a.shape == shape and a.dtype == np.float32 and a.flags.c_contiguous
    assert a.ctypes.data % FRAME_ALIGNMENT == 0
    b = aligned_empty(shape, dtype=np.uint32, alignment=128)
    assert b.dtype == np.uint32 and b.ctypes.data % 128 == 0
