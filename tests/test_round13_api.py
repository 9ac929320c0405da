"""Round thirteen (docs/robustness.md): the library's stream and simulator inputs that were taken
silently or failed with another library's message."""
from __future__ import annotations

import numpy as np
import pytest

from spikesim import SpikeCamera
from spikesim.simulate import Simulator
from spikesim.stream import SpikeStream, frame_bytes, write_dat


@pytest.mark.parametrize("height", [-1, 0, 2.5, True, "8"])
def test_a_spike_stream_refuses_a_geometry_that_is_not_a_positive_integer(height):
    with pytest.raises(ValueError, match="height must be a positive integer"):
        SpikeStream(np.zeros((1, 3), np.uint8), height, 8)
    assert SpikeStream(np.zeros((1, frame_bytes(3, 8)), np.uint8), np.int64(3), 8).height == 3


@pytest.mark.parametrize("start, stop", [(2, 1), (0, 9), (-1, 2), (0.5, 2)])
def test_counts_refuses_a_range_outside_the_stream_or_reversed(start, stop):
    s = SpikeStream.from_bool(np.ones((4, 2, 8), bool))
    with pytest.raises(ValueError, match="SpikeStream.counts"):
        s.counts(start, stop)
    assert s.counts(1, 3).tolist() == np.full((2, 8), 2).tolist()


def test_an_empty_stream_gets_the_writers_own_error(tmp_path):
    empty = SpikeStream.from_bool(np.zeros((0, 8, 12), bool))
    assert empty.shape == (0, 8, 12)
    with pytest.raises(ValueError, match="no frames were written"):
        write_dat(tmp_path / "e.dat", empty)
    assert not (tmp_path / "e.dat").exists()


@pytest.mark.parametrize("frames", [0.3, 7, np.float32(0.2)])
def test_simulator_run_names_what_frames_must_be(frames):
    sim = Simulator(SpikeCamera.realistic(height=4, width=8), backend="numpy", seed=0)
    with pytest.raises(TypeError, match=r"frames must be an \(N, H, W\) array or an iterable"):
        sim.run(frames)
