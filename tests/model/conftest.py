"""Shared settings for the model's tests: one torch thread. The CI machine has 2 cores shared
with other jobs; there, two OpenMP threads made a tiny training step up to 50x slower (threads
wait on each other at every op), while one thread stays fast whatever the load."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))  # modeltest_fakes


@pytest.fixture(autouse=True)
def _small_torch():
    torch.set_num_threads(1)
    torch.manual_seed(0)
    yield


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Two tiny scenes (12 x 16, 28 steps) in the project's dataset layout."""
    pytest.importorskip("OpenEXR", reason="the dataset layout stores ground truth as EXR")
    from modeltest_fakes import make_scene
    from spikesim.dataset import write_scene
    from spikesim.stream import SpikeStream
    root = tmp_path_factory.mktemp("data")
    for i in range(2):
        sc = make_scene(f"scene{i}", 12, 16, 7 * 4, brightness=0.3, seed=i)
        write_scene(root, sc.name, SpikeStream.from_bool(sc.spike_array), sc.gt, meta={})
    return root
