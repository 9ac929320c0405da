"""The traditional STP and SNM methods (model/classic_methods.py): exact steady state on periodic
spike trains, dark stays dark, shapes and range, chunking does not change a frame, parameters
checked by name, and the names every command takes."""
from __future__ import annotations

import argparse
import math

import pytest
import torch

from model.classic_methods import (SNMMethod, SNMParams, STPMethod, STPParams, STPState, stp_rate, stp_update)
from model.methods import method_from_spec
from model.streaming import TensorWindows

T = 41
SPECS = ("stp", "snm")


def frames(method, spikes: torch.Tensor) -> dict[int, torch.Tensor]:
    return dict(method.frames(TensorWindows(spikes)))


def periodic(periods: list[int], num_windows: int, phase_step: int = 3) -> torch.Tensor:
    """(M, T, 1, P): pixel k fires every periods[k] steps, from step (k * phase_step) % period."""
    s = torch.zeros(num_windows * T, 1, len(periods), dtype=torch.bool)
    for k, n in enumerate(periods):
        s[(k * phase_step) % n::n, 0, k] = True
    return s.reshape(num_windows, T, 1, len(periods))


PERIODS = [1, 2, 3, 5, 8, 13, 41, 100, 250]


@pytest.mark.parametrize("spec", SPECS)
def test_a_spike_every_n_steps_reads_one_over_n(spec) -> None:
    """A constant-rate train (one spike every n steps) is read as exactly 1/n once settled: STP
    inverts its synapse's fixed point analytically, SNM's static integration is a harmonic mean of
    equal intervals. Tolerance 1e-5 relative (float64 state, float32 output)."""
    out = frames(method_from_spec(spec), periodic(PERIODS, 30))
    for i in (27, 28, 29):  # the last windows: >= 4 intervals even at n = 250
        want = torch.tensor([1 / n for n in PERIODS])
        assert torch.allclose(out[i][0], want, rtol=1e-5, atol=0), (spec, i, out[i][0] * torch.tensor(PERIODS))


def test_stp_state_decodes_each_interval_at_its_fixed_point() -> None:
    """The decoder is the analytic inverse of the update: driving the functions directly with a
    long constant interval n (far past float32's reach for R at D = 1) gives 1/n."""
    p = STPParams()
    for n in (1, 7, 60, 400):
        st = STPState.rest((1, 1))
        for k in range(1, 200):  # u settles by (1 - f) exp(-n / F) per spike: 0.77 at n = 1
            st = stp_update(st, torch.ones(1, 1, dtype=torch.bool), k * n - 1, p)
        assert stp_rate(st, p).item() == pytest.approx(1 / n, rel=1e-5)


@pytest.mark.parametrize("spec", SPECS)
def test_a_dark_pixel_stays_dark(spec) -> None:
    g = torch.Generator().manual_seed(0)
    s = torch.rand(6, T, 8, 8, generator=g) < 0.3
    s[:, :, 3, 4] = False  # dark, amid bright neighbours (SNM's motion neurons see them)
    s[:, :, :, 7] = False
    out = frames(method_from_spec(spec), s)
    assert all(float(f[3, 4]) == 0 and float(f[:, 7].abs().max()) == 0 for f in out.values())
    assert all(float(f.abs().max()) == 0 for f in frames(method_from_spec(spec), torch.zeros(3, T, 4, 5)).values())


@pytest.mark.parametrize("spec", SPECS)
def test_shapes_range_and_order(spec) -> None:
    g = torch.Generator().manual_seed(1)
    rate = torch.rand(1, 1, 9, 7, generator=g)  # every pixel its own light
    s = torch.rand(5, T, 9, 7, generator=g) < rate
    got = list(method_from_spec(spec).frames(TensorWindows(s)))
    assert [i for i, _ in got] == list(range(5))
    for _, f in got:
        assert f.shape == (9, 7) and f.dtype == torch.float32
        assert bool(torch.isfinite(f).all()) and float(f.min()) >= 0 and float(f.max()) <= 1


@pytest.mark.parametrize("spec", SPECS)
def test_chunk_size_does_not_change_a_frame(spec) -> None:
    """The state is carried across windows and chunks: one window at a time, three, or all at
    once give the same frames, bit for bit."""
    g = torch.Generator().manual_seed(2)
    rate = torch.rand(1, 1, 10, 12, generator=g) * 0.5
    s = torch.rand(7, T, 10, 12, generator=g) < rate
    s[4:, :, 2:8, 3:9] = torch.rand(3, T, 6, 6, generator=g) < 0.05  # a change: SNM's motion neurons fire
    runs = [frames(method_from_spec(spec, chunk=c), s) for c in (1, 3, 64)]
    for i in range(7):
        assert torch.equal(runs[0][i], runs[1][i]) and torch.equal(runs[0][i], runs[2][i])


def test_stp_follows_a_change_of_light() -> None:
    """Short-term plasticity forgets: after the rate of a pixel jumps from 1/10 to 1/4 the frame
    reads 1/4 again within a window."""
    s = torch.zeros(10 * T, 1, 1, dtype=torch.bool)
    s[0:5 * T:10] = True
    s[5 * T::4] = True
    out = frames(STPMethod("STP"), s.reshape(10, T, 1, 1))
    assert float(out[4]) == pytest.approx(0.1, rel=1e-4) and float(out[6]) == pytest.approx(0.25, rel=1e-4)


def test_snm_restarts_integration_where_the_scene_changes() -> None:
    """A patch whose rate jumps (a moving edge) excites the motion neurons there: the static
    integration restarts and the patch reads the new rate; without the motion layer (a threshold
    nothing reaches) the long integration still mixes the old rate in."""
    m = 20
    s = torch.zeros(m * T, 9, 9, dtype=torch.bool)
    before, after = 10, 3
    for k in range(81):
        y, x = divmod(k, 9)
        s[k % before:8 * T:before, y, x] = True
        s[8 * T + k % after::after, y, x] = True
    s = s.reshape(m, T, 9, 9)
    with_motion = frames(SNMMethod("SNM"), s)[m - 1][4, 4]
    without = frames(SNMMethod("no motion", params=SNMParams(lif_threshold=1e9)), s)[m - 1][4, 4]
    assert float(with_motion) == pytest.approx(1 / after, rel=0.01)
    assert float(without) < 0.9 / after


@pytest.mark.parametrize("cls, kwargs, field", [
    (STPParams, {"u0": 1.5}, "STPParams.u0"),
    (STPParams, {"f": 0.0}, "STPParams.f"),
    (STPParams, {"D": 0}, "STPParams.D"),
    (STPParams, {"F": math.nan}, "STPParams.F"),
    (STPParams, {"F": True}, "STPParams.F"),
    (SNMParams, {"neighbourhood": 2}, "SNMParams.neighbourhood"),
    (SNMParams, {"rel_change": -0.1}, "SNMParams.rel_change"),
    (SNMParams, {"lif_decay": 1.0}, "SNMParams.lif_decay"),
    (SNMParams, {"lif_threshold": 0}, "SNMParams.lif_threshold"),
    (SNMParams, {"hold": 2.5}, "SNMParams.hold"),
    (SNMParams, {"static_tau": math.inf}, "SNMParams.static_tau"),
    (SNMParams, {"min_intervals": 0}, "SNMParams.min_intervals"),
])
def test_bad_parameters_are_refused_by_name(cls, kwargs, field) -> None:
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        cls(**kwargs)


def test_params_are_frozen_and_chunk_checked() -> None:
    with pytest.raises(Exception):
        STPParams().u0 = 0.2  # type: ignore[misc]
    with pytest.raises(ValueError, match="chunk"):
        STPMethod("STP", chunk=0)


def test_the_methods_are_taken_by_name() -> None:
    from pipelines.compare import baseline_label, baseline_spec
    assert method_from_spec("stp").name == "STP" and method_from_spec("snm").name == "SNM"
    assert method_from_spec("mine=snm").name == "mine"
    assert isinstance(method_from_spec("stp"), STPMethod) and isinstance(method_from_spec("snm"), SNMMethod)
    assert [baseline_spec(b) for b in SPECS] == list(SPECS) and baseline_label("snm") == "SNM"
    with pytest.raises(argparse.ArgumentTypeError, match="stp"):
        baseline_spec("stpp")
    with pytest.raises(ValueError, match="stp, snm"):
        method_from_spec("stpp")


@pytest.mark.parametrize("spec", SPECS)
def test_a_long_stream_is_read_once_a_chunk_at_a_time(spec) -> None:
    """Memory is one chunk of windows: the source is asked for consecutive chunks of at most
    `chunk` windows, each window once, in order (a 4000-window stream is never held whole)."""
    calls: list[tuple[int, int]] = []

    class Recording(TensorWindows):
        def windows(self, start: int, stop: int) -> torch.Tensor:
            calls.append((start, stop))
            return super().windows(start, stop)

    s = torch.rand(40, T, 2, 2, generator=torch.Generator().manual_seed(3)) < 0.2
    assert len(list(method_from_spec(spec, chunk=4).frames(Recording(s)))) == 40
    assert calls == [(a, a + 4) for a in range(0, 40, 4)]
