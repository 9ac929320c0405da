"""Mitsuba set-up: the libLLVM path and variant selection.

Mitsuba's variant is process-global, so every entry point that touches Mitsuba objects calls
`use_variant` first; that keeps a mono and a spectral renderer usable in one process.
"""
from __future__ import annotations

from spikesim._drjit import DEVICE_CHOICES, DEVICES, dr, resolve_device  # noqa: F401  (dr first: sets DRJIT_LIBLLVM_PATH before mitsuba imports drjit)

import mitsuba as mi

#: Our variant names -> the Mitsuba variant suffix (docs/scenes.md section 5: mono is the fast path,
#: spectral weighted by the silicon response is the accurate one, rgb is for previews only).
VARIANTS = {"mono": "ad_mono", "spectral": "ad_spectral", "rgb": "ad_rgb"}
def variant_name(variant: str, device: str = "llvm") -> str:
    """The Mitsuba variant string for one of our variants on a device ("auto" resolved here)."""
    if variant not in VARIANTS:
        raise ValueError(f"variant={variant!r}; expected one of {tuple(VARIANTS)}")
    device = resolve_device(device)
    name = f"{device}_{VARIANTS[variant]}"
    if name not in mi.variants():
        raise RuntimeError(f"Mitsuba variant {name!r} is not in this build (has {mi.variants()})")
    return name


def use_variant(name: str) -> None:
    """Switch Mitsuba to `name` if it is not already active (switching is cheap but not free)."""
    if mi.variant() != name:
        mi.set_variant(name)


__all__ = ["VARIANTS", "DEVICES", "DEVICE_CHOICES", "resolve_device", "variant_name", "use_variant", "mi", "dr"]
