"""The reconstruction model: representations, the network, training, evaluation methods and the
shipped weights. `model.load_pretrained("lrrep")` returns the shipped network and its config;
`model.reconstruct(spikes)` runs it (or any method) on a spike stream, threads chosen as the
commands choose them (model/inference.py)."""
from __future__ import annotations

from typing import Any

from . import published_nets  # noqa: F401  registers the Table-1 networks (spk2imgnet, wgse, rsir, ssml) in ARCH_REGISTRY


def __getattr__(name: str) -> Any:  # lazy: `import model.config` must not load the weights' module
    if name == "load_pretrained":
        from .pretrained import load_pretrained
        return load_pretrained
    if name == "reconstruct":
        from .inference import reconstruct
        return reconstruct
    raise AttributeError(f"module 'model' has no attribute {name!r}")
