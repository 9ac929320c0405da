"""TFP, TFI, LISI and GISI on hand-made streams, with values computed by hand in the comments."""
from __future__ import annotations

import pytest
import torch

from model.representations import (LastSpike, NextSpike, backward_spike_times, forward_spike_times, gisi,
                                   lisi, lisi_windows, tfi, tfi_windows, tfp, tfp_windows, transform_interval)


def pixel_stream(*spike_steps: int, length: int) -> torch.Tensor:
    """(length, 1, 1) bool stream with spikes at the given steps."""
    s = torch.zeros(length, 1, 1, dtype=torch.bool)
    for n in spike_steps:
        s[n] = True
    return s


def windows_of(stream: torch.Tensor, t: int) -> torch.Tensor:
    return stream.reshape(-1, t, *stream.shape[1:])


# ---- TFP / TFI ----------------------------------------------------------------------------------

def test_tfp_counts_over_length():
    s = pixel_stream(0, 3, 4, length=5)  # 3 spikes in 5 steps
    assert tfp(s).item() == pytest.approx(3 / 5)
    assert tfp(pixel_stream(length=5)).item() == 0.0


def test_tfi_interval_around_centre():
    # T = 7, centre 3. Last spike at or before 3 is at 1; first strictly after 3 is at 6: ISI 5.
    assert tfi(pixel_stream(1, 6, length=7)).item() == pytest.approx(1 / 5)
    # A spike exactly at the centre belongs to the "before" side: 3 -> 5, ISI 2.
    assert tfi(pixel_stream(0, 3, 5, length=7)).item() == pytest.approx(1 / 2)
    # Nothing before the centre: the stand-in is step -1; next at 4: ISI 5.
    assert tfi(pixel_stream(4, length=7)).item() == pytest.approx(1 / 5)
    # Nothing after the centre: stand-in is step T = 7; last at 2: ISI 5.
    assert tfi(pixel_stream(2, length=7)).item() == pytest.approx(1 / 5)
    # Never fired: 1 / (T + 1).
    assert tfi(pixel_stream(length=7)).item() == pytest.approx(1 / 8)
    # Every step fires: ISI 1.
    assert tfi(torch.ones(7, 1, 1, dtype=torch.bool)).item() == pytest.approx(1.0)


def test_tfi_and_tfp_batched_equal_unbatched():
    g = torch.Generator().manual_seed(1)
    s = torch.rand(3, 9, 4, 5, generator=g) < 0.3
    for fn in (tfp, tfi):
        batched = fn(s)
        assert batched.shape == (3, 4, 5)
        for b in range(3):
            assert torch.equal(batched[b], fn(s[b]))


def test_tfi_matches_a_loop_reference():
    g = torch.Generator().manual_seed(2)
    s = torch.rand(11, 6, 7, generator=g) < 0.2
    out = tfi(s)
    c = 5
    for y in range(6):
        for x in range(7):
            col = s[:, y, x].tolist()
            prev = max([n for n in range(c + 1) if col[n]], default=-1)
            nxt = min([n for n in range(c + 1, 11) if col[n]], default=11)
            assert out[y, x].item() == pytest.approx(1 / (nxt - prev))


def test_window_sequence_helpers():
    g = torch.Generator().manual_seed(3)
    s = torch.rand(2, 4, 5, 3, 3, generator=g) < 0.3  # (B, K, T, H, W)
    assert torch.equal(tfp_windows(s)[1, 2], tfp(s[1, 2]))
    assert torch.equal(tfi_windows(s)[0, 3], tfi(s[0, 3]))
    assert torch.equal(lisi_windows(s)[1, 1], lisi(s[1, 1]))


# ---- LISI -------------------------------------------------------------------------------------

def test_lisi_rule_strictly_before_and_at_or_after_centre():
    # T = 5, centre 2. Spikes at 1 and 2: last strictly before 2 is 1, first at or after is 2 -> 1.
    assert lisi(pixel_stream(1, 2, length=5)).item() == 1
    # Spike only at the centre: before-side stand-in -1 -> 2 - (-1) = 3.
    assert lisi(pixel_stream(2, length=5)).item() == 3
    # Silent window: T + 1 = 6 (42 for 41-step windows).
    assert lisi(pixel_stream(length=5)).item() == 6
    assert lisi(pixel_stream(length=41)).item() == 42


# ---- GISI -------------------------------------------------------------------------------------

def test_gisi_hand_computed_sequence():
    # Three windows of T = 5 (centres 2, 7, 12); spikes at absolute steps 1, 9, 12.
    s = windows_of(pixel_stream(1, 9, 12, length=15), 5)
    g, last, nxt = gisi(s)
    # window 0: last < 2 is 1, first >= 2 is 9 -> 8
    # window 1: last < 7 is 1 (carried from window 0), first >= 7 is 9 -> 8
    # window 2: last < 12 is 9, first >= 12 is 12 -> 3
    assert g.flatten().tolist() == [8.0, 8.0, 3.0]
    assert last.steps.item() == 12 and nxt.steps.item() == 1
    # LISI, window by window in window-relative steps (stand-ins -1 and T = 5):
    # window 0: before 1, after none -> 5: 4; window 1: spike at 4 (abs 9): -1 -> 4: 5;
    # window 2: spike at 2 (abs 12), the centre: -1 -> 2: 3.
    assert lisi_windows(s).flatten().tolist() == [4.0, 5.0, 3.0]


def test_gisi_never_fired_sentinel_is_explicit():
    k, t = 4, 41
    s = torch.zeros(k, t, 2, 2, dtype=torch.bool)
    g, last, nxt = gisi(s)
    # Authors' sentinels: last = -1, next = K*41  ->  GISI = K*41 + 1 everywhere.
    assert torch.all(g == k * t + 1)
    assert torch.all(last.steps == -1) and torch.all(nxt.steps == k * t)
    # Only one spike in the whole sequence, at absolute step 50 (in window 1, whose centre is 61):
    s[1, 50 - 41, 0, 0] = True
    g, _, _ = gisi(s)
    # window 0 (centre 20): -1 -> 50: 51. Windows 1..3 (centres 61, 102, 143): 50 -> K*41 = 164: 114.
    assert g[:, 0, 0].tolist() == [51.0, (k * t) - 50, (k * t) - 50, (k * t) - 50]


def test_gisi_matches_loop_reference_randomly():
    gen = torch.Generator().manual_seed(4)
    b, k, t, h, w = 2, 5, 7, 3, 4
    s = torch.rand(b, k, t, h, w, generator=gen) < 0.05
    g, _, _ = gisi(s)
    flat = s.permute(0, 3, 4, 1, 2).reshape(b, h, w, k * t)
    for bi in range(b):
        for y in range(h):
            for x in range(w):
                times = [n for n in range(k * t) if flat[bi, y, x, n]]
                for i in range(k):
                    c = i * t + t // 2
                    before = max([n for n in times if n < c], default=-1)
                    after = min([n for n in times if n >= c], default=k * t)
                    assert g[bi, i, y, x].item() == after - before


def test_gisi_streamed_with_carries_equals_one_shot():
    gen = torch.Generator().manual_seed(5)
    s = torch.rand(6, 9, 5, 5, generator=gen) < 0.04  # K=6 windows of 9 steps
    whole, _, _ = gisi(s)
    t = 9
    # Forward carries flow left to right, backward carries right to left.
    fwd_a, last = forward_spike_times(s[:2], first_step=0)
    fwd_b, _ = forward_spike_times(s[2:], first_step=2 * t, carry=last)
    bwd_b, nxt = backward_spike_times(s[2:], first_step=2 * t, carry=NextSpike.never((5, 5), 6 * t))
    bwd_a, _ = backward_spike_times(s[:2], first_step=0, carry=nxt)
    streamed = torch.cat([bwd_a - fwd_a, bwd_b - fwd_b]).float()
    assert torch.equal(streamed, whole)
    # Without the carries the result differs (so the carries matter for this stream).
    alone, _, _ = gisi(s[2:], first_step=2 * t)
    assert not torch.equal(alone, whole[2:])


def test_gisi_carry_validation():
    s = torch.zeros(2, 5, 3, 3, dtype=torch.bool)
    with pytest.raises(ValueError, match="LastSpike.steps has shape"):
        forward_spike_times(s, carry=LastSpike.never((4, 4)))
    with pytest.raises(TypeError, match="int64"):
        backward_spike_times(s, carry=NextSpike(torch.zeros(3, 3, dtype=torch.int32)))


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="0 or 1"):
        tfp(torch.full((5, 2, 2), 2, dtype=torch.uint8))
    with pytest.raises(TypeError, match="bool, uint8"):
        tfi(torch.zeros(5, 2, 2, dtype=torch.int32))
    with pytest.raises(ValueError, match="dimensions"):
        gisi(torch.zeros(5, 2, 2, dtype=torch.bool))


def test_transform_interval():
    x = torch.tensor([1.0, 4.0, 862.0])
    assert torch.equal(transform_interval(x, "raw"), x)
    assert torch.allclose(transform_interval(x, "inverse"), torch.tensor([1.0, 0.25, 1 / 862]))
    with pytest.raises(ValueError, match="interval transform"):
        transform_interval(x, "log")
