"""Training precision: bf16 autocast by default on GPUs that support it, fp16 autocast with a
GradScaler or fp32 by choice; fp32 by default elsewhere (bf16 and fp16 autocast work on the CPU
too, when asked for).

Why bf16 first: the raw GISI input reaches K x T + 1 (862 for 21 windows of 41 steps) where a
pixel never fired, and the features computed from it are summed over 64 channels x 9 taps per
convolution. bf16 has float32's exponent range, so nothing it computes overflows where float32
would not; fp16 tops out at 65504 and needs a GradScaler to keep small gradients from vanishing.
"""
from __future__ import annotations

import contextlib
from typing import Any

import torch

PRECISIONS = ("auto", "bf16", "fp16", "fp32")
DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


def resolve_precision(name: str, device: torch.device) -> str:
    """"bf16", "fp16" or "fp32" for `name` on `device`. "auto": bf16 on a CUDA GPU that supports
    it, fp16 on an older one, fp32 on the CPU and elsewhere. bf16 asked for on a GPU without it is
    an UnavailableError naming --precision."""
    from spikesim.errors import UnavailableError

    if name not in PRECISIONS:
        raise ValueError(f"--precision {name!r}: expected one of {', '.join(PRECISIONS)}")
    if name == "auto":
        if device.type == "cuda":
            return "bf16" if torch.cuda.is_bf16_supported() else "fp16"
        return "fp32"
    if name == "bf16" and device.type == "cuda" and not torch.cuda.is_bf16_supported():
        raise UnavailableError(f"--precision bf16 asked for, but {torch.cuda.get_device_name(device)} does not "
                               "support bfloat16; use --precision fp16 or fp32")
    return name


def autocast(precision: str, device: torch.device) -> Any:
    """The forward pass's context: autocast to bf16 / fp16, or nothing for fp32."""
    if precision == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(device.type, dtype=DTYPES[precision])


def grad_scaler(precision: str, device: torch.device) -> torch.amp.GradScaler:
    """A GradScaler, enabled for fp16 only (bf16 and fp32 gradients do not underflow)."""
    return torch.amp.GradScaler(device.type, enabled=precision == "fp16")


__all__ = ["PRECISIONS", "resolve_precision", "autocast", "grad_scaler"]
