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
