"""The flip self-ensemble (`flips:NETWORK`, model.methods.FlipEnsembleMethod)."""
from __future__ import annotations

import pytest
import torch

from model.arch import build_model
from model.checkpoint import save_checkpoint
from model.config import ExperimentConfig, ModelConfig, TrainConfig
from model.methods import FLIPS, FlipEnsembleMethod, ModelMethod, method_from_spec
from model.streaming import TensorWindows


@pytest.fixture
def network(tmp_path):
    torch.manual_seed(0)
    exp = ExperimentConfig("tiny_flips", model=ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2),
                           train=TrainConfig(num_windows=3, crop=8))
    path = tmp_path / "net.pt"
    save_checkpoint(path, build_model(exp.model), exp)
    return path


def _frames(method, spikes):
    return torch.stack([f for _, f in method.frames(TensorWindows(spikes))])


def test_the_ensemble_is_the_mean_of_the_network_under_each_flip(network):
    spikes = torch.rand(4, 7, 12, 16, generator=torch.Generator().manual_seed(1)) < 0.3
    plain = method_from_spec(str(network))
    ens = method_from_spec(f"flips:{network}")
    assert isinstance(ens, FlipEnsembleMethod) and ens.name == f"{plain.name}+flips" and ens.window == 7
    want = torch.stack([_frames(plain, spikes.flip(d) if d else spikes).flip(d) if d else _frames(plain, spikes)
                        for d in FLIPS]).mean(0)
    got = _frames(ens, spikes)
    assert torch.allclose(got, want, atol=1e-6)
    # a random network is not flip-equivariant: the ensemble is not the plain frame
    assert not torch.allclose(got, _frames(plain, spikes), atol=1e-4)


def test_the_ensemble_commutes_with_every_flip(network):
    """The flips form a group, so mirroring the stream mirrors the ensemble's frames."""
    spikes = torch.rand(3, 7, 12, 16, generator=torch.Generator().manual_seed(2)) < 0.4
    ens = method_from_spec(f"mine=flips:{network}")
    assert ens.name == "mine"
    base = _frames(ens, spikes)
    for d in FLIPS[1:]:
        assert torch.allclose(_frames(ens, spikes.flip(d)), base.flip(d), atol=1e-5)


@pytest.mark.parametrize("inner", ["tfp", "tfp:123", "stp", "black"])
def test_a_window_average_has_no_ensemble(inner):
    with pytest.raises(ValueError, match="flip self-ensemble is of a network"):
        method_from_spec(f"flips:{inner}")


def test_a_missing_network_is_named(tmp_path):
    with pytest.raises(ValueError, match="existing checkpoint file"):
        method_from_spec(f"flips:{tmp_path / 'none.pt'}")


def test_the_shipped_network_has_one(tmp_path):
    ens = method_from_spec("flips:lrrep")
    assert isinstance(ens.inner, ModelMethod) and ens.name == "LR-Rep+flips" and ens.span == ens.inner.span


def test_gates_refuses_an_ensemble_naming_its_network():
    from model.gates import refining_network
    with pytest.raises(ValueError, match="read the gates of the network itself \\(LR-Rep\\)"):
        refining_network(method_from_spec("flips:lrrep"))
