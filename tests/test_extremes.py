"""The model at its extremes (docs/design.md section 2): no light, saturating light, very long
streams, bad parameters and bad frames."""
import numpy as np
import pytest

from spikesim.camera import SpikeCamera
from spikesim.patterns import constant_frames
from spikesim.simulate import Simulator

from sensor_testing import BACKENDS, FAST_BACKEND, requires_drjit



@pytest.mark.parametrize("backend", BACKENDS)
def test_no_light_no_dark_current_no_spikes(backend):
    s = Simulator(SpikeCamera.noiseless(height=8, width=32), backend=backend).run(constant_frames(0.0, 500, 8, 32))
    assert s.counts().sum() == 0


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("y", [1.0, 1.5, 1e3, 1e30])
def test_saturation_fires_every_step_and_stays_bounded(backend, y):
    cam = SpikeCamera.realistic(height=4, width=32)
    sim = Simulator(cam, backend=backend, seed=1)
    s = sim.run(constant_frames(y, 300, 4, 32))
    # the pixels whose gain x y + dark clears their threshold + noise fire at every step
    assert s.counts().min() >= 299 if y > 1.2 else s.counts().mean() > 0.9 * 300
    acc = sim.get_state()["accumulator"]
    thr = sim.params.threshold
    assert np.all(np.isfinite(acc)) and np.all(acc <= 2 * thr + 1e-6) and np.all(acc >= -thr - 1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("bad,message", [
    (np.nan, "NaN"), (np.inf, "infinite"), (-0.1, "negative")])
def test_bad_frames_are_named(backend, bad, message):
    frames = np.full((5, 4, 8), 0.1, np.float32)
    frames[3, 2, 1] = bad
    sim = Simulator(SpikeCamera.noiseless(height=4, width=8), backend=backend)
    with pytest.raises(ValueError, match=f"frame 3: .*{message}"):
        sim.run(frames)


def test_wrong_frame_shape_is_named():
    sim = Simulator(SpikeCamera.noiseless(height=4, width=8), backend="numpy")
    with pytest.raises(ValueError, match=r"frame 0: shape \(8, 4\)"):
        sim.run([np.zeros((8, 4), np.float32)])


def test_bad_simulator_arguments():
    cam = SpikeCamera.noiseless(height=4, width=8)
    with pytest.raises(ValueError, match="seed"):
        Simulator(cam, seed=-1)
    with pytest.raises(ValueError, match="keyframe_every"):
        Simulator(cam, backend="numpy").run([np.zeros((4, 8))], keyframe_every=0)


@requires_drjit
@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_a_million_steps_do_not_drift(precision):
    # 10^6 steps of constant light via two identical keyframes 10^6 steps apart: the count is
    # floor(N e) within one spike for float64 and within a stated tolerance for float32 (the
    # residual is kept in [0, 1), so the float32 error per step is <= 2^-24, < 0.06 spikes/10^6).
    n = 1_000_000
    cam = SpikeCamera.noiseless(height=1, width=32, precision=precision)
    e = np.linspace(1e-4, 0.95, 32).astype(np.float32)[None, :]
    sim = Simulator(cam, backend=FAST_BACKEND, chunk_steps=1 << 16)
    s = sim.run([e, e], keyframe_every=n - 1)
    assert s.num_steps == n
    tol = 1 if precision == "float64" else 1 + n * 2.0 ** -24 * 2
    assert np.all(np.abs(s.counts()[0] - np.floor(n * e[0].astype(np.float64))) <= tol)


@requires_drjit
def test_step_counter_crosses_2_to_the_32():
    # Temporal noise is keyed by the absolute step; a chunk crossing 2^32 is split, not wrapped.
    cam = SpikeCamera.realistic(height=2, width=32)
    sim = Simulator(cam, backend=FAST_BACKEND, seed=4)
    sim.steps_done = (1 << 32) - 5
    s = sim.run(constant_frames(0.3, 10, 2, 32))
    assert s.num_steps == 10 and sim.steps_done == (1 << 32) + 5
    # the same stream when simulated in small chunks around the boundary
    chunked = Simulator(cam, backend=FAST_BACKEND, seed=4, chunk_steps=3)
    chunked.steps_done = (1 << 32) - 5
    assert chunked.run(constant_frames(0.3, 10, 2, 32)) == s


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_rejected_chunk_leaves_the_state_untouched(backend):
    cam = SpikeCamera.realistic(height=4, width=8)
    sim = Simulator(cam, backend=backend, seed=2)
    sim.run(constant_frames(0.2, 5, 4, 8))
    before = sim.get_state()
    frames = np.full((3, 4, 8), 0.2, np.float32)
    frames[1, 0, 0] = np.nan
    with pytest.raises(ValueError, match="frame 6: 1 NaN"):
        sim.run(frames)
    after = sim.get_state()
    assert after["steps_done"] == before["steps_done"] == 5
    assert np.array_equal(after["accumulator"], before["accumulator"])
