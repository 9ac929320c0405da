"""Import Dr.Jit with its LLVM backend pointed at a libLLVM that works.

Dr.Jit 1.5's CPU backend needs libLLVM >= 17; older ones crash with "Cannot select: fminimum"
(docs/design.md section 6). Debian's `libllvm19` works, but Dr.Jit does not find it by itself, so the
path is set here, before the first `import drjit`, unless the user set DRJIT_LIBLLVM_PATH.
"""
from __future__ import annotations

import gc
import glob
import os
from contextlib import contextmanager
from typing import Iterator

_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
    "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/aarch64-linux-gnu/libLLVM-19.so",
    "/usr/lib/llvm-19/lib/libLLVM.so",
    "/usr/lib/llvm-18/lib/libLLVM.so",
    "/usr/lib/llvm-17/lib/libLLVM.so",
    "/opt/homebrew/opt/llvm/lib/libLLVM.dylib",
)


def find_libllvm() -> str | None:
    """Return a libLLVM >= 17 on this machine, or None."""
    for path in _CANDIDATES:
        if os.path.exists(path):
            return path
    for path in sorted(glob.glob("/usr/lib/*/libLLVM*.so*"), reverse=True):
        name = os.path.basename(path)
        for major in ("17", "18", "19", "20", "21"):
            if f"-{major}" in name or f".so.{major}" in name:
                return path
    return None


def configure() -> None:
    """Set DRJIT_LIBLLVM_PATH before Dr.Jit is imported (no-op if the user set it)."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        path = find_libllvm()
        if path is not None:
            os.environ["DRJIT_LIBLLVM_PATH"] = path


configure()
import drjit as dr  # noqa: E402  (must follow configure())


@contextmanager
def collector_held() -> Iterator[None]:
    """Python's cyclic garbage collector held off while the block runs: wrap calls of `dr.freeze`
    functions in it. Dr.Jit 1.5 ends the process (std::terminate: "RecordThreadState::
    enqueue_host_func(): this function cannot be recorded!") when a collection that starts during a
    frozen function's recording frees an array wrapping NumPy memory without a copy: the release
    of that memory is a host callback, which a recording refuses, and the refusal is thrown from a
    destructor. A collection can start at any allocation, so which run it kills depends on what ran
    before (a CI run of the test suite died of it). The collection runs after the block instead."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def has_llvm() -> bool:
    return bool(dr.has_backend(dr.JitBackend.LLVM))


def has_cuda() -> bool:
    return bool(dr.has_backend(dr.JitBackend.CUDA))


DEVICES = ("llvm", "cuda")
#: What a user may ask for: a device, or "auto" (the GPU when there is one).
DEVICE_CHOICES = ("auto",) + DEVICES


def resolve_device(device: str) -> str:
    """"auto" -> "cuda" where Dr.Jit finds a CUDA GPU, else "llvm" (the CPU); a device that is
    not here is an UnavailableError that says so in one line."""
    from .errors import UnavailableError
    if device not in DEVICE_CHOICES:
        raise ValueError(f"device={device!r}; expected one of {DEVICE_CHOICES}")
    if device == "auto":
        return "cuda" if has_cuda() else "llvm"
    if device == "cuda" and not has_cuda():
        raise UnavailableError("--device cuda: Dr.Jit finds no CUDA GPU or driver on this machine; "
                               "use --device llvm (the CPU) or auto")
    if device == "llvm" and not has_llvm():
        raise UnavailableError("--device llvm: Dr.Jit's CPU backend needs libLLVM >= 17, which is missing")
    return device


__all__ = ["dr", "configure", "find_libllvm", "has_llvm", "has_cuda", "DEVICES", "DEVICE_CHOICES", "resolve_device"]
