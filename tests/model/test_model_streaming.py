"""Chunked streaming inference equals one-shot inference on the same windows (its definition)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from model.arch import build_model
from model.config import ModelConfig
from model.streaming import StepWindows, TensorWindows, reconstruct_windows, stream_reconstruct


def tiny_model(**switches) -> torch.nn.Module:
    torch.manual_seed(0)
    cfg = ModelConfig(window=5, num_features=8, num_blocks=1, deform_groups=2, **switches)
    model = build_model(cfg).eval()
    # Non-zero offset convs, so alignment really moves features (they start at zero).
    for name, p in model.named_parameters():
        if "conv_offset_mask" in name:
            p.data.normal_(0, 0.05, generator=torch.Generator().manual_seed(1))
    return model


def sparse_windows(m: int = 7, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(m, 5, 10, 9, generator=g) < 0.08  # dark: many pixels silent for windows


@pytest.mark.parametrize("switches", [
    {},                                             # (E): GISI carries + both recurrences
    {"interval": "lisi"},                           # (F)
    {"adf": False, "aif": False},                   # (C): GISI carries, no recurrent state
    {"representation": "spike", "aif": False},      # (B)
    {"representation": "tfi"},
])
@pytest.mark.parametrize("chunk", [1, 2, 3])
def test_chunked_equals_one_shot(switches, chunk):
    model = tiny_model(**switches)
    s = sparse_windows()
    with torch.no_grad():
        ref = model(s.unsqueeze(0))[0]
    out = reconstruct_windows(model, s, chunk=chunk)
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-5)


def test_chunks_without_carries_would_differ():
    """The test above can fail: cutting the stream into independent chunks changes the output."""
    model = tiny_model()
    s = sparse_windows()
    with torch.no_grad():
        ref = model(s.unsqueeze(0))[0]
        naive = torch.cat([model(s[a:a + 3].unsqueeze(0))[0] for a in range(0, 7, 3)])
    assert (naive - ref).abs().max() > 1e-3


def test_frames_come_in_order_and_single_chunk_is_one_shot():
    model = tiny_model()
    s = sparse_windows(4)
    idx = [i for i, _ in stream_reconstruct(model, TensorWindows(s), chunk=3)]
    assert idx == [0, 1, 2, 3]
    with torch.no_grad():
        ref = model(s.unsqueeze(0))[0]
    assert torch.equal(reconstruct_windows(model, s, chunk=10), ref)


def test_step_reader_source_and_offset_start():
    """Windows cut from a step reader starting at a non-zero step give the same frames."""
    model = tiny_model()
    s = sparse_windows(5)
    steps = np.concatenate([np.zeros((3, 10, 9), bool), s.reshape(25, 10, 9).numpy()])
    src = StepWindows(lambda a, b: steps[a:b], first_step=3, window=5, num_windows=5)
    out = torch.stack([y for _, y in stream_reconstruct(model, src, chunk=2)])
    with torch.no_grad():
        ref = model(s.unsqueeze(0))[0]
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-5)


def test_window_mismatch_is_named():
    model = tiny_model()
    with pytest.raises(ValueError, match="model expects 5"):
        list(stream_reconstruct(model, TensorWindows(torch.zeros(2, 7, 4, 4, dtype=torch.bool))))
    with pytest.raises(ValueError, match="chunk"):
        list(stream_reconstruct(model, TensorWindows(torch.zeros(2, 5, 4, 4, dtype=torch.bool)), chunk=0))


def test_memory_is_bounded_by_the_chunk(tmp_path):
    """Boundary states are spilled to disk: one file per chunk boundary kind, none left after."""
    model = tiny_model()
    s = sparse_windows(6)
    gen = stream_reconstruct(model, TensorWindows(s), chunk=2, spill_dir=tmp_path)
    next(gen)
    spilled = list(tmp_path.rglob("*.pt"))
    assert {p.name for p in spilled} >= {"bstate0.pt", "bstate1.pt", "next0.pt", "last2.pt"}
    list(gen)
    assert not list(tmp_path.rglob("*.pt"))


def test_interval_clip_for_streams_longer_than_training():
    """ModelMethod clips raw GISI at the training horizon; chunking still equals one-shot."""
    model = tiny_model()
    dark = torch.zeros(1, 7, 5, 4, 4, dtype=torch.bool)
    assert model.input_maps(dark)[0].max().item() == 7 * 5 + 1
    model.max_interval = 3 * 5 + 1.0
    assert model.input_maps(dark)[0].max().item() == 16
    s = sparse_windows()
    with torch.no_grad():
        ref = model(s.unsqueeze(0))[0]
    torch.testing.assert_close(reconstruct_windows(model, s, chunk=2), ref, atol=1e-5, rtol=1e-5)
