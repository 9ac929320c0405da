"""Horizon inference: each frame is the network's output on a piece of K windows on its own, as in
training (model.streaming.horizon_reconstruct), the pieces cover every window once, and the
methods and commands take the horizon."""
from __future__ import annotations

import argparse

import pytest
import torch

from model.arch import build_model
from model.config import ModelConfig
from model.methods import ModelMethod, check_horizon, method_from_spec
from model.streaming import (TensorWindows, default_horizon_stride, horizon_pieces, horizon_reconstruct,
                             reconstruct_windows)
from pipelines.argtypes import horizon_arg

from test_model_streaming import sparse_windows, tiny_model


@pytest.mark.parametrize("m", [1, 3, 5, 6, 9, 17, 40])
@pytest.mark.parametrize("horizon,stride", [(5, 1), (5, 3), (5, 5), (5, 2), (4, 2), (1, 1), (7, 5), (3, 1)])
def test_pieces_give_every_window_once_from_inside_a_piece(m, horizon, stride):
    pieces = horizon_pieces(m, horizon, stride)
    given = [i for _, frames in pieces for i in frames]
    assert given == list(range(m))
    length = min(horizon, m)
    for start, frames in pieces:
        assert 0 <= start and start + length <= m
        assert start <= frames.start and frames.stop <= start + length
    if m > horizon:
        offset = (horizon - stride) // 2
        # away from the stream's ends a piece gives its middle `stride` windows
        for start, frames in pieces[1:-1]:
            assert (frames.start - start, len(frames)) == (offset, stride)


def test_pieces_of_a_short_stream_are_the_stream():
    assert horizon_pieces(4, 5, 3) == [(0, range(4))]
    assert horizon_pieces(5, 5, 1) == [(0, range(5))]


@pytest.mark.parametrize("horizon,stride", [(0, 1), (5, 0), (5, 6), (-1, 1)])
def test_pieces_refuse_bad_arguments(horizon, stride):
    with pytest.raises(ValueError, match="horizon"):
        horizon_pieces(9, horizon, stride)


def test_default_stride_leaves_a_window_each_side():
    assert [default_horizon_stride(k) for k in (1, 2, 3, 5, 9)] == [1, 1, 1, 3, 7]


@pytest.mark.parametrize("switches", [{}, {"output": "refine", "refine_span": 3}, {"interval": "lisi"}])
def test_frames_of_part_of_a_sequence_are_forward_s(switches):
    """ReconNet.frames with `take` runs the recurrences only as far as they need, and gives what
    forward gives for those windows."""
    model = tiny_model(**switches)
    s = sparse_windows(6).unsqueeze(0)
    with torch.no_grad():
        ref = model(s)[0]
        for take in (range(6), range(2, 4), range(0, 1), range(5, 6)):
            got = dict((i, y[0]) for i, y in model.frames(s, take=take))
            assert sorted(got) == list(take)
            for i in take:
                torch.testing.assert_close(got[i], ref[i], atol=1e-6, rtol=1e-6)
    with pytest.raises(ValueError, match="take"):
        next(model.frames(s, take=range(4, 8)))


@pytest.mark.parametrize("horizon,stride", [(5, 3), (5, 1), (3, 3), (4, 2)])
def test_each_frame_is_the_network_on_its_piece_alone(horizon, stride):
    model = tiny_model()
    s = sparse_windows(11)
    got = dict(horizon_reconstruct(model, TensorWindows(s), horizon, stride))
    assert sorted(got) == list(range(11))
    with torch.no_grad():
        for start, frames in horizon_pieces(11, horizon, stride):
            piece = model(s[start:start + horizon].unsqueeze(0))[0]
            for i in frames:
                torch.testing.assert_close(got[i], piece[i - start], atol=1e-6, rtol=1e-6)


def test_horizon_differs_from_the_whole_stream_and_equals_it_when_the_stream_is_short():
    """The test above can fail: on a long stream the pieces' frames are not the one-shot frames; on
    a stream within the horizon they are."""
    model = tiny_model()
    long, short = sparse_windows(9), sparse_windows(5)
    whole = reconstruct_windows(model, long, chunk=4)
    pieces = torch.stack([y for _, y in horizon_reconstruct(model, TensorWindows(long), 5, 3)])
    assert (pieces - whole).abs().max() > 1e-3
    one_shot = reconstruct_windows(model, short, chunk=2)
    same = torch.stack([y for _, y in horizon_reconstruct(model, TensorWindows(short), 5, 3)])
    torch.testing.assert_close(same, one_shot, atol=1e-5, rtol=1e-5)


def _checkpoint(tmp_path, num_windows: int = 3):
    from model.checkpoint import save_checkpoint
    from model.config import ExperimentConfig, TrainConfig
    cfg = ModelConfig(window=5, num_features=8, num_blocks=1, deform_groups=2)
    torch.manual_seed(0)
    model = build_model(cfg)
    path = tmp_path / "last.pt"
    save_checkpoint(path, model, ExperimentConfig(name="t", model=cfg, train=TrainConfig(num_windows=num_windows)))
    return path


def test_a_network_method_runs_at_its_training_horizon_by_default(tmp_path):
    path = _checkpoint(tmp_path, num_windows=3)
    s = sparse_windows(8)
    default = ModelMethod("t", path)
    assert (default.horizon_windows, default.horizon_stride) == (3, 1)
    whole = ModelMethod("t", path, chunk=3, horizon="all")
    assert whole.horizon_windows is None
    ref = torch.stack([y for _, y in horizon_reconstruct(default.model, TensorWindows(s), 3, 1)])
    got = torch.stack([y for _, y in default.frames(TensorWindows(s))])
    torch.testing.assert_close(got, ref)
    one_shot = torch.stack([y for _, y in whole.frames(TensorWindows(s))])
    torch.testing.assert_close(one_shot, reconstruct_windows(whole.model, s), atol=1e-5, rtol=1e-5)
    spec = method_from_spec(str(path), window=5, horizon=4, horizon_stride=2)
    assert (spec.horizon_windows, spec.horizon_stride) == (4, 2)
    flips = method_from_spec(f"flips:{path}", window=5, horizon="all")
    assert flips.inner.horizon_windows is None


@pytest.mark.parametrize("horizon,stride,match", [
    (0, None, "horizon 0"), ("some", None, "horizon 'some'"), (True, None, "horizon True"),
    (5, 0, "stride 0"), ("all", 2, "applies to pieces"),
])
def test_bad_horizons_are_refused(horizon, stride, match):
    with pytest.raises(ValueError, match=match):
        check_horizon(horizon, stride)


def test_a_stride_past_the_horizon_is_refused(tmp_path):
    path = _checkpoint(tmp_path)
    with pytest.raises(ValueError, match="stride 4 is more than its horizon of 3"):
        ModelMethod("t", path, horizon="trained", horizon_stride=4)


def test_the_command_line_takes_a_horizon():
    assert [horizon_arg(t) for t in ("trained", "all", "7")] == ["trained", "all", 7]
    for bad in ("0", "-2", "many", "2.5"):
        with pytest.raises(argparse.ArgumentTypeError, match="trained"):
            horizon_arg(bad)
    from pipelines.cli import build_parser
    args = build_parser().parse_args(["evaluate", "--data", "d", "--methods", "lrrep", "--horizon", "all"])
    assert (args.horizon, args.horizon_stride) == ("all", None)
    args = build_parser().parse_args(["reconstruct", "x.dat", "-o", "o", "--horizon", "4", "--horizon-stride", "1"])
    assert (args.horizon, args.horizon_stride) == (4, 1)


def test_results_record_how_each_network_ran(tmp_path):
    """evaluate's metrics.md and JSON say the horizon: a table made with the default reads otherwise
    like one made with --horizon all."""
    from model.methods import inference_record
    from pipelines.evaluate import horizon_markdown
    path = _checkpoint(tmp_path, num_windows=3)
    methods = [method_from_spec("tfp", window=5), method_from_spec(f"a={path}", window=5),
               method_from_spec(f"b={path}", window=5, horizon="all"),
               method_from_spec(f"c=flips:{path}", window=5, horizon=4, horizon_stride=2)]
    record = inference_record(methods)
    assert record == {"a": "pieces of 3 windows, 1 frame(s) from each",
                      "b": "one pass over the whole stream (horizon all)",
                      "c": "pieces of 4 windows, 2 frame(s) from each"}
    line = horizon_markdown(record)
    assert "a: pieces of 3 windows" in line and "b: one pass" in line
    assert horizon_markdown(inference_record(methods[:1])) == ""


def _reference_order_forward(model, spikes):
    """The training forward pass as every run was made with (before frames() existed): forward
    recurrence, then the backward one with each window decoded as it is reached."""
    from model.arch import span_rates

    x, feats, (k, h, w) = model._features(spikes, None)
    fwd, state = [], None
    for i in range(k):
        state = model.step(feats[:, i], state, backward=False)
        fwd.append(state)
    out = [None] * k
    spans = span_rates(x, model.cfg.refine_span) if model.cfg.refine_span > 1 else None
    state = None
    for i in range(k - 1, -1, -1):
        state = model.step(feats[:, i], state, backward=True)
        out[i] = model.decode(fwd[i], state, x[:, i] if model.cfg.decode_needs_window else None,
                              None if spans is None else spans[:, i])
    return torch.stack(out, 1)[..., :h, :w]


def _gradients(model, run, spikes):
    model.zero_grad(set_to_none=True)
    run(spikes).abs().sum().backward()
    return {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}


@pytest.mark.parametrize("switches", [{}, {"output": "refine", "refine_span": 3}, {"interval": "lisi"}])
def test_forward_builds_the_graph_in_the_order_runs_were_trained_with(switches):
    """Bit for bit, the gradients of forward are those of the construction order every training run
    used: decoding in another order (frames' order) changes their last bits, and a run rerun or
    resumed from an older checkpoint would drift from step 4 (measured on the shipped network's)."""
    model = tiny_model(**switches).train()
    s = torch.stack([sparse_windows(5, seed) for seed in (3, 4)]).float()
    got = _gradients(model, model, s)
    want = _gradients(model, lambda t: _reference_order_forward(model, t), s)
    assert got.keys() == want.keys() and got
    for name in want:
        assert torch.equal(got[name], want[name]), name
