"""Input normalisation by the window's firing rate (model.input_norm "window_rate", model/arch.py):
the features see one brightness at every light level, and the frame is scaled back by the rate."""
from __future__ import annotations

import dataclasses

import pytest
import torch

from model.arch import build_model, window_rate_scale
from model.config import ExperimentConfig, ModelConfig, load_config
from model.streaming import reconstruct_windows

SMALL = ModelConfig(num_features=8, num_blocks=1, deform_groups=2, interval_transform="inverse")
NORM = dataclasses.replace(SMALL, input_norm="window_rate")


def _spikes(k=3, h=20, w=24, rate=0.2, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, k, 41, h, w, generator=g) < rate


def _inverse_gisi(net, spk):
    maps, _, _ = net.input_maps(spk)
    return maps


def test_the_scale_is_each_windows_mean_rate_with_its_floor():
    spk = _spikes(k=2).reshape(2, 41, 20, 24).float()
    torch.testing.assert_close(window_rate_scale(spk, 1e-3), spk.mean(dim=(1, 2, 3)))
    dark = torch.zeros(2, 41, 4, 4)
    dark[0, 0, 0, 0] = 1  # one spike in 656 pixel-steps: 1.5e-3, above the floor
    torch.testing.assert_close(window_rate_scale(dark, 1e-3), torch.tensor([1 / 656, 1e-3]))


@pytest.mark.parametrize("output", ["direct", "refine"])
def test_the_features_do_not_depend_on_the_inputs_scale(output):
    """Rate-like inputs (spikes as floats, 1/GISI) scaled by c give the same features: the scale is
    divided out, so brightness is not something the weights must learn. Without the
    normalisation the same network's features change."""
    torch.manual_seed(0)
    spk = _spikes().float()
    for cfg, same in ((dataclasses.replace(NORM, output=output), True), (dataclasses.replace(SMALL, output=output), False)):
        net = build_model(cfg).eval()
        maps = _inverse_gisi(net, spk)
        x, m = net.pad(spk[0]), net.pad(maps[0])
        with torch.no_grad():
            a, b = net.encode(x, m), net.encode(0.25 * x, 0.25 * m)
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-5) == same, cfg


def test_a_direct_normalised_network_scales_its_frame_with_the_rate():
    """forward(c * x) = c * forward(x) exactly for the direct output: features the same, frame times
    the rate. (A network without it has biases: its frame does not scale.)"""
    torch.manual_seed(0)
    spk = _spikes().float()
    for cfg, homogeneous in ((NORM, True), (SMALL, False)):
        net = build_model(cfg).eval()
        with torch.no_grad():
            net.head[-1].bias.fill_(0.3)  # a bias that a network without normalisation cannot scale away
            maps = _inverse_gisi(net, spk)
            a, b = net(spk, maps), net(0.5 * spk, 0.5 * maps)
        assert torch.allclose(b, 0.5 * a, rtol=1e-4, atol=1e-6) == homogeneous, cfg


def test_the_refining_heads_classic_estimates_are_not_scaled():
    """Open gates give the window's own TFP whatever the normalisation (only the frame channel is
    scaled back), so a plain window average still costs one gate."""
    from model.representations import tfp_windows
    net = build_model(dataclasses.replace(NORM, output="refine")).eval()
    spk = _spikes(rate=0.05)
    with torch.no_grad():
        net.head[-1].weight.zero_()
        net.head[-1].bias[:] = torch.tensor([0.0, 60.0, 60.0])
        torch.testing.assert_close(net(spk), tfp_windows(spk.float()), rtol=0, atol=1e-6)
        net.head[-1].bias[:] = torch.tensor([0.5, -60.0, 0.0])  # the frame channel alone: 0.5 x rate
        rate = spk.float().mean(dim=(2, 3, 4))[0]
        torch.testing.assert_close(net(spk)[0].mean(dim=(1, 2)), 0.5 * rate, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("output,span", [("direct", 1), ("refine", 3)])
def test_a_normalised_network_streams_exactly(output, span):
    torch.manual_seed(2)
    net = build_model(dataclasses.replace(NORM, output=output, refine_span=span)).eval()
    spk = _spikes(k=5, seed=3, rate=0.1)
    with torch.no_grad():
        one_shot = net(spk)[0]
        for chunk in (1, 2):
            torch.testing.assert_close(reconstruct_windows(net, spk[0], chunk=chunk), one_shot, rtol=1e-5, atol=1e-6)


def test_the_fields_are_validated():
    with pytest.raises(ValueError, match="input_norm must be one of"):
        dataclasses.replace(NORM, input_norm="rate")
    with pytest.raises(ValueError, match="input_norm_floor_rate"):
        dataclasses.replace(NORM, input_norm_floor_rate=0.0)
    with pytest.raises(ValueError, match="interval_transform 'inverse'"):
        dataclasses.replace(NORM, interval_transform="raw")  # a raw interval is not a rate
    with pytest.raises(ValueError, match="representation"):
        dataclasses.replace(NORM, representation="tfi")


def test_the_shipped_config_loads_and_an_old_record_reads_as_unnormalised():
    exp = load_config("lrrep_span_norm")
    assert exp.model.input_norm == "window_rate" and exp.model.refine_span == 5
    old = load_config("lrrep_span").to_dict()
    for key in ("input_norm", "input_norm_floor_rate"):
        old["model"].pop(key)
    assert ExperimentConfig.from_dict(old).model.input_norm == "none"


def test_fine_tuning_an_unnormalised_network_into_a_normalised_config_is_refused():
    from model.training import initial_weights
    with pytest.raises(ValueError, match="input_norm"):
        initial_weights("lrrep", load_config("lrrep_span_norm"))
