"""train.trainable "gates": a refining head's gates trained on a frozen direct network. The body and
the network's own frame must stay the --init network's bit for bit, the gates must learn, and a cut
run must resume to the same bits as an uncut one."""
from __future__ import annotations

import dataclasses

import pytest
import torch
from test_round20 import _dataset

from model.arch import REFINE_GATE_GAIN, REFINE_GATE_LOGIT, build_model, trainable_parameters
from model.checkpoint import load_checkpoint
from model.config import ExperimentConfig, ModelConfig, TrainConfig
from model.data import open_scenes
from model.training import run_training

TINY = ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2)


def _experiment(output: str, trainable: str = "all", max_steps: int = 3, seed: int = 3) -> ExperimentConfig:
    model = dataclasses.replace(TINY, output=output, refine_span=3 if output == "refine" else 1)
    return ExperimentConfig(f"tiny_{output}_{trainable}", model=model,
                            train=TrainConfig(num_windows=3, crop=8, batch_size=1, epochs=10, lr_milestones=(50,),
                                              samples_per_epoch=1, val_fraction=0.0, max_steps=max_steps,
                                              lr=1e-2, seed=seed, trainable=trainable))


@pytest.fixture(scope="module")
def direct(tmp_path_factory):
    """A direct network trained a few steps (its frame is not the starting draw), and the data."""
    root = tmp_path_factory.mktemp("gates")
    train, val = _dataset(root / "train", 0.3), _dataset(root / "val", 0.05, side=12)
    run_training(_experiment("direct", max_steps=2), open_scenes(train), open_scenes(val), root / "direct",
                 device="cpu", progress=False)
    return root / "direct" / "last.pt", train, val


def _gates_run(direct, out, max_steps=3, resume=False):
    ckpt, train, val = direct
    run_training(_experiment("refine", "gates", max_steps=max_steps, seed=5), open_scenes(train), open_scenes(val),
                 out, device="cpu", progress=False, resume=resume, init=None if resume else str(ckpt))
    return load_checkpoint(out / "last.pt")["model_state"]


def test_only_the_gate_rows_of_the_heads_last_conv_move(direct, tmp_path):
    start = load_checkpoint(direct[0])["model_state"]
    got = _gates_run(direct, tmp_path / "g")
    last_w, last_b = "head.1.weight", "head.1.bias"
    for k, v in start.items():
        if k not in (last_w, last_b):
            assert torch.equal(got[k], v), f"{k} changed: the body must stay the direct network's"
    # the network's own frame: row 0 of the last conv, exactly the direct network's
    assert torch.equal(got[last_w][:1], start[last_w])
    assert torch.equal(got[last_b][:1], start[last_b])
    # the gates started closed with zero weights (init_gate_channels) and learned
    assert got[last_w].shape[0] == 4
    assert got[last_w][1:].abs().sum() > 0
    assert got[last_b][1] != pytest.approx(REFINE_GATE_LOGIT / REFINE_GATE_GAIN, abs=1e-9)


def test_a_cut_gates_run_resumes_to_the_uncut_runs_bits(direct, tmp_path):
    whole = _gates_run(direct, tmp_path / "whole", max_steps=4)
    _gates_run(direct, tmp_path / "cut", max_steps=2)
    resumed = _gates_run(direct, tmp_path / "cut", max_steps=4, resume=True)
    assert all(torch.equal(whole[k], resumed[k]) for k in whole)


def test_gates_alone_leave_the_gate_rows_alone_to_train():
    model = build_model(dataclasses.replace(TINY, output="refine"))
    params = trainable_parameters(model, "gates")
    assert [p.shape for p in params] == [model.head[-1].weight.shape, model.head[-1].bias.shape]
    assert sum(p.requires_grad for p in model.parameters()) == 2
    # the hook holds the frame row's gradient at 0
    (model.head[-1].weight.sum() + model.head[-1].bias.sum()).backward()
    assert model.head[-1].weight.grad[0].abs().sum() == 0 and model.head[-1].bias.grad[0] == 0
    assert model.head[-1].weight.grad[1:].abs().min() == 1


def test_gates_alone_need_a_refining_head_and_the_option_is_checked():
    with pytest.raises(ValueError, match="trainable='gates'.*model.output 'refine'"):
        _experiment("direct", "gates")
    with pytest.raises(ValueError, match="train.trainable must be one of"):
        TrainConfig(trainable="body")
    with pytest.raises(ValueError, match="needs a refining head"):
        trainable_parameters(build_model(TINY), "gates")
    with pytest.raises(ValueError, match="trainable must be one of"):
        trainable_parameters(build_model(TINY), "body")


def test_the_head_alone_trains_on_the_frozen_body():
    model = build_model(TINY)
    params = trainable_parameters(model, "head")
    assert {id(p) for p in params} == {id(p) for p in model.head.parameters()}
    frozen = [n for n, p in model.named_parameters() if not p.requires_grad]
    assert frozen and not any(n.startswith("head.") for n in frozen)
    assert all(p.requires_grad for p in trainable_parameters(build_model(TINY), "all"))
