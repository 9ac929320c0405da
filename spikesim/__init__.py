"""spikesim: a spike camera simulator for low light (integrate-and-fire sensor, Dr.Jit kernels,
PKU `.dat` streams) and the scene rendering that feeds it."""
from __future__ import annotations

__version__ = "0.1.0"

from .camera import NOISE_TERMS, SpikeCamera  # noqa: E402
from .stream import DatReader, DatWriter, SpikeStream, read_dat, write_dat  # noqa: E402


def __getattr__(name: str):
    # The simulator imports Dr.Jit; keep `import spikesim` light for stream-only users.
    if name in ("Simulator", "simulate", "available_backends"):
        from . import simulate as _sim
        return getattr(_sim, name)
    raise AttributeError(name)


__all__ = ["SpikeCamera", "NOISE_TERMS", "SpikeStream", "DatReader", "DatWriter", "read_dat", "write_dat",
           "Simulator", "simulate", "available_backends", "__version__"]
