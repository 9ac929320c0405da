"""`spikesim export --format spikezoo` writes Spike-Zoo's layout, and `evaluate --spikezoo` reads it
back: a round trip scores every frame as the original dataset does (up to the 8-bit PNG's
quantisation), an independent reader written here from Spike-Zoo's conventions sees the same
spikes, and bad input is refused in one line."""
from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

pytest.importorskip("OpenEXR", reason="the dataset layout stores ground truth as EXR")

from cli_testing import one_line, run_cli
from pipelines.cli import main
from spikesim.dataset import open_dataset, write_manifest, write_scene
from spikesim.stream import SpikeStream

WINDOW = 41


# ---- data --------------------------------------------------------------------------------------
def _integrate_and_fire(y: np.ndarray, seed: int) -> np.ndarray:
    """A noiseless sensor: A += y each step, a spike per integer crossed, random initial A."""
    a0 = np.random.default_rng(seed).uniform(0, 1, size=y.shape[1:])
    acc = a0[None] + np.cumsum(y.astype(np.float64), axis=0)
    prev = np.concatenate([a0[None], acc[:-1]], axis=0)
    return np.floor(acc) > np.floor(prev)


def _texture(height: int, width: int, steps: int, mean_y: float, seed: int) -> np.ndarray:
    """y (N, H, W): a smooth random texture sliding sideways at 0.05 px/step, mean about `mean_y`."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    t = np.arange(steps, dtype=np.float64)[:, None, None]
    img = sum(np.sin(rng.uniform(0.1, 0.5) * (xs[None] - 0.05 * t) + rng.uniform(0.1, 0.5) * ys[None]
                     + rng.uniform(0, 2 * np.pi)) for _ in range(4))
    return (mean_y * (1.0 + 0.45 * img / 4.0)).astype(np.float32)


@pytest.fixture(scope="module")
def texture_data(tmp_path_factory):
    """Two 16 x 24 scenes of 420 steps, a low-light one (mean y 0.01) and a normal one (0.3), ground
    truth every 41 steps from step 20: a 301-step window fits around steps 184, 225 and 266 only."""
    root = tmp_path_factory.mktemp("texture") / "data"
    for i, (name, mean_y, lux) in enumerate((("tex_low", 0.01, 10.0), ("tex_normal", 0.3, 200.0))):
        y = _texture(16, 24, 420, mean_y, seed=i)
        spikes = _integrate_and_fire(y, seed=10 + i)
        write_scene(root, name, SpikeStream.from_bool(spikes), {n: y[n] for n in range(20, 420, WINDOW)},
                    meta={"subject_illuminance_lux": lux,
                          **({"camera": {"readout_period_s": 5e-5}} if name == "tex_normal" else {})})
    write_manifest(root, {"kind": "test"})
    return root


@pytest.fixture(scope="module")
def llr_data(tmp_path_factory):
    """A small LLR dataset (ball, low and normal light, 16 x 24, 3 windows: 123 steps, ground truth
    at steps 20, 61, 102), rendered and simulated as `generate` makes one (about 20 s on 2 busy cores)."""
    root = tmp_path_factory.mktemp("llr") / "llr"
    assert main(["generate", "llr", "--preset", "small", "--scenes", "ball", "--windows", "3", "--height", "16",
                 "--width", "24", "--quality", "fast", "--workers", "1", "--quiet", "-o", str(root)]) == 0
    return root


def _export(capsys, data, out, *extra) -> str:
    rc, err = run_cli(["export", data, "--format", "spikezoo", "-o", out, *extra], capsys)
    assert rc == 0, err
    return err


# ---- the round trip ----------------------------------------------------------------------------
def _quantisation_tolerance_db(pred: np.ndarray, gt: np.ndarray, rate: float) -> float:
    """How far the 8-bit PNG may move a frame's aligned PSNR. Rounding to a level q = rate / 255
    moves each ground-truth pixel by at most e = q / 2: the light level L (the 99.5th percentile)
    by at most e, 20 log10((L + e) / (L - e)) dB at worst; and it adds noise of power q^2 / 12,
    uncorrelated with the fit's residual r (rms), to the MSE: 10 log10(1 + q^2 / (12 r^2)) dB.
    The tolerance is twice their sum (a 16 x 24 image's rounding noise is not quite uncorrelated)."""
    from model.metrics import aligned_prediction, light_level
    p, t = np.clip(pred.astype(np.float64), 0, 1), np.clip(gt.astype(np.float64), 0, 1)
    level, residual = light_level(t), float(np.sqrt(np.mean((t - aligned_prediction(p, t)) ** 2)))
    q = rate / 255.0
    return 2 * (20 * math.log10((level + q / 2) / (level - q / 2)) + 10 * math.log10(1 + q * q / (12 * residual ** 2)))


def _original_scores(data, steps: int) -> dict[str, tuple[float, float, float]]:
    """Per exported frame: TFP's aligned PSNR on the original dataset as `evaluate --dat --gt`
    scores it, the same against the ground truth rounded to the PNG's levels, and the tolerance."""
    from model.evaluation import evaluate_pair
    from model.methods import method_from_spec
    from spikesim.spikezoo import png_levels, scene_rate
    tfp = [method_from_spec("tfp", WINDOW)]
    out = {}
    for sc in open_dataset(data):
        fits = [g for g in sc.gt_steps if g - steps // 2 >= 0 and g - steps // 2 + steps <= sc.num_steps]
        rate = scene_rate(max(float(sc.ground_truth(g).max()) for g in fits))
        for g in fits:
            gt = sc.ground_truth(g)
            rounded = png_levels(gt, rate).astype(np.float32) / np.float32(255) * np.float32(rate)
            scores = [evaluate_pair(sc.path / "spikes.dat", y, g, tfp, WINDOW, sc.height, sc.width, 0, True)[0][0].psnr_aligned
                      for y in (gt, rounded)]
            pred = sc.spikes(g - WINDOW // 2, g + WINDOW - WINDOW // 2).mean(axis=0)
            out[f"{sc.name}_step{g:06d}"] = (*scores, _quantisation_tolerance_db(pred, gt, rate))
    return out


def _stdout(capsys, argv) -> tuple[int, str]:
    """Exit status and stdout of one in-process run."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr().out


def _scored_back(capsys, out, tmp_path) -> dict[str, float]:
    rc, text = _stdout(capsys, ["evaluate", "--spikezoo", out, "--methods", "tfp", "--json", "--threads", "1",
                                "-o", tmp_path / "scores"])
    assert rc == 0, text
    doc = json.loads(text)
    assert (tmp_path / "scores" / "metrics.csv").is_file()
    return {name: row["TFP"]["psnr_aligned"] for name, row in doc["scenes"].items()}


@pytest.mark.parametrize("which", ["llr", "texture"])
def test_round_trip_scores_every_frame_as_the_original_to_within_8_bit_quantisation(which, request, capsys, tmp_path):
    data = request.getfixturevalue(f"{which}_data")
    steps = 41 if which == "llr" else 301  # the LLR streams are 123 steps: no 301-step window fits
    out = tmp_path / "zoo"
    _export(capsys, data, out, *(["--steps", str(steps)] if steps != 301 else []))
    original, back = _original_scores(data, steps), _scored_back(capsys, out, tmp_path)
    assert sorted(back) == sorted(original) and len(back) == 6
    for name, (psnr, psnr_rounded, tolerance) in original.items():
        # the layout changes nothing but the ground truth's rounding: same spikes, key step and rate
        assert back[name] == pytest.approx(psnr_rounded, abs=1e-6), name
        assert abs(back[name] - psnr) <= tolerance < 0.1, (name, back[name], psnr, tolerance)  # the goal: 0.1 dB


def test_the_default_window_is_spike_zoos_301_steps_around_the_middle_one(texture_data, capsys, tmp_path):
    out = tmp_path / "zoo"
    err = _export(capsys, texture_data, out)
    assert "tex_low: skipped ground-truth step(s) 20, 61, 102, 143, 307, 348, 389" in " ".join(err.split())
    record = json.loads((out / "spikezoo.json").read_text())
    split = record["splits"]["test"]
    assert (record["height"], record["width"], split["steps"], split["key_index"]) == (16, 24, 301, 150)
    assert split["complete"] and split["pairs"]["tex_low_step000184"]["first_step"] == 184 - 150
    assert sorted(p.name for p in (out / "test" / "spike").iterdir()) == [
        f"{s}_step{g:06d}.dat" for s in ("tex_low", "tex_normal") for g in (184, 225, 266)]
    assert not (out / "train").exists() and (out / "README.md").is_file()


def test_gt_stride_keeps_the_exported_ground_truth_steps_apart(texture_data, capsys, tmp_path):
    # an RLLR scene has ground truth at every step: --gt-stride thins the pairs (here every other one)
    out = tmp_path / "zoo"
    _export(capsys, texture_data, out, "--steps", "41", "--gt-stride", "82")
    pairs = json.loads((out / "spikezoo.json").read_text())["splits"]["test"]["pairs"]
    assert sorted(p["gt_step"] for p in pairs.values() if p["scene"] == "tex_low") == [20, 102, 184, 266, 348]


def test_a_rate_per_scene_keeps_low_light_off_black(texture_data, capsys, tmp_path):
    from PIL import Image
    out = tmp_path / "zoo"
    _export(capsys, texture_data, out)
    scenes = json.loads((out / "spikezoo.json").read_text())["splits"]["test"]["scenes"]
    assert scenes["tex_low"]["rate"] < 0.05 < scenes["tex_normal"]["rate"]
    for sc in open_dataset(texture_data):
        rate = scenes[sc.name]["rate"]
        png = np.asarray(Image.open(out / "test" / "gt" / f"{sc.name}_step000184.png"))
        assert png.dtype == np.uint8 and png.ndim == 2
        y = sc.ground_truth(184)
        assert np.array_equal(png, np.round(255 * np.clip(y.astype(np.float64) / rate, 0, 1)).astype(np.uint8))
        assert png.max() >= 250 and len(np.unique(png)) > 50  # the low-light scene spans the 8 bits too
    readme = (out / "README.md").read_text()
    assert f"| tex_low | 3 | {scenes['tex_low']['rate']:g} |" in readme and "MIT" in readme and "| 10 |" in readme
    # the stream's timing where the scene records its camera (a 20 kHz one here; round sixteen)
    assert scenes["tex_normal"]["readout_period_s"] == 5e-5 and "readout_period_s" not in scenes["tex_low"]
    assert "| 20,000 |" in readme and "readout (Hz)" in readme


# ---- an independent reader ---------------------------------------------------------------------
def _read_like_spike_zoo(path, height: int, width: int) -> np.ndarray:
    """Spike-Zoo's load_vidar_dat, restated: H W / 8 bytes a frame, bit b of byte k is pixel 8k + b
    of the row-major frame, then the rows flipped upside down."""
    raw = np.fromfile(path, dtype=np.uint8)
    per = height * width // 8
    assert raw.size % per == 0
    frames = []
    for f in raw.reshape(-1, per):
        bits = np.stack([(f >> b) & 1 for b in range(8)], axis=1)  # (bytes, 8): pixel 8k + b
        frames.append(np.flipud(bits.reshape(height, width)))
    return np.stack(frames).astype(bool)


def test_an_independent_reader_sees_exactly_the_datasets_spikes(texture_data, capsys, tmp_path):
    out = tmp_path / "zoo"
    _export(capsys, texture_data, out)
    pairs = json.loads((out / "spikezoo.json").read_text())["splits"]["test"]["pairs"]
    by_name = {sc.name: sc for sc in open_dataset(texture_data)}
    for name, info in pairs.items():
        sc = by_name[info["scene"]]
        dat = out / "test" / "spike" / f"{name}.dat"
        assert dat.stat().st_size == 301 * 16 * 24 // 8
        got = _read_like_spike_zoo(dat, 16, 24)
        assert np.array_equal(got, sc.spikes(info["first_step"], info["first_step"] + 301)), name


# ---- theirs read here --------------------------------------------------------------------------
def test_a_spike_zoo_folder_without_a_record_is_read_with_spike_zoos_defaults(shared_data, capsys, tmp_path):
    # Spike-Zoo's own `base` sample, laid out as its repository has it: the key step is the middle
    # of 301 (index 150) and the rate Spike-Zoo's 0.6, so the score is `evaluate --dat` at step 150.
    sample = shared_data / "spk2imgnet-sample"
    root = tmp_path / "base"
    for sub, ext in (("spike", "dat"), ("gt", "png")):
        (root / "test" / sub).mkdir(parents=True)
        shutil.copy(sample / f"203_part1_key_id151.{ext}", root / "test" / sub)
    back = _scored_back(capsys, root, tmp_path)
    rc, text = _stdout(capsys, ["evaluate", "--dat", sample / "203_part1_key_id151.dat", "--gt",
                                sample / "203_part1_key_id151.png", "--center", "150", "--gt-scale", "0.6", "--height",
                                "250", "--width", "400", "--header-columns", "0", "--methods", "tfp", "--json",
                                "--threads", "1"])
    assert rc == 0, text
    assert back["203_part1_key_id151"] == pytest.approx(json.loads(text)["methods"]["TFP"]["psnr_aligned"], abs=1e-9)


# ---- bad input ---------------------------------------------------------------------------------
def _refused(capsys, args) -> str:
    rc, err = run_cli(args, capsys)
    assert rc == 2, err
    return one_line(err)


def test_a_missing_dataset_is_refused_naming_it(capsys, tmp_path):
    line = _refused(capsys, ["export", tmp_path / "nothing", "--format", "spikezoo", "-o", tmp_path / "zoo"])
    assert "nothing" in line and "does not exist" in line
    assert not (tmp_path / "zoo").exists()


def test_an_unknown_format_is_refused_naming_the_flag(texture_data, capsys, tmp_path):
    rc, err = run_cli(["export", texture_data, "--format", "hdf5", "-o", tmp_path / "zoo"], capsys)
    line = err.strip().splitlines()[-1]  # argparse's refusal, after its usage lines
    assert rc == 2 and line.startswith("spikesim export: error:"), err
    assert "--format" in line and "hdf5" in line and "spikezoo" in line
    assert not (tmp_path / "zoo").exists()


def test_a_folder_that_is_not_an_export_is_left_alone(texture_data, capsys, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    line = _refused(capsys, ["export", texture_data, "--format", "spikezoo", "-o", out])
    assert str(out) in line and "not a Spike-Zoo export" in line
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_an_earlier_export_is_replaced_but_a_stray_sample_is_refused(texture_data, capsys, tmp_path):
    out = tmp_path / "zoo"
    _export(capsys, texture_data, out)
    _export(capsys, texture_data, out, "--split", "train", "--steps", "41")  # a second split beside the first
    record = json.loads((out / "spikezoo.json").read_text())
    assert sorted(record["splits"]) == ["test", "train"] and len(record["splits"]["train"]["pairs"]) == 20
    _export(capsys, texture_data, out, "--steps", "381")  # the test split again, now one pair per scene
    assert sorted(p.name for p in (out / "test" / "gt").iterdir()) == ["tex_low_step000225.png", "tex_normal_step000225.png"]
    (out / "test" / "spike" / "other.dat").write_bytes(b"\0" * 48)
    line = _refused(capsys, ["export", texture_data, "--format", "spikezoo", "-o", out])
    assert "other.dat" in line and "would read it" in line


def test_a_window_longer_than_every_stream_is_refused_naming_steps(texture_data, capsys, tmp_path):
    line = _refused(capsys, ["export", texture_data, "--format", "spikezoo", "--steps", "1001", "-o", tmp_path / "zoo"])
    assert "1001-step window" in line and "--steps" in line
    assert not (tmp_path / "zoo").exists()


@pytest.mark.parametrize("rate", ["1e300", "2", "0", "1e-9", "nan"])
def test_a_rate_no_png_can_hold_is_refused(rate, tmp_path, capsys):
    """--rate 1e300 wrote every ground truth as 0, rc 0 (round six): a rate is a y in 1e-6..1."""
    rc, err = run_cli(["export", tmp_path / "none", "--format", "spikezoo", "-o", tmp_path / "o", "--rate", rate], capsys)
    assert rc == 2 and "argument --rate" in err and not (tmp_path / "o").exists()


def test_swapped_or_altered_pairs_of_an_export_are_refused_naming_the_file(texture_data, capsys, tmp_path):
    """Two exported streams swapped were scored against each other's truth, rc 0 (round eight): the
    record keeps each file's sha256 and the reader checks it."""
    out = tmp_path / "zoo"
    _export(capsys, texture_data, out, "--steps", "41", "--gt-stride", "82")
    spikes = out / "test" / "spike"
    a, b = spikes / "tex_low_step000020.dat", spikes / "tex_normal_step000020.dat"
    a_bytes, b_bytes = a.read_bytes(), b.read_bytes()
    a.write_bytes(b_bytes)
    b.write_bytes(a_bytes)
    code, err = run_cli(["evaluate", "--spikezoo", out, "--methods", "tfp", "--json"], capsys)
    assert code == 2 and "tex_low_step000020.dat: not the file the export wrote" in one_line(err)
    a.write_bytes(a_bytes)
    b.write_bytes(b_bytes)
    assert run_cli(["evaluate", "--spikezoo", out, "--methods", "tfp", "--json"], capsys)[0] == 0


def test_a_file_given_as_a_dataset_is_said_to_be_no_folder(capsys, tmp_path):
    """evaluate / train / export --data FILE said the dataset folder does not exist (round eight)."""
    (tmp_path / "flat.dat").write_bytes(b"\0" * 64)
    for argv in (["evaluate", "--data", tmp_path / "flat.dat", "--methods", "tfp", "-o", tmp_path / "e"],
                 ["export", tmp_path / "flat.dat", "--format", "spikezoo", "-o", tmp_path / "x"]):
        code, err = run_cli(argv, capsys)
        assert code == 2 and "flat.dat is not a folder (a dataset is a folder)" in one_line(err), err


def test_outputs_inside_a_dataset_are_refused(texture_data, capsys, tmp_path):
    """train -o and export -o inside a dataset wrote there; verify then reported the set damaged (round eight)."""
    for argv in (["export", texture_data, "--format", "spikezoo", "-o", texture_data / "exp"],
                 ["train", "--config", "tiny", "--data", texture_data, "--max-steps", "1", "-o", texture_data / "run"],
                 ["evaluate", "--data", texture_data, "--methods", "tfp", "-o", texture_data / "tex_low"]):
        code, err = run_cli(argv, capsys)
        assert code == 2 and f"inside the dataset {texture_data}" in one_line(err), err
        assert not (texture_data / "exp").exists() and not (texture_data / "run").exists()
    assert run_cli(["verify", texture_data], capsys)[0] == 0


def test_pairs_shorter_than_the_window_are_scored_with_a_shorter_one(texture_data, capsys, tmp_path):
    """export --steps 40 wrote pairs evaluate --spikezoo refused without saying what would score them
    (round eight)."""
    out = tmp_path / "zoo"
    _export(capsys, texture_data, out, "--steps", "40", "--gt-stride", "82")
    code, err = run_cli(["evaluate", "--spikezoo", out, "--methods", "tfp", "--json"], capsys)
    assert code == 2 and "a shorter --window (odd, at most 39) scores it" in one_line(err)
    assert "its key step 20:" in err and "--center" not in err
    assert run_cli(["evaluate", "--spikezoo", out, "--methods", "tfp", "--window", "39", "--json"], capsys)[0] == 0
