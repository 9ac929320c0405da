"""Helpers shared by the sensor tests (a uniquely named module: sub-folders have their own
conftest.py, so `from conftest import ...` would be ambiguous)."""
from __future__ import annotations

import pytest


def _drjit_available() -> bool:
    try:
        from spikesim._drjit import has_llvm
        return has_llvm()
    except Exception:  # pragma: no cover - depends on the machine
        return False


HAS_LLVM = _drjit_available()


def _drjit_any() -> list[str]:
    try:
        from spikesim.simulate import available_backends
        return [b for b in available_backends() if b != "numpy"]
    except Exception:  # pragma: no cover
        return []


#: Dr.Jit backends on this machine (llvm on the CPU; cuda where a GPU is present).
DRJIT_BACKENDS = _drjit_any()
#: The backend tests use where they need one fast Dr.Jit backend.
FAST_BACKEND = "cuda" if "cuda" in DRJIT_BACKENDS else ("llvm" if "llvm" in DRJIT_BACKENDS else None)
BACKENDS = ["numpy"] + DRJIT_BACKENDS


def drjit_backends() -> list[str]:
    from spikesim.simulate import available_backends
    return [b for b in available_backends() if b != "numpy"]


requires_llvm = pytest.mark.skipif(not HAS_LLVM, reason="Dr.Jit LLVM backend unavailable (needs libLLVM >= 17)")
requires_drjit = pytest.mark.skipif(FAST_BACKEND is None, reason="no Dr.Jit backend (needs libLLVM >= 17 or CUDA)")
