"""The refining output (model.output "refine", model/arch.py): the frame is a per-pixel blend of the
network's own estimate and the window's TFP and TFI, so a plain window average costs nothing."""
from __future__ import annotations

import dataclasses

import pytest
import torch

from model.arch import REFINE_GATE_LOGIT, build_model, classic_estimates, widen_head_state
from model.config import ModelConfig, load_config
from model.representations import tfi_windows, tfp_windows
from model.streaming import reconstruct_windows

SMALL = ModelConfig(num_features=8, num_blocks=1, deform_groups=2, interval_transform="inverse")


def _spikes(k=4, h=20, w=24, rate=0.3, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, k, 41, h, w, generator=g) < rate


def test_open_gates_give_exactly_tfp_and_tfi():
    net = build_model(dataclasses.replace(SMALL, output="refine")).eval()
    spk = _spikes()
    last = net.head[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias[:] = torch.tensor([0.0, 60.0, 60.0])  # gate to the classic estimate, all TFP
        torch.testing.assert_close(net(spk), tfp_windows(spk.float()), rtol=0, atol=1e-6)
        last.bias[2] = -60.0  # all TFI
        torch.testing.assert_close(net(spk), tfi_windows(spk), rtol=0, atol=1e-6)
        last.bias[1] = -60.0  # gate closed: the network's frame channel alone (its bias here)
        last.bias[0] = 0.123
        torch.testing.assert_close(net(spk), torch.full_like(net(spk), 0.123), rtol=0, atol=1e-6)


def test_classic_estimates_match_the_representations():
    spk = _spikes(k=1)[0]
    tfp_map, tfi_map = classic_estimates(spk.float())
    torch.testing.assert_close(tfp_map, tfp_windows(spk.float()))
    torch.testing.assert_close(tfi_map, tfi_windows(spk))


def test_a_widened_direct_network_starts_as_that_network():
    direct = build_model(SMALL).eval()
    refine_cfg = dataclasses.replace(SMALL, output="refine")
    widened = build_model(refine_cfg).eval()
    widened.load_state_dict(widen_head_state(direct.state_dict(), refine_cfg))
    spk = _spikes(rate=0.05)
    with torch.no_grad():
        a, b = widened(spk), direct(spk)
        tfp_map, tfi_map = classic_estimates(spk.reshape(-1, 41, 20, 24).float())
        classic = (0.5 * tfp_map + 0.5 * tfi_map).reshape(a.shape)
    gate = torch.sigmoid(torch.tensor(REFINE_GATE_LOGIT))
    torch.testing.assert_close(a, (1 - gate) * b + gate * classic, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="refine"):
        widen_head_state(direct.state_dict(), SMALL)


def test_refine_streams_exactly():
    torch.manual_seed(1)
    net = build_model(dataclasses.replace(SMALL, output="refine")).eval()
    with torch.no_grad():
        net.head[-1].weight[1:].normal_(0, 0.1)  # gates that vary per pixel
        spk = _spikes(k=5, seed=3)
        one_shot = net(spk)[0]
        for chunk in (1, 2, 3):
            torch.testing.assert_close(reconstruct_windows(net, spk[0], chunk=chunk), one_shot, rtol=1e-5, atol=1e-6)


def test_fine_tuning_from_the_shipped_network_widens_its_head_and_refuses_other_changes():
    from model.training import initial_weights
    exp = load_config("lrrep_refine")
    state, record = initial_weights("lrrep_v2", exp)  # a direct network: its head is widened
    net = build_model(exp.model)
    net.load_state_dict(state)  # strict: every key and shape fits
    assert record["spec"] == "lrrep_v2"
    other = dataclasses.replace(exp, model=dataclasses.replace(exp.model, num_blocks=3))
    with pytest.raises(ValueError, match="num_blocks"):
        initial_weights("lrrep_v2", other)


def test_the_output_field_is_validated():
    with pytest.raises(ValueError, match="model.output"):
        ModelConfig(output="residual")


def test_several_dataset_roots_are_read_as_one_with_their_names_kept_apart(dataset, tmp_path):
    import shutil

    from model.data import open_scenes
    other = tmp_path / "second"
    shutil.copytree(dataset, other)
    one = open_scenes(dataset)
    both = open_scenes([dataset, other])
    assert len(both) == 2 * len(one)
    assert [s.name for s in both] == [f"{dataset.name}:{s.name}" for s in one] + [f"second:{s.name}" for s in one]
    joined = open_scenes(f"{dataset}+{other}")
    assert [s.name for s in joined] == [s.name for s in both]
    assert both[0].num_steps == one[0].num_steps and (both[0].spikes(0, 3) == one[0].spikes(0, 3)).all()
    with pytest.raises(ValueError, match="once"):
        open_scenes([dataset, dataset])


SPAN = dataclasses.replace(SMALL, output="refine", refine_span=5)


def test_span_rates_are_tfp_over_the_clipped_span():
    from model.arch import span_rates
    spk = _spikes(k=6, h=5, w=7, seed=4).float()
    got = span_rates(spk, 5)
    for i in range(6):
        lo, hi = max(0, i - 2), min(6, i + 3)
        want = spk[:, lo:hi].reshape(1, -1, 5, 7).mean(dim=1)  # every step of the windows it covers
        torch.testing.assert_close(got[:, i], want, rtol=0, atol=1e-6)


def test_an_open_span_gate_gives_the_span_rate():
    from model.arch import span_rates
    net = build_model(SPAN).eval()
    spk = _spikes(k=5, seed=5)
    with torch.no_grad():
        net.head[-1].weight.zero_()
        net.head[-1].bias[:] = torch.tensor([0.0, 60.0, 60.0, 60.0])  # classic, TFP, span
        torch.testing.assert_close(net(spk), span_rates(spk, 5), rtol=0, atol=1e-6)


@pytest.mark.parametrize("k", [3, 7])
def test_span_refine_streams_exactly(k):
    torch.manual_seed(2)
    net = build_model(SPAN).eval()
    with torch.no_grad():
        net.head[-1].weight[1:].normal_(0, 0.1)
        spk = _spikes(k=k, seed=6)
        one_shot = net(spk)[0]
        for chunk in (1, 2, 3, 8):
            torch.testing.assert_close(reconstruct_windows(net, spk[0], chunk=chunk), one_shot, rtol=1e-5, atol=1e-6)


def test_a_refine_network_widens_to_a_span_and_starts_as_it_was():
    from model.arch import REFINE_GATE_GAIN
    refine_cfg = dataclasses.replace(SMALL, output="refine")
    torch.manual_seed(3)
    narrow = build_model(refine_cfg).eval()
    wide = build_model(SPAN).eval()
    wide.load_state_dict(widen_head_state(narrow.state_dict(), SPAN))
    with torch.no_grad():
        narrow.head[-1].bias[1] = 60.0 / REFINE_GATE_GAIN  # classic gate open: only TFP/TFI differ
        narrow.head[-1].bias[2] = 60.0 / REFINE_GATE_GAIN  # all TFP
        wide.head[-1].bias[1:3] = narrow.head[-1].bias[1:3]
        wide.head[-1].bias[3] = -60.0 / REFINE_GATE_GAIN  # span gate shut: the narrow network exactly
        spk = _spikes(k=4, seed=7)
        torch.testing.assert_close(wide(spk), narrow(spk), rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="channels"):
        widen_head_state(wide.state_dict(), SPAN)


def test_refine_span_is_validated():
    with pytest.raises(ValueError, match="refine_span"):
        dataclasses.replace(SMALL, output="refine", refine_span=4)
    with pytest.raises(ValueError, match="needs model.output"):
        dataclasses.replace(SMALL, refine_span=5)
