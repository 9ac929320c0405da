"""Shared fixtures. Like Mitsuba's own tests, Dr.Jit caches are cleared between tests so that
one test's kernels and memory do not leak into the next."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

#: Optional test data that is not part of the repository: `spk2imgnet-sample/`, one spike stream
#: of the Spk2ImgNet synthetic test set (`203_part1_key_id151.dat`, 301 frames of 250 x 400, rows
#: flipped) and its 8-bit ground truth at frame 151 (`203_part1_key_id151.png`), as published in
#: the Spike-Zoo and WGSE repositories. Looked for in $SPIKESIM_TEST_DATA, else in `shared/data`
#: beside the repository's folder; the tests that need it skip when it is absent.
SHARED_DATA = Path(os.environ.get("SPIKESIM_TEST_DATA")
                   or Path(__file__).resolve().parents[2] / "shared" / "data")


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
        pytest.skip(f"optional test data not found at {SHARED_DATA}: set SPIKESIM_TEST_DATA to a folder "
                    "holding spk2imgnet-sample/ (see tests/conftest.py)")
    return SHARED_DATA

