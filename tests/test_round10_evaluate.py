"""Round ten's defects of `evaluate`: a Spike-Zoo export scored in part, a checkpoint scored on the
scenes it trained on without a word, and a negative ground truth given as an array."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

pytest.importorskip("OpenEXR", reason="the dataset layout stores ground truth as EXR")

from cli_testing import one_line, run_cli
from pipelines.cli import main
from spikesim.dataset import write_manifest, write_scene
from spikesim.stream import SpikeStream


def _dataset(root, steps: int, gt_every: int, first: int):
    """Two 16 x 24 scenes (low and normal light) of a sliding gradient, noiseless spikes."""
    for i, (name, level) in enumerate((("tex_low", 0.02), ("tex_normal", 0.3))):
        xs = np.linspace(0.2, 1.8, 24, dtype=np.float32)
        y = np.stack([level * np.roll(np.tile(xs, (16, 1)), t // 10, axis=1) for t in range(steps)])
        acc = np.random.default_rng(i).uniform(0, 1, (16, 24)) + np.cumsum(y.astype(np.float64), axis=0)
        spikes = np.diff(np.floor(np.concatenate([acc[:1] - y[:1], acc])), axis=0) > 0
        write_scene(root, name, SpikeStream.from_bool(spikes), {n: y[n] for n in range(first, steps, gt_every)},
                    meta={})
    write_manifest(root, {"kind": "test"})
    return root


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return _dataset(tmp_path_factory.mktemp("r10") / "data", 170, 41, 20)


def test_an_export_missing_pairs_its_record_lists_is_refused_naming_them(data, tmp_path, capsys):
    """With one scene's pairs deleted, `evaluate --spikezoo` scored the 5 left of 10 pairs, rc 0;
    with one pair deleted, 9 of 10 (round ten)."""
    out = tmp_path / "zoo"
    assert run_cli(["export", data, "--format", "spikezoo", "--steps", "41", "-o", out], capsys)[0] == 0
    record = json.loads((out / "spikezoo.json").read_text())["splits"]["test"]["pairs"]
    assert len(record) == 8
    argv = ["evaluate", "--spikezoo", out, "--methods", "tfp", "--window", "41", "--json"]
    assert run_cli(argv, capsys)[0] == 0
    spike, gt = out / "test" / "spike", out / "test" / "gt"
    (spike / "tex_normal_step000061.dat").unlink()
    (gt / "tex_normal_step000061.png").unlink()
    code, err = run_cli(argv, capsys)
    line = one_line(err)
    assert code == 2 and "lists 8 test pairs, but 1 is not in" in line and "tex_normal_step000061" in line, line
    for f in [*spike.glob("tex_normal_*"), *gt.glob("tex_normal_*")]:
        f.unlink()
    code, err = run_cli(argv, capsys)
    line = one_line(err)
    assert code == 2 and "4 are not in" in line and "tex_normal_step000020, tex_normal_step000061" in line, line


def test_a_negative_or_nan_ground_truth_array_is_refused():
    """`evaluate_pair` (the library under `evaluate --dat`) clipped a negative ground truth to 0 and
    scored it (round ten); read_image_y refuses such a file, the array is refused too."""
    from model.evaluation import evaluate_pair
    from model.methods import method_from_spec
    from spikesim.simulate import Simulator
    from spikesim import SpikeCamera
    import dataclasses
    import tempfile
    from pathlib import Path
    cam = dataclasses.replace(SpikeCamera.noiseless(), height=16, width=16)
    y = np.tile(np.linspace(0.05, 0.5, 16, dtype=np.float32), (16, 1))
    with tempfile.TemporaryDirectory() as tmp:
        dat = Simulator(cam, backend="numpy", seed=0).run_to_dat([y] * 61, Path(tmp) / "s.dat", flip=False)
        tfp = [method_from_spec("tfp", 41)]
        assert evaluate_pair(dat, y, 30, tfp, 41)[0][0].frames == 1
        for bad, words in ((y - 0.2, "negative (min -0.15)"), (np.where(y > 0.3, np.nan, y), "NaN or infinite")):
            with pytest.raises(ValueError, match=r"--gt \(the ground truth of .*s\.dat\) has \d+ " + re.escape(words)):
                evaluate_pair(dat, bad.astype(np.float32), 30, tfp, 41)


def test_a_checkpoint_scored_on_scenes_it_trained_on_is_noted(tmp_path, capsys):
    """`evaluate --data D --methods mine=RUN/best.pt` scored the checkpoint on its own training
    scenes without a word, where compare and train refuse that overlap (round ten): a note on
    stderr, in the JSON and in metrics.md, naming the checkpoint and the scenes."""
    from model.arch import build_model
    from model.checkpoint import save_checkpoint
    from model.config import ExperimentConfig, ModelConfig, TrainConfig
    data = _dataset(tmp_path / "d7", 60, 7, 3)
    model = ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2)
    exp = ExperimentConfig("tiny10", model=model, train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=1,
                                                                    lr_milestones=(5,), samples_per_epoch=1,
                                                                    val_fraction=0.0, max_steps=1))
    ckpt = tmp_path / "run" / "best.pt"
    ckpt.parent.mkdir()
    save_checkpoint(ckpt, build_model(model), exp, extra={"data_order": [["tex_low"], ["tex_normal"]]})
    out = tmp_path / "scores"
    capsys.readouterr()
    assert main(["evaluate", "--data", str(data), "--methods", "tfp", f"mine={ckpt}", "--window", "7", "--json",
                 "--threads", "1", "--quiet", "-o", str(out)]) == 0
    got = capsys.readouterr()
    notes = json.loads(got.out)["notes"]
    assert len(notes) == 2 and "mine" in notes[0] and str(ckpt) in notes[0] and "trained on 1" in notes[0]
    assert "(tex_low)" in notes[0] and "training fit" in notes[0] and "validated" in notes[1] and "tex_normal" in notes[1]
    assert f"[evaluate] note: mine ({ckpt}) trained on 1 of the scenes scored here (tex_low)" in got.err
    assert "tex_low" in (out / "metrics.md").read_text().split("**Notes**")[1]
    # held-out scenes, or a checkpoint with no record: nothing to note
    assert main(["evaluate", "--data", str(data), "--scenes", "tex_normal", "--methods", "tfp", f"mine={ckpt}",
                 "--window", "7", "--json", "--threads", "1", "--quiet"]) == 0
    assert [n for n in json.loads(capsys.readouterr().out)["notes"] if "trained" in n] == []
    save_checkpoint(ckpt, build_model(model), exp)
    assert main(["evaluate", "--data", str(data), "--methods", f"mine={ckpt}", "--window", "7", "--json",
                 "--threads", "1", "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["notes"] == []


def test_scenes_of_the_same_names_in_another_dataset_are_not_taken_for_training_scenes(tmp_path, capsys):
    """Every RLLR set names its scenes rllr_0000, ...: matched by name, `evaluate` said a network had
    trained on held-out sets' scenes. `train` records each scene's stream sha256 (extra.data_streams),
    and the note matches by it: a same-named scene of another dataset is not noted, a copy of the
    training set elsewhere is."""
    import shutil

    from model.checkpoint import load_checkpoint
    from model.config import ExperimentConfig, ModelConfig, TrainConfig
    from model.data import open_scenes, stream_sha256
    from model.training import run_training
    trained = _dataset(tmp_path / "a", 60, 7, 3)
    other = _dataset(tmp_path / "b", 62, 7, 3)  # the same names, other streams
    model = ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2)
    exp = ExperimentConfig("tiny10", model=model, train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=1,
                                                                    lr_milestones=(5,), samples_per_epoch=1,
                                                                    max_steps=1, val_every=1))
    scenes = open_scenes(trained)
    run_training(exp, scenes[:1], scenes[1:], tmp_path / "run", device="cpu", progress=False)
    ckpt = tmp_path / "run" / "last.pt"
    assert load_checkpoint(ckpt)["extra"]["data_streams"] == [[stream_sha256(scenes[0])], [stream_sha256(scenes[1])]]
    assert stream_sha256(open_scenes(other)[0]) != stream_sha256(scenes[0])

    def notes(root):
        capsys.readouterr()
        assert main(["evaluate", "--data", str(root), "--methods", f"mine={ckpt}", "--window", "7", "--json",
                     "--threads", "1", "--quiet"]) == 0
        return json.loads(capsys.readouterr().out)["notes"]
    assert notes(other) == []
    got = notes(trained)
    assert len(got) == 2 and "trained on 1 of the scenes scored here (tex_low): the same spike streams" in got[0]
    assert "validated" in got[1] and "(tex_normal)" in got[1]
    shutil.copytree(trained, tmp_path / "copy")  # the training set copied elsewhere: still its streams
    assert [n.split(": ")[1][:24] for n in notes(tmp_path / "copy")] == ["the same spike streams ("] * 2
