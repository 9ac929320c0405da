"""`spikesim gates` and model.gates: the refining head's pieces (model.arch.refine_parts) read on a
dataset's evaluation frames, with the frame Y the one `evaluate` scores."""
from __future__ import annotations

import csv
import dataclasses
import json
import math

import numpy as np
import pytest
import torch

pytest.importorskip("OpenEXR", reason="the dataset layout stores ground truth as EXR")

from cli_testing import one_line, run_cli
from model.arch import build_model, classic_estimates, refine, refine_parts
from model.checkpoint import save_checkpoint
from model.config import ExperimentConfig, ModelConfig, TrainConfig
from model.data import open_scenes
from model.gates import gate_scene
from model.methods import method_from_spec
from pipelines.cli import main
from spikesim.dataset import write_manifest, write_scene
from spikesim.stream import SpikeStream

TINY = ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2, output="refine")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Two 16 x 24 scenes of a sliding gradient (low and normal light), noiseless spikes, ground truth
    every 7 steps."""
    root = tmp_path_factory.mktemp("gates") / "data"
    steps = 60
    for i, (name, level) in enumerate((("tex_low", 0.02), ("tex_normal", 0.3))):
        xs = np.linspace(0.2, 1.8, 24, dtype=np.float32)
        y = np.stack([level * np.roll(np.tile(xs, (16, 1)), t // 10, axis=1) for t in range(steps)])
        acc = np.random.default_rng(i).uniform(0, 1, (16, 24)) + np.cumsum(y.astype(np.float64), axis=0)
        spikes = np.diff(np.floor(np.concatenate([acc[:1] - y[:1], acc])), axis=0) > 0
        write_scene(root, name, SpikeStream.from_bool(spikes), {n: y[n] for n in range(3, steps, 7)}, meta={})
    write_manifest(root, {"kind": "test"})
    return root


def _checkpoint(path, cfg: ModelConfig, bias: tuple[float, ...] | None = None, seed: int = 0):
    """A tiny network's checkpoint; `bias` sets its head's last conv to zero weights and these biases
    (the gates' logits are REFINE_GATE_GAIN times them)."""
    torch.manual_seed(seed)
    net = build_model(cfg)
    if bias is not None:
        with torch.no_grad():
            net.head[-1].weight.zero_()
            net.head[-1].bias[:] = torch.tensor(bias)
    exp = ExperimentConfig("tiny_gates", model=cfg, train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=1,
                                                                      lr_milestones=(5,), samples_per_epoch=1,
                                                                      val_fraction=0.0, max_steps=1))
    path.parent.mkdir(parents=True, exist_ok=True)
    save_checkpoint(path, net, exp)
    return path


def test_refine_parts_blend_the_network_and_the_classic_estimate():
    g = torch.Generator().manual_seed(3)
    window = (torch.rand(2, 41, 6, 5, generator=g) < 0.2).float()
    span = torch.rand(2, 6, 5, generator=g)
    for channels in (3, 4):
        head = torch.randn(2, channels, 6, 5, generator=g) * 0.2
        p = refine_parts(head, window, span if channels == 4 else None)
        torch.testing.assert_close(p.frame, refine(head, window, span if channels == 4 else None), rtol=0, atol=0)
        torch.testing.assert_close(p.frame, p.classic_gate * p.classic + (1 - p.classic_gate) * p.net)
        tfp_map, tfi_map = classic_estimates(window)
        if channels == 3:
            assert p.span_gate is None
            torch.testing.assert_close(p.classic, p.tfp_share * tfp_map + (1 - p.tfp_share) * tfi_map)
        else:
            tfp_span = p.span_gate * span + (1 - p.span_gate) * tfp_map
            torch.testing.assert_close(p.classic, p.tfp_share * tfp_span + (1 - p.tfp_share) * tfi_map)
        for gate in (p.classic_gate, p.tfp_share, *(() if p.span_gate is None else (p.span_gate,))):
            assert float(gate.min()) > 0 and float(gate.max()) < 1
    with pytest.raises(ValueError, match="span"):
        refine_parts(torch.zeros(2, 4, 6, 5), window)


@pytest.mark.parametrize("logit_sign, branch", [(1.0, "classic"), (-1.0, "net")])
def test_a_closed_gate_makes_the_frame_that_branch(data, tmp_path, logit_sign, branch):
    """Gate biases at +-60 (logit +-960): g is 1 or 0, so Y is C or N exactly and scores as it does."""
    ckpt = _checkpoint(tmp_path / "run" / "best.pt", TINY, (0.05, 60.0 * logit_sign, 0.0))
    method = method_from_spec(str(ckpt), window=7)
    scene = open_scenes(data)[1]
    score, maps = gate_scene(scene, method)
    assert score.classic_gate == pytest.approx(1.0 if branch == "classic" else 0.0, abs=1e-6)
    assert score.mostly_classic == (1.0 if branch == "classic" else 0.0)
    assert score.tfp_share == pytest.approx(0.5)
    assert math.isnan(score.span_gate)
    assert score.psnr_frame == pytest.approx(getattr(score, f"psnr_{branch}"), abs=1e-9)
    assert score.psnr_aligned_frame == pytest.approx(getattr(score, f"psnr_aligned_{branch}"), abs=1e-9)
    np.testing.assert_allclose(maps.frame, getattr(maps, branch), atol=1e-6)
    if branch == "net":  # N is the frame channel's bias
        assert score.net_mean_y == pytest.approx(0.05, abs=1e-6)
    assert maps.frame.shape == maps.ground_truth.shape == (16, 24)


def test_the_frames_are_those_evaluate_scores(data, tmp_path, capsys):
    """A randomly drawn refining network with a span gate: the gates' frame count and Y's PSNR are
    evaluate's, scene by scene; every gate mean lies in (0, 1)."""
    cfg = dataclasses.replace(TINY, refine_span=3)
    ckpt = _checkpoint(tmp_path / "run" / "best.pt", cfg, seed=5)
    capsys.readouterr()
    assert main(["evaluate", "--data", str(data), "--methods", f"mine={ckpt}", "--window", "7", "--json",
                 "--threads", "1", "--quiet"]) == 0
    rows = {name: by_method["mine"] for name, by_method in json.loads(capsys.readouterr().out)["scenes"].items()}
    method = method_from_spec(str(ckpt), window=7)
    for scene in open_scenes(data):
        score, _ = gate_scene(scene, method)
        assert score.frames == rows[scene.name]["frames"]
        assert score.psnr_frame == pytest.approx(rows[scene.name]["psnr"], abs=1e-6)
        for gate in (score.classic_gate, score.tfp_share, score.span_gate):
            assert 0 < gate < 1
        assert 0 <= score.mostly_classic <= 1
    assert method.model.refine_observer is None  # the hook is removed after reading


def test_the_command_writes_its_tables_and_pictures_and_refuses_what_has_no_gates(data, tmp_path, capsys):
    ckpt = _checkpoint(tmp_path / "run" / "best.pt", TINY, seed=2)
    out = tmp_path / "gates"
    argv = ["gates", "--data", data, "--method", ckpt, "--threads", "1", "--quiet", "-o", out, "--maps"]
    code, err = run_cli(argv, capsys)
    assert code == 0, err
    with open(out / "gates.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["scene"] for r in table] == ["tex_low", "tex_normal"]
    assert {p.name for p in out.glob("*.png")} == {f"{s}_{k}.png" for s in ("tex_low", "tex_normal")
                                                   for k in ("panel", "gate")}
    from PIL import Image
    assert Image.open(out / "tex_low_panel.png").size == (4 * 24, 16)
    assert run_cli(argv, capsys)[0] == 0  # a rerun replaces its own results
    (out / "gates.md").write_text("mine")
    code, err = run_cli(argv, capsys)
    assert code == 2 and "gates.md" in one_line(err)
    assert (out / "gates.md").read_text() == "mine"
    code, err = run_cli(["gates", "--data", data, "--method", "tfp"], capsys)
    assert code == 2 and "only a network with a refining head" in one_line(err)
    direct = _checkpoint(tmp_path / "direct" / "best.pt", dataclasses.replace(TINY, output="direct"))
    code, err = run_cli(["gates", "--data", data, "--method", direct], capsys)
    assert code == 2 and "model.output is 'direct'" in one_line(err)
    code, err = run_cli(["gates", "--data", data, "--method", ckpt, "--maps"], capsys)
    assert code == 2 and "--maps" in one_line(err)
    code, err = run_cli(["gates", "--data", data, "--method", ckpt, "--scenes", "nope"], capsys)
    assert code == 2 and "nope" in one_line(err) and "tex_low" in one_line(err)
    code, err = run_cli(["gates", "--data", data, "--method", ckpt, "-o", data / "inside"], capsys)
    assert code == 2 and "inside the dataset" in one_line(err)
