"""Reconstruction methods behind one interface, for the evaluate and reconstruct pipelines:
the TFP and TFI baselines and any trained checkpoint, each turning windows into frames."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Protocol

import torch

from .checkpoint import model_from_checkpoint
from .representations import tfi_windows, tfp_windows
from .streaming import WindowSource, stream_reconstruct


class Method(Protocol):
    name: str
    window: int

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        """(window index, float32 (H, W) on the y scale) for every window of the source, in order."""
        ...


@dataclass
class MapMethod:
    """TFP or TFI of each window on its own (the paper's baselines)."""

    name: str
    kind: str  # "tfp" | "tfi"
    window: int = 41
    chunk: int = 64

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        fn = tfp_windows if self.kind == "tfp" else tfi_windows
        for a in range(0, source.num_windows, self.chunk):
            b = min(a + self.chunk, source.num_windows)
            maps = fn(source.windows(a, b))
            for i in range(b - a):
                yield a + i, maps[i]


@dataclass
class ModelMethod:
    """A trained network (any config), run with exact chunked streaming inference."""

    name: str
    checkpoint: Path
    chunk: int = 8
    device: str = "cpu"

    def __post_init__(self) -> None:
        self.model, self.experiment = model_from_checkpoint(self.checkpoint, self.device)
        self.model.eval()
        self.window = self.experiment.model.window
        # GISI beyond the training horizon (K*T + 1) is clipped: see ReconNet.max_interval.
        self.model.max_interval = float(self.experiment.train.num_windows * self.window + 1)

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        yield from stream_reconstruct(self.model, source, self.chunk, self.device)


def method_from_spec(spec: str, window: int = 41, chunk: int = 8, device: str = "cpu") -> Method:
    """"tfp", "tfi", or a checkpoint path; "label=..." names the method in tables."""
    label, _, body = spec.rpartition("=") if "=" in spec else ("", "", spec)
    if body in ("tfp", "tfi"):
        return MapMethod(label or body.upper(), body, window)
    path = Path(body.removeprefix("ckpt:"))
    if not path.is_file():
        raise ValueError(f"method {spec!r}: expected 'tfp', 'tfi' or an existing checkpoint file")
    return ModelMethod(label or path.parent.name or path.stem, path, chunk, device)
