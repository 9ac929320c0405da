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


#: The light level below which l1_sum_relative stops dividing (y, expected spikes per step): about
#: the dark current of the realistic camera (docs/sensor.md), below which no stream says more.
RELATIVE_LOSS_FLOOR_Y = 1e-3


def _l1_sum_weighted(pred: torch.Tensor, target: torch.Tensor,
                     weight: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """l1_sum with each sample's error times weight(level), the level being the sample's mean ground
    truth over its K windows, at least RELATIVE_LOSS_FLOOR_Y; the level is a weight, not learned."""
    _check(pred, target)
    level = target.detach().flatten(1).mean(dim=1).clamp_min(RELATIVE_LOSS_FLOOR_Y)
    per_sample_window = (pred - target).abs().flatten(2).mean(dim=2) * weight(level)[:, None]  # (B, K)
    return per_sample_window.mean(dim=0).sum()


def _l1_sum_light_weighted(pred: torch.Tensor, target: torch.Tensor, power: float) -> torch.Tensor:
    """Weight 1 / level**power: power 0 is l1_sum, 1 the relative loss, 1/2 the shot-noise weighting."""
    return _l1_sum_weighted(pred, target, lambda level: level ** -power)


@LOSS_REGISTRY.register("l1_sum_relative")
def l1_sum_relative(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """l1_sum with each sample's error divided by its light level (the mean ground truth over its K
    windows, at least RELATIVE_LOSS_FLOOR_Y). Why: with plain L1 a 100 lx sample outweighs a 1 lx
    one a hundredfold, so a small network spends itself on the bright scenes and learns little of
    the dark ones it is judged on; relative to the light, every sample counts alike, as the
    light-normalised and aligned metrics count every frame alike (model/metrics.py)."""
    return _l1_sum_light_weighted(pred, target, 1.0)


@LOSS_REGISTRY.register("l1_sum_shot")
def l1_sum_shot(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """l1_sum with each sample's error divided by the square root of its light level (floored as in
    l1_sum_relative): between plain L1 and the relative loss. Why: a window's spike count is
    Poisson, so a window average's error grows as sqrt(level); relative to that shot-noise floor a
    bright sample, where a window average is already good, weighs sqrt(level) times what the
    relative loss gives it (a 100-fold brighter sample 10 times more), and a dark one still far
    more than plain L1 gives it. A lever of issue 39 (loss weights by light level), measured in
    docs/model.md."""
    return _l1_sum_light_weighted(pred, target, 0.5)


#: The light level (y, expected spikes per step) where l1_sum_knee turns from the relative weighting
#: to the shot-noise one, set from light levels (docs/model.md, "The knee loss"): the validation
#: scene the shot loss lost (val_nat8 rllr_0001, mean y 4.5e-4) lies far below it, as do most natural
#: scenes (median mean y 0.002, docs/scenes.md
#: section 11); the bright photo scenes and REDS-like frames where the shot loss gained (y 0.1-0.35)
#: lie far above it. A sample at y 0.3 then weighs 1/55 of one at the floor: relative 1/300, shot 1/17.
KNEE_LOSS_KNEE_Y = 1e-2


@LOSS_REGISTRY.register("l1_sum_knee")
def l1_sum_knee(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """l1_sum with each sample's error times 1 / (sqrt(level) * sqrt(min(level, KNEE_LOSS_KNEE_Y))):
    the relative loss (1 / level) below the knee, the shot-noise weighting (1 / sqrt(level * knee))
    above it, continuous at the knee. Why: the shot loss's budget run gained in bright light but lost
    3-4 dB on the darkest natural scenes, where the relative loss weighs a sample 10 times more
    against one at y 0.01 and the shot loss only 3 times more (docs/model.md); this keeps the
    relative loss's balance among dark samples and the shot loss's among bright ones. Measured in a
    budget run, not kept: the darkest scene stayed without structure (docs/model.md, "The knee loss")."""
    return _l1_sum_weighted(
        pred, target, lambda level: 1.0 / (level.sqrt() * level.clamp_max(KNEE_LOSS_KNEE_Y).sqrt()))


#: The loss of networks trained from spikes alone (SSML, model/published_nets/ssml.py): the model
#: computes it, `model.self_supervised_loss(spikes)`, with no ground truth; the training step
#: calls it through SelfSupervisedObjective instead of comparing a prediction with a target.
SELF_SUPERVISED = "self_supervised"


@LOSS_REGISTRY.register(SELF_SUPERVISED)
def self_supervised(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    raise TypeError("the self_supervised loss comes from the model (model.self_supervised_loss(spikes)), "
                    "not from a prediction and a target")


class SelfSupervisedObjective(torch.nn.Module):
    """forward(spikes) -> model.self_supervised_loss(spikes): the training objective of a network
    that learns from spikes alone, as a module so that DDP wraps it as it wraps a forward pass."""

    def __init__(self, model: torch.nn.Module) -> None:
        super().__init__()
        if not callable(getattr(model, "self_supervised_loss", None)):
            raise ValueError(f"train.loss {SELF_SUPERVISED!r} needs a network that learns from spikes alone "
                             f"(one with self_supervised_loss, e.g. arch \"ssml\"); {type(model).__name__} has none")
        self.model = model

    def forward(self, spikes: torch.Tensor) -> torch.Tensor:
        return self.model.self_supervised_loss(spikes)


def build_loss(name: str) -> Loss:
    return LOSS_REGISTRY.get(name)
