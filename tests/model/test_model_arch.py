"""Every named config builds, runs and back-propagates at tiny sizes; configs validate their fields."""
from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from model.arch import ReconNet, build_model, count_parameters
from model.config import ExperimentConfig, ModelConfig, TrainConfig, available_configs, load_config

NAMED = ["full", "ablation_a", "ablation_b", "ablation_c", "ablation_d", "ablation_f", "rep_tfp", "rep_tfi", "tiny"]


def shrink(cfg: ModelConfig) -> ModelConfig:
    """Same switches, tiny width and depth, short windows."""
    return dataclasses.replace(cfg, num_features=8, num_blocks=1, deform_groups=2, window=7)


def test_all_paper_configs_are_shipped():
    assert set(NAMED) <= set(available_configs())


@pytest.mark.parametrize("name", NAMED)
def test_named_config_shapes_and_gradients(name):
    exp = load_config(name)
    model = build_model(shrink(exp.model))
    spikes = torch.rand(2, 3, 7, 10, 12) < 0.2  # H = 10 is not a multiple of 4: padded then cropped
    out = model(spikes)
    assert out.shape == (2, 3, 10, 12)
    assert torch.isfinite(out).all()
    out.square().mean().backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None]
    assert not missing, f"parameters without gradient: {missing}"
    first = next(model.representation.parameters())
    assert first.grad.abs().sum() > 0 and model.head[-1].weight.grad.abs().sum() > 0


def test_switches_change_the_network():
    base = shrink(load_config("full").model)
    full = build_model(base)
    a = build_model(shrink(load_config("ablation_a").model))
    assert full.align is not None and a.align is None
    assert hasattr(full.representation, "interval_branch") and not hasattr(a.representation, "interval_branch")
    assert load_config("ablation_f").model.interval == "lisi"
    assert load_config("rep_tfp").model.representation == "tfp"


def test_full_config_is_the_paper_model():
    m = load_config("full").model
    assert (m.window, m.num_features, m.num_blocks, m.deform_groups) == (41, 64, 16, 8)
    assert (m.representation, m.interval, m.adf, m.aif) == ("lr_rep", "gisi", True, True)
    t = load_config("full").train
    assert (t.num_windows, t.crop, t.batch_size, t.epochs, t.lr, t.betas, t.lr_milestones, t.lr_gamma) == \
        (21, 64, 8, 100, 1e-4, (0.9, 0.99), (70,), 0.1)


def test_adf_off_means_windows_are_independent():
    """Without ADF a window's output does not depend on its neighbours (GISI off: LISI)."""
    cfg = dataclasses.replace(shrink(load_config("ablation_a").model))
    model = build_model(cfg).eval()
    s = torch.rand(1, 3, 7, 8, 8) < 0.3
    s2 = s.clone()
    s2[:, 0] = ~s2[:, 0]
    with torch.no_grad():
        assert torch.allclose(model(s)[:, 1:], model(s2)[:, 1:])
    full = build_model(shrink(load_config("ablation_b").model)).eval()
    with torch.no_grad():
        assert not torch.allclose(full(s)[:, 1:], full(s2)[:, 1:])


def test_padding_to_multiple_of_four_and_crop():
    model = build_model(shrink(ModelConfig()))
    assert model.padded_size(250, 400) == (252, 400)
    x = torch.arange(10.0).reshape(1, 1, 10, 1).expand(1, 1, 10, 3)
    p = model.pad(x)
    assert p.shape == (1, 1, 12, 4) and torch.equal(p[..., 10:, :3], x[..., 9:10, :].expand(1, 1, 2, 3))


def test_parameter_count_scales_with_width():
    small = count_parameters(build_model(shrink(ModelConfig())))
    big = count_parameters(build_model(dataclasses.replace(shrink(ModelConfig()), num_features=16)))
    assert big > 3 * small


@pytest.mark.parametrize("field,value,msg", [
    ("window", 40, "odd"),
    ("num_features", 0, "num_features"),
    ("representation", "rsir_ast", "representation"),
    ("interval", "isi", "interval"),
    ("interval_transform", "log", "interval_transform"),
    ("deform_groups", 5, "deform_groups"),
    ("pad_multiple", 6, "pad_multiple"),
])
def test_model_config_rejects_bad_values(field, value, msg):
    with pytest.raises(ValueError, match=msg):
        ModelConfig(**{field: value})


def test_aif_needs_adf():
    with pytest.raises(ValueError, match="aif=true needs model.adf=true"):
        ModelConfig(adf=False, aif=True)


def test_train_config_rejects_bad_values():
    with pytest.raises(ValueError, match="crop"):
        TrainConfig(crop=62)
    with pytest.raises(ValueError, match="batch_size"):
        TrainConfig(batch_size=0)
    with pytest.raises(ValueError, match="lr_milestones"):
        TrainConfig(lr_milestones=(70, 10))


def test_unknown_fields_and_files_are_named(tmp_path):
    p = tmp_path / "x.json"
    p.write_text(json.dumps({"name": "x", "model": {"feature_count": 3}}))
    with pytest.raises(ValueError, match="feature_count"):
        load_config(p)
    with pytest.raises(FileNotFoundError, match="no config"):
        load_config("no_such_config")


def test_config_round_trip():
    exp = load_config("tiny")
    again = ExperimentConfig.from_dict(json.loads(json.dumps(exp.to_dict())))
    assert again == exp


def test_wrong_window_length_is_named():
    model = build_model(shrink(ModelConfig()))
    assert isinstance(model, ReconNet)
    with pytest.raises(ValueError, match="window=7"):
        model(torch.zeros(1, 2, 9, 8, 8, dtype=torch.bool))
