"""Shared fixtures. Like Mitsuba's own tests, Dr.Jit caches are cleared between tests so that
one test's kernels and memory do not leak into the next."""
from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


from sensor_testing import HAS_LLVM


@pytest.fixture(autouse=True)
def _clean_drjit():
    yield
    if HAS_LLVM:
        from spikesim._drjit import dr
        dr.sync_thread()
        dr.flush_kernel_cache()
        dr.flush_malloc_cache()


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared test data not found at {SHARED_DATA} (see ../shared/data/README.md)")
    return SHARED_DATA

