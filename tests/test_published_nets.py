"""The re-implemented Table-1 networks (model/published_nets): shapes, exact chunked streaming,
checkpoint round trip, and a few training steps that lower the loss (SSML from spikes alone)."""
from __future__ import annotations

import csv
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import model  # noqa: F401  registration happens on `import model`
from model.arch import build_model, parameter_count
from model.checkpoint import for_inference, model_from_checkpoint, save_checkpoint
from model.config import ExperimentConfig, ModelConfig, TrainConfig, load_config
from model.losses import SelfSupervisedObjective
from model.methods import ModelMethod
from model.registry import ARCH_REGISTRY
from model.streaming import TensorWindows, reconstruct_windows

sys.path.insert(0, str(Path(__file__).parent / "model"))  # modeltest_fakes

ARCHS = ("spk2imgnet", "wgse", "rsir", "ssml")
WINDOW = 41  # Spk2ImgNet's five 13-step sub-windows, 7 steps apart


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)
    torch.manual_seed(0)


def tiny(arch: str) -> ModelConfig:
    return ModelConfig(arch=arch, window=WINDOW, num_features=8, num_blocks=1, deform_groups=2)


def net(arch: str) -> torch.nn.Module:
    torch.manual_seed(0)
    m = build_model(tiny(arch)).eval()
    for name, p in m.named_parameters():  # offsets that move features (they start at zero)
        if "conv_offset_mask" in name:
            p.data.normal_(0, 0.05, generator=torch.Generator().manual_seed(1))
    return m


def windows(m: int = 5, h: int = 10, w: int = 13, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(m, WINDOW, h, w, generator=g) < 0.1


def test_registered_on_import_model():
    assert set(ARCHS) <= set(ARCH_REGISTRY.names())


@pytest.mark.parametrize("arch", ARCHS)
def test_shapes_and_parameter_count(arch):
    m = net(arch)
    s = windows(3).unsqueeze(0).repeat(2, 1, 1, 1, 1)  # (B=2, K=3, T, 10, 13): padded inside, cut back
    with torch.no_grad():
        y = m(s)
    assert y.shape == (2, 3, 10, 13) and torch.isfinite(y).all()
    assert parameter_count(m.cfg) == sum(p.numel() for p in m.parameters())
    with pytest.raises(ValueError, match="window"):
        m(torch.zeros(1, 1, WINDOW - 2, 8, 8))
    with pytest.raises(ValueError, match="own front end"):
        build_model(dataclasses.replace(m.cfg, representation="tfp"))


@pytest.mark.parametrize("arch", ARCHS)
def test_chunked_streaming_equals_one_shot(arch):
    m, s = net(arch), windows(5)
    with torch.no_grad():
        ref = m(s.unsqueeze(0))[0]
    for chunk in (1, 2, 5):
        torch.testing.assert_close(reconstruct_windows(m, s, chunk=chunk), ref, atol=1e-5, rtol=1e-5)


def test_rsir_is_recurrent_forward_only():
    """RSIR's frame i depends on windows before it (the carried state) and never on later ones."""
    m, s = net("rsir"), windows(4)
    with torch.no_grad():
        ref = m(s.unsqueeze(0))[0]
        alone = m(s[2:].unsqueeze(0))[0]
        prefix = m(s[:3].unsqueeze(0))[0]
    assert (alone[0] - ref[2]).abs().max() > 1e-6
    torch.testing.assert_close(prefix, ref[:3])


def test_blind_spot_never_sees_its_pixel():
    from model.published_nets.ssml import BlindSpotNet
    bsn = BlindSpotNet(3, 4, 2)
    x = torch.randn(1, 3, 12, 12, requires_grad=True)
    bsn(x)[0, 5, 6].backward()
    g = x.grad[0].abs().sum(0)
    assert g[5, 6] == 0 and g[4, 6] > 0 and g[6, 6] > 0 and g[5, 5] > 0 and g[5, 7] > 0


@pytest.mark.parametrize("arch", ["spk2imgnet", "rsir"])
def test_checkpoint_round_trip_and_method(arch, tmp_path):
    m = net(arch)
    exp = ExperimentConfig("t", model=m.cfg, train=TrainConfig(num_windows=2, crop=16))
    save_checkpoint(tmp_path / "last.pt", m, exp)
    back, exp2 = model_from_checkpoint(tmp_path / "last.pt")
    assert exp2 == exp and type(back) is type(m)
    for_inference(back, exp2)
    s = windows(3)
    with torch.no_grad():
        ref = m(s.unsqueeze(0))[0]
    method = ModelMethod("t", tmp_path / "last.pt", chunk=2)
    out = torch.stack([f for _, f in method.frames(TensorWindows(s))])
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-5)


def test_self_supervised_objective_needs_a_network_that_has_one():
    with pytest.raises(ValueError, match="self_supervised"):
        SelfSupervisedObjective(build_model(tiny("wgse")))
    with pytest.raises(TypeError):
        from model.losses import build_loss
        build_loss("self_supervised")(torch.zeros(1, 1, 2, 2), torch.zeros(1, 1, 2, 2))


@pytest.mark.parametrize("arch", ARCHS)
def test_a_few_training_steps_lower_the_loss(arch, tmp_path):
    from modeltest_fakes import make_scene
    from pipelines.train import run_training
    scene = make_scene("s0", 16, 16, WINDOW * 4, brightness=0.3, velocity=0.2, seed=0)
    loss = "self_supervised" if arch == "ssml" else "l1_sum"
    tc = TrainConfig(num_windows=2, crop=16, batch_size=2, epochs=1000, lr=3e-3, lr_milestones=(999,),
                     samples_per_epoch=2, val_every=1000, seed=0, max_steps=25, loss=loss, precision="fp32")
    run_training(ExperimentConfig("t", model=tiny(arch), train=tc), [scene], [], tmp_path, device="cpu",
                 progress=False)
    losses = [float(r["loss"]) for r in csv.DictReader((tmp_path / "train_log.csv").open())]
    assert len(losses) == 25 and np.mean(losses[-5:]) < 0.7 * np.mean(losses[:5]), losses


@pytest.mark.parametrize("name", ["cpu_s2i", "cpu_wgse", "cpu_rsir", "cpu_ssml", "s2i", "wgse", "rsir", "ssml"])
def test_configs_load(name):
    exp = load_config(name)
    assert exp.model.arch in ARCHS and parameter_count(exp.model) > 0
    assert (exp.train.loss == "self_supervised") == (exp.model.arch == "ssml")
