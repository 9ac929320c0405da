"""spikesim: a spike camera simulator for low light (integrate-and-fire sensor, Dr.Jit kernels,
PKU `.dat` streams) and the scene rendering that feeds it."""
from __future__ import annotations

from importlib import import_module, metadata

try:
    __version__ = metadata.version("spikesim")  # one version: pyproject.toml's, as installed
except metadata.PackageNotFoundError:  # a checkout used without installing it
    __version__ = "0+unknown"

from .camera import NOISE_TERMS, SpikeCamera  # noqa: E402

_LAZY = {"Simulator": ".simulate", "available_backends": ".simulate", "DatReader": ".stream", "DatWriter": ".stream",
         "SpikeStream": ".stream", "read_dat": ".stream", "write_dat": ".stream"}


def __getattr__(name: str):
    # Imported on first use: the simulator pulls in Dr.Jit and the stream NumPy, and the package
    # itself must stay importable without either (spikesim.outputs serves the GPU campaign before
    # it has installed anything). import_module, not `from . import simulate`: that asks this very
    # hook for `simulate` first and recursed without end in a fresh interpreter. The function
    # `simulate` is not exported here: once imported, `spikesim.simulate` is the submodule.
    if name in _LAZY:
        return getattr(import_module(_LAZY[name], __name__), name)
    raise AttributeError(name)


__all__ = ["SpikeCamera", "NOISE_TERMS", "SpikeStream", "DatReader", "DatWriter", "read_dat", "write_dat",
           "Simulator", "available_backends", "__version__"]
