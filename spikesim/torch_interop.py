"""Spike words from the sensor to torch, on the device they were made on.

The Dr.Jit kernels leave packed words (32 pixels per UInt32, least significant bit first) on
their device; `DevicePacked.to_torch()` hands them to torch through DLPack without a copy, and
`unpack_words` expands them there, so a training loop can read spikes straight from the sensor.
"""
from __future__ import annotations

import torch


def unpack_words(words: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """(..., n, G) 32-bit words -> (..., n, height, width) bool spikes, on the words' device.

    G = ceil(height * width / 32); bit b of word g is pixel 32 g + b in row-major order (the
    `.dat` frame layout before any vertical flip)."""
    pixels = height * width
    if words.shape[-1] * 32 < pixels:
        raise ValueError(f"{words.shape[-1]} words per frame cannot hold {height}x{width} pixels")
    # torch has few operations on uint32; the same bits as int32 shift and mask alike.
    signed = words.view(torch.int32) if words.dtype == torch.uint32 else words.to(torch.int32)
    shifts = torch.arange(32, device=words.device, dtype=torch.int32)
    bits = (signed.unsqueeze(-1) >> shifts) & 1
    bits = bits.flatten(-2)[..., :pixels]
    return bits.reshape(*words.shape[:-1], height, width).to(torch.bool)


__all__ = ["unpack_words"]
