"""What a network costs, counted rather than timed: parameters, FLOP per reconstructed frame and
FLOP per training step, from the config alone.

The count runs the network on the `meta` device (shapes only, no memory, well under a second), under
torch's FlopCounterMode, which counts convolutions and matrix products (2 FLOP per multiply-add).
Deformable convolution runs through the pure-torch path for the count (model/deform.py); its
convolution part is a matrix product and counted, its bilinear sampling is not an op the counter
knows, so it is added here at 8 FLOP per sampled value and channel forward (four multiply-adds of
the corners) and 16 backward, and reported apart (`sampling_flop`) so a reader sees what was added.
Element-wise work (activations, the representation's maps, the optimiser's update) is left out, as
in the papers' FLOP figures.

Equal compute between methods (issue 28's tables) is equal steps of networks whose FLOP per step is
stated beside them; time on a shared 2-core machine is recorded too but is not the budget.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode

#: FLOP per bilinear sample and channel: four corner weights times values, summed (4 multiply-adds).
SAMPLE_FLOP_FORWARD = 8
SAMPLE_FLOP_BACKWARD = 16  # the gradient reaches the input's four corners and the grid's two coordinates


def _prod(shape: Any) -> int:
    return math.prod(int(s) for s in shape)


def _grid_sample_flop(input_shape: Any, grid_shape: Any, *args: Any, out_shape: Any = None, **kwargs: Any) -> int:
    return SAMPLE_FLOP_FORWARD * _prod(out_shape)


def _grid_sample_backward_flop(grad_shape: Any, *args: Any, out_shape: Any = None, **kwargs: Any) -> int:
    return SAMPLE_FLOP_BACKWARD * _prod(grad_shape)


def _sampling_ops() -> dict[Any, Any]:
    aten = torch.ops.aten
    return {aten.grid_sampler_2d: _grid_sample_flop,
            aten.grid_sampler_2d_backward: _grid_sample_backward_flop}


@dataclass(frozen=True)
class Cost:
    """One network's cost. flop_per_frame: one more window of a long stream at height x width (the
    recurrent nets' steady state); train_flop_per_step: forward and backward of one batch at the
    config's crop, batch and K; sampling_flop: the part of flop_per_frame that is deformable sampling."""

    parameters: int
    height: int
    width: int
    flop_per_frame: int
    sampling_flop_per_frame: int
    train_flop_per_step: int

    @property
    def gflop_per_frame(self) -> float:
        return self.flop_per_frame / 1e9

    def to_dict(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "gflop_per_frame": self.gflop_per_frame,
                "train_gflop_per_step": self.train_flop_per_step / 1e9}


def _counted(fn: Any) -> tuple[int, int]:
    """(all FLOP, sampling FLOP) of fn() on the meta device."""
    counter = FlopCounterMode(display=False, custom_mapping=_sampling_ops())
    with counter:
        fn()
    counts = counter.get_flop_counts().get("Global", {})
    sampling = sum(v for k, v in counts.items() if "grid_sampler" in str(k))
    return int(counter.get_total_flops()), int(sampling)


def network_cost(experiment: Any, height: int, width: int) -> Cost:
    """Parameters, FLOP per frame at height x width and FLOP per training step of a config
    (an ExperimentConfig: its model, and its train section's crop, batch and K)."""
    from .arch import build_model, count_parameters

    if height < 1 or width < 1:
        raise ValueError(f"network_cost: frame size must be positive, got {height} x {width}")
    mc = experiment.model
    if hasattr(mc, "deform_backend"):
        mc = dataclasses.replace(mc, deform_backend="torch")  # countable on meta; same arithmetic
    tc = experiment.train
    t = mc.window
    with torch.device("meta"):
        model = build_model(mc)
        params = count_parameters(model)
        model.eval()

        def frames(k: int) -> tuple[int, int]:
            x = torch.zeros(1, k, t, height, width, dtype=torch.bool)
            with torch.no_grad():
                return _counted(lambda: model(x))
        # one more window of a long stream: the difference between 3 and 2 windows (the first
        # window of each direction skips alignment, so a single window would undercount)
        (f3, s3), (f2, s2) = frames(3), frames(2)
        model.train()
        crop = getattr(tc, "crop", 32)
        x = torch.zeros(tc.batch_size, tc.num_windows, t, crop, crop, dtype=torch.bool)

        def step() -> None:
            if getattr(tc, "loss", None) == "self_supervised":  # its training runs its own objective (SSML)
                model.self_supervised_loss(x).float().backward()
            else:
                model(x).float().sum().backward()
        train, _ = _counted(step)
    return Cost(params, height, width, f3 - f2, s3 - s2, train)
