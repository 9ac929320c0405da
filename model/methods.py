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


def black_windows(windows: torch.Tensor) -> torch.Tensor:
    """The floor every table shows: an all-black image, whatever the spikes."""
    return torch.zeros(windows.shape[:1] + windows.shape[2:], dtype=torch.float32)


def mean_windows(windows: torch.Tensor) -> torch.Tensor:
    """A constant image at the window's mean firing rate: right overall light, no structure."""
    rate = tfp_windows(windows).mean(dim=(-2, -1), keepdim=True)
    return rate.expand(windows.shape[:1] + windows.shape[2:]).contiguous()


#: Images without structure, the floor every table shows.
FLOORS = ("black", "mean")

#: Methods that map each window to an image on its own: the paper's baselines and two floors.
MAP_METHODS = {"tfp": tfp_windows, "tfi": tfi_windows, "black": black_windows, "mean": mean_windows}

@dataclass
class MapMethod:
    """TFP or TFI of each window on its own (the paper's baselines), or a trivial floor."""

    name: str
    kind: str  # a key of MAP_METHODS
    window: int = 41
    chunk: int = 64

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        fn = MAP_METHODS[self.kind]
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
    """"tfp", "tfi", "black", "mean", or a checkpoint path; "label=..." names the method in tables."""
    label, _, body = spec.rpartition("=") if "=" in spec else ("", "", spec)
    if body in MAP_METHODS:
        return MapMethod(label or (body.upper() if body in ("tfp", "tfi") else body), body, window)
    if body == "lrrep":  # the name shipped weights will load by; none ship yet
        raise ValueError("method 'lrrep': no trained weights ship with this version (training at the paper's "
                         "scale needs a GPU, docs/model.md); train a model with `spikesim train` and pass "
                         "LABEL=path/to/best.pt")
    path = Path(body.removeprefix("ckpt:"))
    if not path.is_file():
        raise ValueError(f"method {spec!r}: expected one of {', '.join(MAP_METHODS)} or an existing checkpoint file")
    return ModelMethod(label or path.parent.name or path.stem, path, chunk, device)
