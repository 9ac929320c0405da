"""Quantum efficiency of a silicon photodiode, from silicon's absorption coefficient.

Why a model rather than a datasheet curve: the spike camera's QE curve is not published, and a
two-parameter collection model built on measured absorption gives a curve of the right shape
(blue loss near the surface, red/NIR loss below the collection depth) whose assumptions are
explicit and adjustable.

Model (the standard photodiode collection model; e.g. Sze & Ng, *Physics of Semiconductor
Devices*, 3rd ed., section 13.2; Theuwissen, *Solid-State Imaging with CCDs*, 1995, ch. 6):

    QE(lambda) = T_stack * [exp(-alpha d_dead) - exp(-alpha d_collect)]

photons absorbed between the recombining surface layer (depth d_dead) and the bottom of the
collection region (d_collect) are collected; T_stack is the transmittance of the dielectric
stack above the silicon.
"""
from __future__ import annotations

import numpy as np

#: Absorption coefficient of intrinsic silicon at 300 K, 1/cm, against wavelength in nm.
#: Values read from M. A. Green, "Self-consistent optical parameters of intrinsic silicon at
#: 300 K including temperature coefficients", Sol. Energy Mater. Sol. Cells 92 (2008) 1305,
#: Table 1 (rounded to 3 significant figures).
SILICON_ABSORPTION_PER_CM = {
    360: 1.02e6, 370: 6.97e5, 380: 2.93e5, 390: 1.50e5, 400: 9.52e4, 410: 6.74e4, 420: 5.00e4,
    430: 3.96e4, 440: 3.11e4, 450: 2.55e4, 460: 2.10e4, 470: 1.72e4, 480: 1.48e4, 490: 1.28e4,
    500: 1.11e4, 510: 9.70e3, 520: 8.80e3, 530: 7.85e3, 540: 7.05e3, 550: 6.39e3, 560: 5.78e3,
    570: 5.32e3, 580: 4.88e3, 590: 4.49e3, 600: 4.14e3, 610: 3.81e3, 620: 3.52e3, 630: 3.27e3,
    640: 3.04e3, 650: 2.81e3, 660: 2.58e3, 670: 2.38e3, 680: 2.21e3, 690: 2.05e3, 700: 1.90e3,
    710: 1.77e3, 720: 1.66e3, 730: 1.54e3, 740: 1.42e3, 750: 1.30e3, 760: 1.19e3, 770: 1.10e3,
    780: 1.01e3, 790: 9.28e2, 800: 8.50e2, 810: 7.75e2, 820: 7.07e2, 830: 6.47e2, 840: 5.91e2,
    850: 5.35e2, 900: 3.06e2, 950: 1.57e2, 1000: 6.40e1, 1050: 1.63e1, 1100: 3.50e0,
}


def absorption_per_um(wavelength_nm: np.ndarray) -> np.ndarray:
    """Silicon's absorption coefficient in 1/um, interpolated in log space (it spans 6 decades)."""
    lam = np.array(sorted(SILICON_ABSORPTION_PER_CM), dtype=np.float64)
    log_alpha = np.log(np.array([SILICON_ABSORPTION_PER_CM[int(k)] for k in lam]))
    wl = np.asarray(wavelength_nm, dtype=np.float64)
    if wl.size and (wl.min() < lam[0] or wl.max() > lam[-1]):
        raise ValueError(f"wavelengths {wl.min():.0f}-{wl.max():.0f} nm are outside the silicon "
                         f"absorption table ({lam[0]:.0f}-{lam[-1]:.0f} nm)")
    return np.exp(np.interp(wl, lam, log_alpha)) * 1e-4  # 1/cm -> 1/um


def quantum_efficiency(wavelength_nm: np.ndarray, dead_layer_um: float, collection_depth_um: float,
                       stack_transmittance: float) -> np.ndarray:
    """Electrons collected per photon reaching the pixel's photosensitive area (0..1)."""
    if not 0.0 <= dead_layer_um < collection_depth_um:
        raise ValueError(f"need 0 <= dead_layer_um ({dead_layer_um}) < collection_depth_um ({collection_depth_um})")
    if not 0.0 < stack_transmittance <= 1.0:
        raise ValueError(f"stack_transmittance={stack_transmittance} must be in (0, 1]")
    alpha = absorption_per_um(wavelength_nm)
    return stack_transmittance * (np.exp(-alpha * dead_layer_um) - np.exp(-alpha * collection_depth_um))


__all__ = ["SILICON_ABSORPTION_PER_CM", "absorption_per_um", "quantum_efficiency"]
