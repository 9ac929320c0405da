"""spikesim: a spike camera simulator for low light (integrate-and-fire sensor, Dr.Jit kernels,
PKU `.dat` streams) and the scene rendering that feeds it."""
from __future__ import annotations

from importlib import import_module, metadata

try:
    __version__ = metadata.version("spikesim")  # one version: pyproject.toml's, as installed
except metadata.PackageNotFoundError:  # a checkout used without installing it
    __version__ = "0+unknown"

from .camera import NOISE_TERMS, SpikeCamera  # noqa: E402
from .stream import DatReader, DatWriter, SpikeStream, read_dat, write_dat  # noqa: E402


def __getattr__(name: str):
    # The simulator imports Dr.Jit; keep `import spikesim` light for stream-only users.
    # import_module, not `from . import simulate`: that asks this very hook for `simulate` first
    # and recursed without end in a fresh interpreter. The function `simulate` is not exported
    # here: once imported, `spikesim.simulate` is the submodule (spikesim.simulate.simulate).
    if name in ("Simulator", "available_backends"):
        return getattr(import_module(".simulate", __name__), name)
    raise AttributeError(name)


__all__ = ["SpikeCamera", "NOISE_TERMS", "SpikeStream", "DatReader", "DatWriter", "read_dat", "write_dat",
           "Simulator", "available_backends", "__version__"]
