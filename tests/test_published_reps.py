"""The published methods' representations (model/published_reps.py): hand-computed cases for the
non-learned parts, shapes, refusals, window locality (streaming equals one-shot), cost, and a few
training steps that lower the loss."""
from __future__ import annotations

import math
import warnings

import pytest
import torch

from model.arch import ReconNet, build_model, parameter_count
from model.config import REPRESENTATIONS, ModelConfig, load_config
from model.lrrep import LRRep, build_representation
from model.published_reps import (PUBLISHED_REPRESENTATIONS, PUBLISHED_REPS, AMIMRep, amim_tfi, ast_counts,
                                  ast_maps, published_input_map, representation_cost, sali_geometry, sali_subwindows,
                                  wavelet_band_lengths, wavelet_coefficients_1d, wavelet_reconstruct_1d)
from model.streaming import reconstruct_windows

T = 41


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    yield
    torch.set_num_threads(threads)


def train_at(*steps: int, t: int = T) -> torch.Tensor:
    """One pixel's spike train (t, 1, 1) with spikes at the given steps."""
    s = torch.zeros(t, 1, 1)
    s[list(steps), 0, 0] = 1
    return s


# ---- AST ----------------------------------------------------------------------------------------

def test_ast_counts_by_hand():
    s = train_at(18, 20, 25, 30)  # centre 20
    expected = {1: (1, 1),    # the centre step itself
                2: (2, 5),    # [18, 22]
                3: (3, 11),   # [15, 25]
                4: (4, 21),   # [10, 30]
                5: (4, 41)}   # never reached: the whole window
    for target, (count, span) in expected.items():
        n, L = ast_counts(s, target)
        assert (n.item(), L.item()) == (count, span), target
    silent = ast_counts(torch.zeros(2, 3, T, 4, 5, dtype=torch.bool), 1)
    assert silent[0].shape == (2, 3, 4, 5) and (silent[0] == 0).all() and (silent[1] == T).all()


def test_ast_short_span_where_bright_long_where_dark():
    bright = torch.zeros(T, 1, 1)
    bright[::2] = 1                        # 0.5 spikes per step
    dark = train_at(4, 36)                 # two spikes, far from the centre
    s = torch.cat([bright, dark], 2)
    maps = ast_maps(s)                     # rates of targets 1, 2, 4, 8, then spans / T
    assert maps.shape == (8, 1, 2)
    spans = (maps[4:, 0] * T).round()
    assert spans[:, 0].tolist() == [1, 5, 9, 17]        # bright (spikes on even steps): short spans
    assert spans[:, 1].tolist() == [33, 33, 41, 41]     # dark: [4, 36], then the whole window
    assert maps[3, 0, 0].item() == pytest.approx(9 / 17)  # rate = count / span: 9 spikes in [12, 28]
    assert maps[0, 0, 1].item() == pytest.approx(2 / 33)


def test_ast_refuses_bad_input():
    with pytest.raises(ValueError, match="odd number of steps"):
        ast_counts(torch.zeros(40, 2, 2), 1)
    with pytest.raises(ValueError, match="positive integer"):
        ast_counts(torch.zeros(41, 2, 2), 0)
    with pytest.raises(ValueError, match="0 or 1"):
        ast_counts(torch.full((41, 2, 2), 2.0), 1)
    with pytest.raises(ValueError, match="dimensions"):
        ast_counts(torch.zeros(41, 2), 1)


# ---- AMIM ---------------------------------------------------------------------------------------

def test_amim_tfi_by_hand():
    cases = {(20, 25): 1 / 5,            # last at/before the centre 20, first after it
             (9, 32): 1 / 23,            # both at the edges of the 12-step search range
             (5, 36): 1 / 26,            # outside it on both sides: 33 - 7
             (): 1 / 26,                 # silent
             (15,): 1 / (33 - 15)}       # no spike after the centre within 12 steps
    for steps, value in cases.items():
        assert amim_tfi(train_at(*steps)).item() == pytest.approx(value), steps
    with pytest.raises(ValueError, match="radius"):
        amim_tfi(train_at(20), radius=0)


# ---- SALI ---------------------------------------------------------------------------------------

def test_sali_subwindows_are_spk2imgnets_blocks():
    assert sali_geometry(41) == (0, 7, 13)
    steps = torch.arange(T, dtype=torch.float32).view(1, T, 1, 1).expand(2, T, 3, 4)
    sub = sali_subwindows(steps)
    assert sub.shape == (2, 5, 13, 3, 4)
    for i in range(5):
        assert sub[0, i, :, 0, 0].tolist() == list(range(7 * i, 7 * i + 13))
    assert sali_geometry(13) == (0, 0, 13) and sali_geometry(7) == (0, 0, 7)


# ---- WGSE-1d ------------------------------------------------------------------------------------

def test_haar_dwt_by_hand():
    x = torch.tensor([1.0, 0.0, 1.0, 1.0], dtype=torch.float64).view(4, 1, 1)
    ca, cd = wavelet_coefficients_1d(x, "haar", 1)
    r = 1 / math.sqrt(2)
    torch.testing.assert_close(ca.flatten(), torch.tensor([r, 2 * r], dtype=torch.float64))  # (a + b) / sqrt 2
    torch.testing.assert_close(cd.flatten(), torch.tensor([r, 0.0], dtype=torch.float64))    # (a - b) / sqrt 2
    ones = torch.ones(4, 1, 1, dtype=torch.float64)
    ca2, cd2, cd1 = wavelet_coefficients_1d(ones, "haar", 2)
    torch.testing.assert_close(ca2.flatten(), torch.tensor([2.0], dtype=torch.float64))
    assert cd2.abs().max() == 0 and cd1.abs().max() == 0
    torch.testing.assert_close(wavelet_reconstruct_1d([ca, cd], "haar"), x)


@pytest.mark.parametrize("wavelet,levels", [("haar", 3), ("db8", 5), ("db2", 2)])
def test_dwt_matches_pywavelets_and_reconstructs(wavelet, levels):
    pywt = pytest.importorskip("pywt")
    g = torch.Generator().manual_seed(1)
    x = (torch.rand(2, T, 3, 4, generator=g) < 0.3).to(torch.float64)
    bands = wavelet_coefficients_1d(x, wavelet, levels)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # db8 at 5 levels is above pywt's maximum for 41 steps
        ref = pywt.wavedec(x.numpy(), wavelet, mode="zero", level=levels, axis=1)
    assert [b.shape[1] for b in bands] == [r.shape[1] for r in ref] == wavelet_band_lengths(T, wavelet, levels)
    for b, r in zip(bands, ref):
        torch.testing.assert_close(b, torch.from_numpy(r), atol=1e-12, rtol=0)
    rec = wavelet_reconstruct_1d(bands, wavelet)
    torch.testing.assert_close(rec[:, :T], x, atol=1e-12, rtol=0)  # perfect reconstruction
    assert rec.shape[1] == T + 1 and rec[:, T].abs().max() < 1e-12
    f32 = wavelet_coefficients_1d(x.to(torch.bool), wavelet, levels)  # bool spikes -> float32
    assert f32[0].dtype == torch.float32
    torch.testing.assert_close(f32[-1].double(), bands[-1], atol=1e-5, rtol=0)


def test_dwt_refuses_bad_input():
    with pytest.raises(ValueError, match="unknown discrete wavelet"):
        wavelet_coefficients_1d(torch.zeros(T, 2, 2), "morl", 2)
    with pytest.raises(ValueError, match="levels"):
        wavelet_coefficients_1d(torch.zeros(T, 2, 2), "haar", 0)
    with pytest.raises(ValueError, match="band"):
        wavelet_reconstruct_1d([torch.zeros(4, 1, 1)], "haar")


# ---- modules, wiring, cost ----------------------------------------------------------------------

@pytest.mark.parametrize("name", PUBLISHED_REPRESENTATIONS)
def test_modules_shapes_and_refusals(name):
    assert name in REPRESENTATIONS
    rep = PUBLISHED_REPS[name](T, 16)
    spikes = (torch.rand(2, T, 12, 10) < 0.2).float()
    with torch.no_grad():
        out = rep(spikes, None)
    assert out.shape == (2, 16, 12, 10) and torch.isfinite(out).all()
    with pytest.raises(ValueError, match=r"\(N, T=41, H, W\)"):
        rep(spikes[:, :40], None)
    with pytest.raises(ValueError, match=r"\(N, T=41, H, W\)"):
        rep(spikes[0], None)
    built = build_representation(ModelConfig(window=T, num_features=16, representation=name))
    assert type(built) is PUBLISHED_REPS[name]


def test_published_input_map():
    s = torch.rand(2, 3, T, 5, 6) < 0.1
    m = published_input_map("amim", s)
    assert m.shape == (2, 3, 5, 6)
    torch.testing.assert_close(m[1, 2], amim_tfi(s[1, 2]))
    assert all(published_input_map(n, s) is None for n in ("ast", "sali", "wgse1d"))
    with pytest.raises(ValueError, match="unknown published representation"):
        published_input_map("lr_rep", s)
    # AMIM with its map given equals AMIM computing it itself
    rep = AMIMRep(T, 8).eval()
    x = s[0].float()
    with torch.no_grad():
        torch.testing.assert_close(rep(x, m[0].unsqueeze(1)), rep(x, None))
    with pytest.raises(ValueError, match="maps must be"):
        rep(x, m[0])


def test_cost_matches_the_module_docstring():
    """Parameters and FLOP of each front end at channels=16 on (1, 41, 64, 64) (the docstring's table),
    all within a factor 2 of LR-Rep's."""
    lr_params, lr_flop = representation_cost(LRRep(T, 16), with_map=True)
    table = {"ast": (5808, 0.0472), "amim": (9135, 0.0740), "sali": (5088, 0.1121), "wgse1d": (6406, 0.1664)}
    assert lr_params == 13136 and lr_flop / 1e9 == pytest.approx(0.1073, abs=5e-4)
    for name, (params, gflop) in table.items():
        p, f = representation_cost(PUBLISHED_REPS[name](T, 16))
        assert p == params and f / 1e9 == pytest.approx(gflop, abs=5e-4), name
        assert 0.25 < f / lr_flop < 2, name


@pytest.mark.parametrize("name", PUBLISHED_REPRESENTATIONS)
def test_configs(name):
    base, cpu, full = load_config("lrrep_cpu"), load_config(f"cpu_rep_{name}"), load_config(f"rep_{name}")
    assert cpu.model.representation == full.model.representation == name
    assert cpu.model.to_dict() | {"representation": "lr_rep"} == base.model.to_dict() and cpu.train == base.train
    assert not cpu.model.carries_spike_times
    assert parameter_count(full.model) > parameter_count(cpu.model) > 0  # builds on the meta device
    from model.flops import network_cost  # runs the network on the meta device (compare's cost column)
    assert network_cost(cpu, 16, 16).flop_per_frame > 0


# ---- inside ReconNet ----------------------------------------------------------------------------

def tiny_net(name: str) -> ReconNet:
    torch.manual_seed(0)
    return build_model(ModelConfig(window=T, num_features=8, num_blocks=1, deform_groups=2, representation=name))


@pytest.mark.parametrize("name", PUBLISHED_REPRESENTATIONS)
def test_streaming_equals_one_shot(name):
    model = tiny_net(name).eval()
    g = torch.Generator().manual_seed(2)
    s = torch.rand(5, T, 10, 9, generator=g) < 0.08
    with torch.no_grad():
        ref = model(s.unsqueeze(0))[0]
    for chunk in (1, 2):
        torch.testing.assert_close(reconstruct_windows(model, s, chunk=chunk), ref, atol=1e-5, rtol=1e-5)
    # window-local: changing window 0's spikes leaves window 2's representation untouched
    s2 = s.clone()
    s2[0] = ~s2[0]
    maps = model.input_maps(s.unsqueeze(0))[0]
    maps2 = model.input_maps(s2.unsqueeze(0))[0]
    with torch.no_grad():
        a = model.encode(s[2:3].float(), None if maps is None else maps[0, 2:3])
        b = model.encode(s2[2:3].float(), None if maps2 is None else maps2[0, 2:3])
    assert torch.equal(a, b)


def synthetic_batch(b: int = 2, k: int = 2, h: int = 16, w: int = 16) -> tuple[torch.Tensor, torch.Tensor]:
    """Smooth random light y (expected spikes per step, 0.03 .. 0.6) and Bernoulli spikes of it."""
    g = torch.Generator().manual_seed(3)
    coarse = torch.rand(b * k, 1, 4, 4, generator=g)
    y = torch.nn.functional.interpolate(coarse, size=(h, w), mode="bilinear", align_corners=False)
    y = (0.03 + 0.57 * y).reshape(b, k, h, w)
    spikes = torch.rand(b, k, T, h, w, generator=g) < y.unsqueeze(2)
    return spikes, y


@pytest.mark.parametrize("name", PUBLISHED_REPRESENTATIONS)
def test_training_lowers_the_loss(name):
    model = tiny_net(name).train()
    spikes, y = synthetic_batch()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    losses = []
    for _ in range(20):
        loss = (model(spikes) - y).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert all(math.isfinite(v) for v in losses)
    assert sum(losses[-3:]) / 3 < 0.6 * losses[0], losses  # about 0.35-0.45 x on this set
