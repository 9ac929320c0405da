"""`evaluate --dat --gt`: one external stream and its ground-truth image, scored in every metric
convention, with the black and mean floors beside the methods."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from cli_testing import one_line, run_cli
from pipelines.cli import main
from spikesim import SpikeCamera
from spikesim.simulate import Simulator

H, W, STEPS = 30, 40, 61


def _pair(tmp_path: Path, level: float, camera: SpikeCamera | None = None) -> tuple[Path, Path]:
    """A stream (noiseless by default) of a static gradient (mean y = level) with its sidecar, and
    the y image."""
    y = (level * 2 * np.linspace(0.05, 0.95, W, dtype=np.float32)[None, :] * np.ones((H, 1), np.float32))
    cam = dataclasses.replace(camera or SpikeCamera.noiseless(), height=H, width=W)
    dat = Simulator(cam, backend="numpy", seed=0).run_to_dat([y] * STEPS, tmp_path / "s.dat", flip=False)
    np.save(tmp_path / "gt.npy", y)
    return dat, tmp_path / "gt.npy"


def _scores(argv, capsys) -> dict:
    capsys.readouterr()
    rc = main([str(a) for a in ["evaluate", *argv, "--json"]])
    out = capsys.readouterr()
    assert rc == 0, out.err
    return json.loads(out.out)


def test_project_pair_reads_geometry_from_the_sidecar(tmp_path, capsys) -> None:
    dat, gt = _pair(tmp_path, 0.3)
    doc = _scores(["--dat", dat, "--gt", gt, "--center", 30, "--methods", "tfp", "black", "mean"], capsys)
    assert doc["input"]["height"] == H and doc["input"]["width"] == W and doc["input"]["flip"] is False
    tfp, black, mean = (doc["methods"][k] for k in ("TFP", "black", "mean"))
    # noiseless: TFP's error is at most one spike per 41-step window, so PSNR >= 20 log10(41)
    assert tfp["psnr"] >= 20 * math.log10(41)
    for key in ("psnr", "ssim", "psnr_8bit", "ssim_8bit", "psnr_norm", "ssim_norm"):
        assert tfp[key] > mean[key] > black[key], key
    assert tfp["psnr_aligned"] > mean["psnr_aligned"] == pytest.approx(black["psnr_aligned"])
    assert set(tfp) == {"psnr", "ssim", "psnr_8bit", "ssim_8bit", "psnr_norm", "ssim_norm", "psnr_aligned", "ssim_aligned",
                        "frames"}


def test_in_low_light_black_beats_tfp_in_psnr_but_not_aligned_or_ssim_norm(tmp_path, capsys) -> None:
    """Why the aligned column exists: at mean y = 0.004 with every noise term, a 41-step TFP has a
    larger error than an all-black image, so black wins PSNR in every unaligned convention; it
    scores the floor in the aligned one and near 0 in the light-normalised SSIM."""
    dat, gt = _pair(tmp_path, 0.004, SpikeCamera.realistic())
    doc = _scores(["--dat", dat, "--gt", gt, "--center", 30, "--methods", "tfp", "black", "mean"], capsys)
    tfp, black, mean = (doc["methods"][k] for k in ("TFP", "black", "mean"))
    assert black["psnr"] > tfp["psnr"] and black["psnr_norm"] > tfp["psnr_norm"]
    assert tfp["psnr_aligned"] > black["psnr_aligned"] == pytest.approx(mean["psnr_aligned"])
    assert tfp["ssim_norm"] > black["ssim_norm"]


def test_spk2imgnet_sample_against_its_ground_truth(shared_data, capsys) -> None:
    """Another simulator's stream: the firing rate is 0.6 of the image intensity (--gt-scale 0.6).
    The independent check in the data's README gives TFP/0.6 about 23.5 dB against the PNG (range
    1); here y = 0.6 image, so the same error reads 20 log10(1/0.6) = 4.44 dB higher."""
    d = shared_data / "spk2imgnet-sample"
    doc = _scores(["--dat", d / "203_part1_key_id151.dat", "--gt", d / "203_part1_key_id151.png",
                   "--center", 151, "--gt-scale", 0.6, "--methods", "tfp", "tfi", "black", "mean"], capsys)
    m = doc["methods"]
    assert m["TFP"]["psnr"] - 20 * math.log10(1 / 0.6) == pytest.approx(23.5, abs=0.3)
    for method in ("TFP", "TFI"):
        for key in ("psnr", "psnr_norm", "ssim", "ssim_norm"):
            assert m[method][key] > m["mean"][key] > m["black"][key]
    assert doc["input"]["flip"] is True  # no sidecar: the real-camera (bottom-up) default


@pytest.mark.parametrize("argv, match", [
    (["--center", 30, "--methods", "tfp"], "needs --gt IMAGE and --center"),
    (["--gt", "GT", "--center", 59], "needs steps 39..79"),
    (["--gt", "SMALL", "--center", 30], "--gt is 20 x 40 but the stream is read as 30 x 40"),
    (["--gt", "GT", "--center", 30, "--methods", "tfp:82"], "odd number of 41-step windows"),
    (["--gt", "GT", "--center", 30, "--methods", "nothing.pt"], "expected one of"),
])
def test_bad_pairs_get_one_line(tmp_path, capsys, argv, match) -> None:
    dat, gt = _pair(tmp_path, 0.3)
    np.save(tmp_path / "small.npy", np.zeros((20, W), np.float32))
    argv = [{"GT": gt, "SMALL": tmp_path / "small.npy"}.get(a, a) if isinstance(a, str) else a for a in argv]
    rc, err = run_cli(["evaluate", "--dat", dat, *argv], capsys)
    assert rc == 2 and match in one_line(err)


def test_gt_without_dat_is_refused(tmp_path, capsys) -> None:
    rc, err = run_cli(["evaluate", "--data", tmp_path, "--gt", __file__, "--center", 3], capsys)
    assert rc == 2 and "--gt and --center go with --dat" in one_line(err)


def test_span_tfp_sees_the_windows_around_the_centre(tmp_path, capsys) -> None:
    """The pair's stream is cut into every whole window around the centre one, so TFP over 3
    windows averages 123 steps: in low light on a still scene it beats the 41-step TFP (aligned),
    and the record says which windows were read."""
    dat, gt = _pair(tmp_path, 0.01, SpikeCamera.realistic())
    doc = _scores(["--dat", dat, "--gt", gt, "--center", 30, "--methods", "tfp", "tfp:123"], capsys)
    assert doc["input"]["windows"] == 1 and doc["input"]["first_step"] == 10  # 61 steps: one whole window
    (tmp_path / "long").mkdir()
    y = np.load(gt)
    cam = dataclasses.replace(SpikeCamera.realistic(), height=H, width=W)
    long_dat = Simulator(cam, backend="numpy", seed=1).run_to_dat([y] * 205, tmp_path / "long" / "s.dat", flip=False)
    doc = _scores(["--dat", long_dat, "--gt", gt, "--center", 102, "--methods", "tfp", "tfp:123"], capsys)
    assert doc["input"]["windows"] == 5 and doc["input"]["first_step"] == 0
    assert doc["methods"]["TFP-123"]["psnr_aligned"] > doc["methods"]["TFP"]["psnr_aligned"] + 2


def test_panel_measures_every_method_on_the_same_pixels(tmp_path, capsys) -> None:
    """`panel` on a still scene in low light: the long average is less noisy than one window (at
    under one spike per window the count's quantisation dominates, and three windows hold three
    times the spikes), and the picture holds one tile per method."""
    from PIL import Image
    y = np.full((64, 64), 0.02, np.float32)
    y[:, 32:] = 0.005  # two flat halves and one edge, in low light (under one spike per window)
    cam = dataclasses.replace(SpikeCamera.realistic(), height=64, width=64)
    dat = Simulator(cam, backend="numpy", seed=2).run_to_dat([y] * 123, tmp_path / "still.dat", flip=False)
    capsys.readouterr()
    rc = main(["panel", str(dat), "--methods", "tfp", "tfp:123", "-o", str(tmp_path / "p.png"), "--json"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    doc = json.loads(out.out)
    noise = {k: v["flat_noise"] for k, v in doc["scores"].items()}
    assert doc["read"]["windows"] == 3 and doc["read"]["frame"] == 1
    assert noise["TFP"] > 1.4 * noise["TFP-123"]
    image = Image.open(tmp_path / "p.png")
    assert image.width > 2 * 64 and image.height > 64
    rc, err = run_cli(["panel", dat, "--frame", 7, "-o", tmp_path / "q.png"], capsys)
    assert rc == 2 and "numbered 0..2" in one_line(err)
    # -o a folder, as the other commands take it: panel.png in it (it used to be "is a directory")
    (tmp_path / "figs").mkdir()
    assert main(["panel", str(dat), "--methods", "tfp", "-o", str(tmp_path / "figs")]) == 0
    assert main(["panel", str(dat), "--methods", "tfp", "-o", str(tmp_path / "new") + "/"]) == 0
    assert Image.open(tmp_path / "figs" / "panel.png").width > 64 and (tmp_path / "new" / "panel.png").is_file()


def test_tables_lead_with_aligned_psnr_and_never_bold_a_floor() -> None:
    from pipelines.evaluate import Score, markdown_table
    # low light: black beats TFP in PSNR (the ground truth is nearly black) but not aligned
    rows = [Score(scene, "tfp", psnr=30.0, ssim=0.5, frames=3, psnr_8bit=30.0, ssim_8bit=0.5, psnr_norm=1.0,
                  ssim_norm=0.1, psnr_aligned=16.0) for scene in ("a_low", "ALL_low", "ALL")]
    rows += [Score(scene, "black", psnr=50.0, ssim=0.9, frames=3, psnr_8bit=50.0, ssim_8bit=0.9, psnr_norm=10.0,
                   ssim_norm=0.2, psnr_aligned=14.0) for scene in ("a_low", "ALL_low", "ALL")]
    rows += [Score(scene, "net", psnr=40.0, ssim=0.8, frames=3, psnr_8bit=40.0, ssim_8bit=0.8, psnr_norm=5.0,
                   ssim_norm=0.3, psnr_aligned=20.0) for scene in ("a_low", "ALL_low", "ALL")]
    text = markdown_table(rows, ["tfp", "black", "net"])
    table = text.split("\n\n")[1].splitlines()
    assert table[0] == "| Metric | tfp | black (floor) | net |"
    assert table[2].startswith("| PSNR aligned |") and "**20.000**" in table[2]
    psnr_row = next(line for line in table if line.startswith("| PSNR |"))
    assert "**40.000**" in psnr_row and "**50.000**" not in psnr_row  # the floor's 50 dB is shown, not bolded
