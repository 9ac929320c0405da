"""evaluate / reconstruct pipelines end to end on tiny streams, the CLI hooks, and TFP on a real
stream from another simulator (the Spk2ImgNet sample: optional test data, see tests/conftest.py)."""
from __future__ import annotations

import argparse
import csv

import numpy as np
import pytest
import torch

from model.arch import build_model
from model.checkpoint import save_checkpoint
from model.config import ExperimentConfig, ModelConfig
from model.metrics import psnr, ssim
from model.methods import MapMethod, method_from_spec
from model.representations import tfp_windows
from modeltest_fakes import make_scene
from pipelines import evaluate as ev
from pipelines import reconstruct as rc
from pipelines import train as tr


def tiny_checkpoint(path, window=7):
    exp = ExperimentConfig("tinytest", model=ModelConfig(window=window, num_features=8, num_blocks=1, deform_groups=2))
    torch.manual_seed(0)
    save_checkpoint(path, build_model(exp.model), exp)
    return path


def test_add_parser_registers_subcommands():
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command", required=True)
    for mod in (tr, ev, rc):
        mod.add_parser(sub)
    a = parser.parse_args(["train", "--data", "d", "--config", "tiny", "--max-steps", "3"])
    assert a.func is tr.cmd_train and a.max_steps == 3
    a = parser.parse_args(["evaluate", "--data", "d", "--methods", "tfp", "net=run/last.pt"])
    assert a.func is ev.cmd_evaluate and a.methods == ["tfp", "net=run/last.pt"]
    a = parser.parse_args(["reconstruct", "x.dat", "--out", "o", "--enhance", "stretch"])
    assert a.func is rc.cmd_reconstruct and a.enhance == "stretch"


def test_metrics_conventions():
    rng = np.random.default_rng(0)
    gt = rng.uniform(0, 1, (32, 32))
    assert psnr(gt + 0.1, gt) == pytest.approx(20.0, abs=0.8)  # clipping at 1 trims some error
    assert psnr(np.full((8, 8), 0.5), np.full((8, 8), 0.6)) == pytest.approx(20.0)
    assert psnr(gt, gt) == float("inf") and ssim(gt, gt) == pytest.approx(1.0)
    assert psnr(np.full((8, 8), 3.0), np.ones((8, 8))) == float("inf")  # both clipped to [0, 1]
    with pytest.raises(ValueError, match="NaN"):
        psnr(np.full((8, 8), np.nan), gt[:8, :8])
    with pytest.raises(ValueError, match="one shape"):
        ssim(gt, gt[:5])
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(gt[:10], gt[:10])


def test_evaluation_run_finds_longest_run():
    sc = make_scene("a", 8, 8, 7 * 6, gt_every=1)
    assert ev.evaluation_run(sc, 7) == (3, 6)
    sc.gt = {n: sc.gt[n] for n in (3, 10, 24, 31, 38)}  # runs 3,10 and 24,31,38
    assert ev.evaluation_run(sc, 7) == (24, 3)
    sc.gt = {0: sc.gt[24]}
    with pytest.raises(ValueError, match="no ground-truth step"):
        ev.evaluation_run(sc, 7)


def test_evaluate_table(tmp_path):
    scenes = [make_scene(f"s{i}", 12, 16, 7 * 4, brightness=0.3, seed=i) for i in range(2)]
    ckpt = tiny_checkpoint(tmp_path / "net" / "last.pt")
    methods = [MapMethod("TFP", "tfp", 7), MapMethod("TFI", "tfi", 7), method_from_spec(f"net={ckpt}", 7, chunk=2)]
    rows = ev.evaluate(scenes, methods, 7, progress=False)
    assert len(rows) == 2 * 3 + 3
    # TFP by hand on scene s1, window 2
    sc = scenes[1]
    win = torch.from_numpy(sc.spikes(14, 21)).unsqueeze(0)
    by = {(r.scene, r.method): r for r in rows}
    manual = [psnr(tfp_windows(torch.from_numpy(sc.spikes(7 * i, 7 * i + 7)).unsqueeze(0))[0].numpy(),
                   sc.ground_truth(7 * i + 3)) for i in range(4)]
    assert by[("s1", "TFP")].psnr == pytest.approx(np.mean(manual))
    assert by[(ev.ALL, "net")].frames == 8 and win.shape == (1, 7, 12, 16)
    csv_path, md_path = ev.write_results(rows, ["TFP", "TFI", "net"], tmp_path / "out")
    table = md_path.read_text()
    assert "| PSNR |" in table and "data range 1" in table and "| s0 | 4 |" in table
    assert len(list(csv.DictReader(csv_path.open()))) == 9
    with pytest.raises(ValueError, match="unique"):
        ev.evaluate(scenes, [methods[0], methods[0]], 7, progress=False)
    with pytest.raises(ValueError, match="7-step windows"):
        ev.evaluate(scenes, [MapMethod("TFP9", "tfp", 9)], 7, progress=False)


def test_evaluate_command_on_a_dataset_on_disk(tmp_path):
    pytest.importorskip("OpenEXR", reason="the dataset layout stores ground truth as EXR")
    from spikesim.dataset import write_scene
    from spikesim.stream import SpikeStream
    for i in range(2):
        sc = make_scene(f"scene{i}", 12, 16, 41 * 3, brightness=0.2, seed=i)
        write_scene(tmp_path / "data", sc.name, SpikeStream.from_bool(sc.spike_array),
                    {n: sc.gt[n] for n in (20, 61, 102)}, meta={})
    parser = argparse.ArgumentParser()
    ev.add_parser(parser.add_subparsers())
    args = parser.parse_args(["evaluate", "--data", str(tmp_path / "data"), "--out", str(tmp_path / "res"),
                              "--quiet", "--device", "cpu"])
    assert args.func(args) == 0
    rows = list(csv.DictReader((tmp_path / "res" / "metrics.csv").open()))
    assert {(r["scene"], r["method"], r["frames"]) for r in rows} >= {("ALL", "TFP", "6"), ("scene1", "TFI", "3")}


def test_reconstruct_dat_to_frames(tmp_path):
    from spikesim.stream import SpikeStream, write_dat
    sc = make_scene("r", 16, 24, 7 * 5 + 3, brightness=0.3)
    dat = write_dat(tmp_path / "s.dat", SpikeStream.from_bool(sc.spike_array))
    summary = rc.reconstruct_file(dat, tmp_path / "tfp", "tfp", 16, 24, None, True, start=3, window=7,
                                  save_npy=True, mp4=False, progress=False)
    assert summary["frames"] == 5 and summary["header_columns"] == 0
    frames = np.load(tmp_path / "tfp" / "frames.npy")
    want = tfp_windows(torch.from_numpy(sc.spike_array[3:38]).reshape(5, 7, 16, 24)).numpy()
    np.testing.assert_allclose(frames, want)
    assert len(list((tmp_path / "tfp" / "png").glob("*.png"))) == 5 and (tmp_path / "tfp" / "frames.gif").exists()
    # a network, from its checkpoint, through the same path
    ckpt = tiny_checkpoint(tmp_path / "n.pt")
    s = rc.reconstruct_file(dat, tmp_path / "net", str(ckpt), 16, 24, None, True, window=7, chunk=2,
                            enhance="stretch", gif=False, mp4=False, progress=False)
    assert s["frames"] == 5 and len(list((tmp_path / "net" / "png").glob("*.png"))) == 5


def test_reconstruct_drops_header_columns(tmp_path):
    from spikesim.stream import SpikeStream, write_dat
    sc = make_scene("h", 16, 24, 7 * 4, brightness=0.3)
    wide = np.concatenate([sc.spike_array, np.ones((28, 16, 16), bool)], axis=2)  # 16 junk columns last
    dat = write_dat(tmp_path / "wide.dat", SpikeStream.from_bool(wide))
    assert rc.detect_header_columns(dat, 16, 24) == 16
    s = rc.reconstruct_file(dat, tmp_path / "o", "tfp", 16, 24, None, True, window=7, save_npy=True,
                            gif=False, mp4=False, progress=False)
    assert s["header_columns"] == 16
    want = tfp_windows(torch.from_numpy(sc.spike_array).reshape(4, 7, 16, 24)).numpy()
    np.testing.assert_allclose(np.load(tmp_path / "o" / "frames.npy"), want)
    (tmp_path / "bad.dat").write_bytes(b"\0" * 7)
    with pytest.raises(ValueError, match="not a whole number"):
        rc.detect_header_columns(tmp_path / "bad.dat", 16, 24)


def test_tfp_on_the_spk2imgnet_sample(shared_data):
    """TFP over the 41 steps around frame 151, divided by that simulator's 0.6 firing scale,
    against its ground-truth PNG (README: about 23.5 dB); the unflipped read is far worse."""
    from PIL import Image
    from spikesim.stream import read_dat
    folder = shared_data / "spk2imgnet-sample"
    dat, png = folder / "203_part1_key_id151.dat", folder / "203_part1_key_id151.png"
    if not dat.exists() or not png.exists():
        pytest.skip(f"Spk2ImgNet sample not found in {folder}")
    gt = np.asarray(Image.open(png), dtype=np.float32) / 255.0
    win = torch.from_numpy(read_dat(dat, 250, 400, 131, 172, flip=True).unpack())
    est = tfp_windows(win.unsqueeze(0))[0].numpy() / 0.6
    assert 22.5 < psnr(est, gt) < 25.0
    flipped = tfp_windows(torch.from_numpy(read_dat(dat, 250, 400, 131, 172, flip=False).unpack()).unsqueeze(0))[0]
    assert psnr(flipped.numpy() / 0.6, gt) < psnr(est, gt) - 3


def test_evaluate_says_when_a_window_leaves_ground_truth_unscored(capsys):
    """--window 3 on a set with ground truth every 41 steps scored 1 of 5 frames per scene and said
    nothing but "(1 frames)" (round eight)."""
    from model.evaluation import evaluate, unscored_note
    sc = make_scene("s_low", 16, 16, 41 * 5, gt_every=41)
    assert unscored_note(sc, 41) is None
    note = unscored_note(sc, 3)
    assert note == ("s_low: 1 of its 4 ground-truth frames scored: the scored windows are consecutive, so their "
                    "centres must be 3 steps apart; its ground truth is 41 steps apart")
    rows = evaluate([sc], [method_from_spec("tfp", 3)], 3, progress=False)
    assert rows[0].frames == 1 and f"[evaluate] note: {note}" in capsys.readouterr().err


def test_model_reconstruct_takes_a_checkpoint_as_a_path_object(tmp_path):
    """method=pathlib.Path(...) was refused as "not a method spec" while the same str worked (round eight)."""
    import model
    ckpt = tiny_checkpoint(tmp_path / "t.pt", window=41)
    s = np.random.default_rng(0).random((41 * 3, 16, 16)) < 0.2
    np.testing.assert_array_equal(model.reconstruct(s, method=ckpt), model.reconstruct(s, method=str(ckpt)))
