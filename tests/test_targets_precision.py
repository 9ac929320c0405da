"""Training precision: bf16 by default on GPUs that support it, fp16 and fp32 by flag, and a
forward + backward pass with GISI at its never-fired sentinel (K x T + 1 = 862) finite in every
precision this machine has."""
from __future__ import annotations

import argparse

import pytest
import torch

from model.arch import build_model
from model.config import ExperimentConfig, ModelConfig, TrainConfig, load_config
from model.precision import autocast, grad_scaler, resolve_precision
from model.representations import gisi

K, T = 21, 41
# The paper network's widths (64 features, 8 deformable groups) with one residual block and 8x8
# crops, so that the test stays fast: overflow comes from the widths (sums over 64 channels x 9
# taps), not from depth. fp16 autocast is emulated on the CPU (20-40 s a pass at these widths), so
# there the default suite runs it at the `tiny` config's widths and the full widths are slow.
WIDE = ModelConfig(num_blocks=1)
NARROW = ModelConfig(num_features=16, num_blocks=2, deform_groups=4)
CPU, CUDA = torch.device("cpu"), torch.device("cuda")
HAS_CUDA = torch.cuda.is_available()
CUDA_BF16 = HAS_CUDA and torch.cuda.is_bf16_supported()



@pytest.fixture(autouse=True)
def _one_thread():
    """One torch thread, as tests/model (on the shared 2-core machine two threads waited on each
    other at every op)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


CASES = [
    pytest.param(CPU, "fp32", WIDE, id="cpu-fp32"),
    pytest.param(CPU, "bf16", WIDE, id="cpu-bf16"),
    pytest.param(CPU, "fp16", NARROW, id="cpu-fp16-narrow"),
    pytest.param(CPU, "fp16", WIDE, id="cpu-fp16", marks=pytest.mark.slow),
] + [pytest.param(CUDA, p, WIDE, id=f"cuda-{p}", marks=[pytest.mark.gpu, pytest.mark.skipif(
        not HAS_CUDA or (p == "bf16" and not CUDA_BF16), reason=f"needs a CUDA GPU{' with bf16' if p == 'bf16' else ''}")])
     for p in ("fp32", "bf16", "fp16")]


def test_the_silent_stream_puts_gisi_at_its_sentinel():
    silent = torch.zeros(1, K, T, 4, 4, dtype=torch.uint8)
    g, _, _ = gisi(silent)
    assert float(g.min()) == float(g.max()) == K * T + 1 == 862


def _finite_grads(model: torch.nn.Module) -> bool:
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    return bool(grads) and all(bool(torch.isfinite(g).all()) for g in grads)


@pytest.mark.parametrize("dev,precision,config", CASES)
def test_forward_and_backward_at_the_gisi_sentinel_are_finite(dev, precision, config):
    torch.manual_seed(0)
    model = build_model(config).to(dev).train()
    spikes = torch.zeros(1, K, T, 8, 8, dtype=torch.uint8, device=dev)  # never fires: GISI = 862
    spikes[0, 5:, :, 2, 2] = 1  # one pixel at saturation from window 5 on: both extremes at once
    with autocast(precision, dev):
        pred = model(spikes)
    assert torch.isfinite(pred).all(), f"{precision}: non-finite output"
    loss = (pred.float() - 0.5).abs().mean()
    loss.backward(retain_graph=True)
    assert _finite_grads(model), f"{precision}: non-finite gradient"
    assert any(float(p.grad.abs().max()) > 0 for p in model.parameters() if p.grad is not None)
    if precision != "fp16":
        assert not grad_scaler(precision, dev).is_enabled()
        return
    # Training scales the fp16 loss: at the sentinel the GradScaler's first scale (2^16)
    # overflows (measured: it needs 2^10), so it must skip those steps, leaving the weights as
    # they are, and back off until a step goes through with finite gradients.
    scaler = grad_scaler(precision, dev)
    opt = torch.optim.SGD(model.parameters(), lr=1.0)
    before = [p.detach().clone() for p in model.parameters()]
    tries = 1 if dev.type == "cpu" and config is NARROW else 16
    for _ in range(tries):
        opt.zero_grad(set_to_none=True)
        scale = scaler.get_scale()
        scaler.scale(loss).backward(retain_graph=True)
        scaler.step(opt)
        scaler.update()
        stepped = scaler.get_scale() >= scale
        moved = any(not torch.equal(a, p.detach()) for a, p in zip(before, model.parameters()))
        assert moved == stepped, "a skipped step changed the weights, or a taken one did not"
        if stepped:
            assert _finite_grads(model) and all(torch.isfinite(p).all() for p in model.parameters())
            break
        assert scaler.get_scale() == scale / 2
    else:
        assert tries == 1, "the GradScaler found no scale with finite gradients"


def test_precision_defaults_bf16_on_gpus_that_have_it_fp32_on_the_cpu(monkeypatch):
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    assert TrainConfig().precision == "auto" and load_config("full").train.precision == "auto"
    assert resolve_precision("auto", cpu) == "fp32"
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: True)
    assert resolve_precision("auto", cuda) == "bf16"
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: False)
    assert resolve_precision("auto", cuda) == "fp16"
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda *a, **k: "an old GPU")
    from spikesim.errors import UnavailableError
    with pytest.raises(UnavailableError, match="--precision bf16"):
        resolve_precision("bf16", cuda)
    for p in ("bf16", "fp16", "fp32"):
        assert resolve_precision(p, cpu) == p
    assert grad_scaler("fp16", cpu).is_enabled() and not grad_scaler("bf16", cpu).is_enabled()


def test_configs_written_with_amp_still_read():
    assert TrainConfig.from_dict({"amp": True}).precision == "auto"
    assert TrainConfig.from_dict({"amp": False}).precision == "fp32"
    with pytest.raises(ValueError, match="precision"):
        TrainConfig(precision="fp8")
    exp = ExperimentConfig.from_dict({"name": "old", "train": {"amp": False, "max_steps": 3}})
    assert exp.train.precision == "fp32"


def test_train_flags_choose_the_precision(capsys):
    from pipelines import train as tr
    parser = argparse.ArgumentParser()
    tr.add_parser(parser.add_subparsers())
    for flags, want in ((["--precision", "bf16"], "bf16"), (["--no-amp"], "fp32"), ([], "auto")):
        args = parser.parse_args(["train", "--data", "d", *flags])
        assert tr._apply_overrides(load_config("tiny"), args).train.precision == want
    with pytest.raises(SystemExit):
        parser.parse_args(["train", "--data", "d", "--precision", "fp8"])
    with pytest.raises(SystemExit):
        parser.parse_args(["train", "--data", "d", "--precision", "bf16", "--no-amp"])
    assert "--precision" in capsys.readouterr().err


def test_a_short_bf16_run_on_the_cpu_trains(tmp_path):
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent / "model"))
    from modeltest_fakes import make_scene
    from pipelines.train import run_training
    scenes = [make_scene(f"s{i}", 16, 20, 7 * 6, brightness=0.3, velocity=0.2, seed=i) for i in range(2)]
    exp = ExperimentConfig("bf16", model=ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2),
                           train=TrainConfig(num_windows=3, crop=16, batch_size=2, epochs=100, lr=3e-3,
                                             lr_milestones=(99,), samples_per_epoch=2, max_steps=3,
                                             val_every=100, precision="bf16"))
    summary = run_training(exp, scenes, [], tmp_path, device="cpu", progress=False)
    assert summary["precision"] == "bf16" and summary["steps"] == 3
