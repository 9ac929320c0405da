"""Shared settings for the model's tests: few threads (the CI machine has 2 cores, shared)."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))  # modeltest_fakes


@pytest.fixture(autouse=True)
def _small_torch():
    torch.set_num_threads(min(2, torch.get_num_threads()))
    torch.manual_seed(0)
    yield
