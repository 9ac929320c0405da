"""Training losses, looked up by name (LOSS_REGISTRY) so the training loop names none of them."""
from __future__ import annotations

from typing import Callable

import torch

from .registry import LOSS_REGISTRY

Loss = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def _check(pred: torch.Tensor, target: torch.Tensor) -> None:
    if pred.shape != target.shape:
        raise ValueError(f"prediction {tuple(pred.shape)} and target {tuple(target.shape)} differ in shape")
    if pred.dim() < 3:
        raise ValueError(f"expected (B, K, H, W) sequences, got shape {tuple(pred.shape)}")


@LOSS_REGISTRY.register("l1_sum")
def l1_sum_over_windows(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L = sum_{i=1..K} ||Y^_i - Y_i||_1 (paper, loss equation), each window's 1-norm taken as the
    mean absolute error over batch and pixels (the authors' torch.nn.L1Loss), so the loss does not
    scale with crop size; windows are on dim 1 of (B, K, H, W)."""
    _check(pred, target)
    per_window = (pred - target).abs().transpose(0, 1).reshape(pred.shape[1], -1).mean(dim=1)
    return per_window.sum()


@LOSS_REGISTRY.register("l1_sum_pixels")
def l1_sum_pixels(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The literal 1-norm: absolute errors summed over pixels and windows, averaged over the batch."""
    _check(pred, target)
    return (pred - target).abs().sum() / pred.shape[0]


def build_loss(name: str) -> Loss:
    return LOSS_REGISTRY.get(name)
