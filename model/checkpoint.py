"""Checkpoints: atomic writes (temp file in the same folder, then rename) and self-describing
contents (the configs travel with the weights, so a checkpoint alone rebuilds its network)."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import torch

from .arch import build_model
from .config import ExperimentConfig

FORMAT_VERSION = 1


def atomic_torch_save(obj: Any, path: str | Path) -> None:
    """torch.save to a temp file beside `path`, fsync, then os.replace: a crash mid-write never
    leaves a truncated checkpoint under the final name."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(obj, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_checkpoint(path: str | Path, model: torch.nn.Module, experiment: ExperimentConfig,
                    optimizer: torch.optim.Optimizer | None = None, scheduler: Any = None,
                    scaler: Any = None, epoch: int = 0, step: int = 0,
                    extra: dict[str, Any] | None = None) -> None:
    state = {
        "format_version": FORMAT_VERSION,
        "experiment": experiment.to_dict(),
        "model_state": model.state_dict(),
        "optimizer_state": optimizer.state_dict() if optimizer is not None else None,
        "scheduler_state": scheduler.state_dict() if scheduler is not None else None,
        "scaler_state": scaler.state_dict() if scaler is not None else None,
        "epoch": epoch,
        "step": step,
        "rng": {"torch": torch.get_rng_state(),
                "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None},
        "extra": extra or {},
    }
    atomic_torch_save(state, path)


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    state = torch.load(path, map_location=map_location, weights_only=False)
    if not isinstance(state, dict) or state.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{path}: not a checkpoint of this project (format_version "
                         f"{state.get('format_version') if isinstance(state, dict) else None!r}, "
                         f"expected {FORMAT_VERSION})")
    return state


def model_from_checkpoint(path: str | Path, map_location: str | torch.device = "cpu"
                          ) -> tuple[torch.nn.Module, ExperimentConfig]:
    """Rebuild the network a checkpoint describes and load its weights (strict)."""
    state = load_checkpoint(path, map_location)
    experiment = ExperimentConfig.from_dict(state["experiment"], where=f"{path} experiment")
    model = build_model(experiment.model)
    model.load_state_dict(state["model_state"])
    return model.to(map_location), experiment

