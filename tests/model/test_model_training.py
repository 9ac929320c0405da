"""Training loop, loss, data sampling and checkpoints, on tiny in-memory scenes."""
from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from model.checkpoint import atomic_torch_save, load_checkpoint, model_from_checkpoint, save_checkpoint
from model.config import ExperimentConfig, ModelConfig, TrainConfig
from model.data import SequenceDataset, sequence_starts, split_scenes
from model.losses import build_loss
from modeltest_fakes import make_scene
from pipelines.train import run_training

TINY_MODEL = ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2)


def tiny_experiment(**train) -> ExperimentConfig:
    base = dict(num_windows=3, crop=16, batch_size=2, epochs=1000, lr=3e-3, lr_milestones=(999,),
                samples_per_epoch=4, val_crop=16, val_max_samples=1, val_every=1000, seed=0)
    base.update(train)
    return ExperimentConfig("test", model=TINY_MODEL, train=TrainConfig(**base))


@pytest.fixture(scope="module")
def scenes():
    return [make_scene(f"s{i}", 16, 20, 7 * 6, brightness=0.3, velocity=0.2, seed=i) for i in range(3)]


def test_l1_sum_over_windows():
    loss = build_loss("l1_sum")
    pred = torch.zeros(2, 3, 4, 4)
    target = torch.zeros(2, 3, 4, 4)
    target[:, 1] = 0.5  # window 1 off by 0.5 everywhere, windows 0 and 2 exact
    assert loss(pred, target).item() == pytest.approx(0.5)
    target[:, 2] = 0.25
    assert loss(pred, target).item() == pytest.approx(0.75)  # summed over windows, not averaged
    # literal 1-norm: (16 * 0.5 + 16 * 0.25) per sample, averaged over the batch of 2
    assert build_loss("l1_sum_pixels")(pred, target).item() == pytest.approx(12.0)
    with pytest.raises(ValueError, match="differ in shape"):
        loss(pred, target[:, :2])
    with pytest.raises(KeyError, match="unknown loss"):
        build_loss("l2")


def test_sequence_starts_need_ground_truth_at_every_centre():
    sc = make_scene("a", 8, 8, 7 * 5, gt_every=1)
    # centres c, c+7, c+14 with c >= 3 and c + 14 + 3 <= 34
    assert sequence_starts(sc, 7, 3) == list(range(3, 18))
    assert sequence_starts(sc, 7, 3, stride=5) == [3, 8, 13]
    every7 = make_scene("b", 8, 8, 7 * 5, gt_every=7)  # gt at 0, 7, 14, 21, 28
    assert sequence_starts(every7, 7, 3) == [7, 14]
    every2 = make_scene("c", 8, 8, 7 * 5, gt_every=2)  # c and c + 7 never both even
    assert sequence_starts(every2, 7, 3) == []


def test_dataset_samples_are_reproducible_and_aligned(scenes):
    ds = SequenceDataset(scenes, 7, 3, crop=8, seed=5, samples_per_epoch=6)
    a, b = ds[2], ds[2]
    assert torch.equal(a["spikes"], b["spikes"]) and (a["y0"], a["x0"]) == (b["y0"], b["x0"])
    assert a["spikes"].shape == (3, 7, 8, 8) and a["gt"].shape == (3, 8, 8)
    sc = next(s for s in scenes if s.name == a["scene"])
    c, y0, x0 = a["first_centre"], a["y0"], a["x0"]
    np.testing.assert_array_equal(a["gt"][1].numpy(), sc.ground_truth(c + 7)[y0:y0 + 8, x0:x0 + 8])
    np.testing.assert_array_equal(a["spikes"][0, 3].numpy(), sc.spikes(c, c + 1)[0, y0:y0 + 8, x0:x0 + 8])
    ds.set_epoch(1)
    assert any(ds[i]["y0"] != a["y0"] or ds[i]["x0"] != a["x0"] or ds[i]["scene"] != a["scene"] for i in range(6))
    with pytest.raises(ValueError, match="larger than scene"):
        SequenceDataset(scenes, 7, 3, crop=64)


def test_validation_crop_is_cut_to_a_smaller_scene(scenes):
    """A dataset of several pixel scales: validation's centre crop is cut to each smaller scene
    (its samples are scored one at a time), where a training crop that does not fit is refused."""
    small = make_scene("small", 6, 10, 7 * 4, seed=3)
    ds = SequenceDataset([*scenes, small], 7, 3, crop=8, random_crop=False)
    shapes = {ds[i]["scene"]: tuple(ds[i]["gt"].shape) for i in range(len(ds))}
    assert shapes["small"] == (3, 6, 8) and all(v == (3, 8, 8) for k, v in shapes.items() if k != "small")
    with pytest.raises(ValueError, match="larger than scene"):
        SequenceDataset([*scenes, small], 7, 3, crop=8, random_crop=True)


def test_split_by_scene(scenes):
    train, val = split_scenes(scenes, 0.34, seed=0)
    assert len(val) == 2 and len(train) == 1 and not {s.name for s in train} & {s.name for s in val}
    train, val = split_scenes(scenes, 0.0, val_names=["s1"])
    assert [s.name for s in val] == ["s1"]
    with pytest.raises(ValueError, match="not in the dataset"):
        split_scenes(scenes, 0.0, val_names=["nope"])


def test_tiny_overfit_loss_falls(scenes, tmp_path):
    exp = tiny_experiment(max_steps=40, samples_per_epoch=2, batch_size=2)
    summary = run_training(exp, scenes[:1], [], tmp_path, device="cpu", progress=False)
    rows = list(csv.DictReader((tmp_path / "train_log.csv").open()))
    losses = [float(r["loss"]) for r in rows]
    assert summary["steps"] == 40 and len(losses) == 40
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5]), losses


def test_resume_of_a_finished_run_trains_nothing(scenes, tmp_path, capsys):
    """`--resume` on a finished run trained one more step ("step 4 of 3", loss nan) and changed
    last.pt; now it says there is nothing to do and leaves every file as it was."""
    run_training(tiny_experiment(max_steps=3), scenes[:2], scenes[2:], tmp_path, device="cpu", progress=False)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    again = run_training(tiny_experiment(max_steps=3), scenes[:2], scenes[2:], tmp_path, device="cpu", resume=True,
                         progress=False)
    assert again["nothing_to_do"] and again["steps"] == 3
    assert "nothing to do" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before


def test_resume_on_other_data_is_refused(scenes, tmp_path):
    """`train --resume --data OTHER` continued on another dataset, and best.pt then compared scores
    of different validation sets; the data's identity is in every checkpoint now."""
    run_training(tiny_experiment(max_steps=2), scenes[:2], scenes[2:], tmp_path, device="cpu", progress=False)
    with pytest.raises(ValueError, match="trained on other data"):
        run_training(tiny_experiment(max_steps=4), scenes[1:], scenes[:1], tmp_path, device="cpu", resume=True,
                     progress=False)
    again = run_training(tiny_experiment(max_steps=4), scenes[:2], scenes[2:], tmp_path, device="cpu", resume=True,
                         progress=False)
    assert again["steps"] == 4


def test_resume_continues_exactly(scenes, tmp_path):
    straight = run_training(tiny_experiment(max_steps=4), scenes[:2], scenes[2:], tmp_path / "a",
                            device="cpu", progress=False)
    run_training(tiny_experiment(max_steps=2), scenes[:2], scenes[2:], tmp_path / "b", device="cpu", progress=False)
    resumed = run_training(tiny_experiment(max_steps=4), scenes[:2], scenes[2:], tmp_path / "b", device="cpu",
                           resume=True, progress=False)
    assert straight["steps"] == resumed["steps"] == 4
    a = load_checkpoint(tmp_path / "a" / "last.pt")["model_state"]
    b = load_checkpoint(tmp_path / "b" / "last.pt")["model_state"]
    for k in a:  # bit for bit: a run cut anywhere and resumed is the run that was not cut
        assert torch.equal(a[k], b[k]), k
    losses = [[r["loss"] for r in csv.DictReader((tmp_path / x / "train_log.csv").open())] for x in "ab"]
    assert losses[0] == losses[1] and len(losses[0]) == 4
    assert (tmp_path / "b" / "best.pt").exists() and (tmp_path / "b" / "val_log.csv").exists()
    with pytest.raises(FileExistsError, match="--resume"):
        run_training(tiny_experiment(max_steps=4), scenes[:2], [], tmp_path / "a", device="cpu", progress=False)
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        run_training(tiny_experiment(), scenes[:2], [], tmp_path / "empty", device="cpu", resume=True)


def test_checkpoint_round_trip(tmp_path):
    exp = tiny_experiment()
    from model.arch import build_model
    torch.manual_seed(3)
    model = build_model(exp.model).eval()
    opt = torch.optim.Adam(model.parameters())
    path = tmp_path / "ck" / "model.pt"
    save_checkpoint(path, model, exp, opt, epoch=7, step=70)
    again, exp2 = model_from_checkpoint(path)
    assert exp2 == exp
    s = torch.rand(1, 2, 7, 8, 8) < 0.3
    with torch.no_grad():
        assert torch.equal(model(s), again.eval()(s))
    state = load_checkpoint(path)
    assert (state["epoch"], state["step"]) == (7, 70)
    assert [p.name for p in path.parent.iterdir()] == ["model.pt"]  # no temp file left behind


def test_atomic_save_keeps_the_old_file_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "x.pt"
    atomic_torch_save({"v": 1}, path)

    def boom(*a, **k):
        raise OSError("disk full")
    monkeypatch.setattr(torch, "save", boom)
    with pytest.raises(OSError, match="disk full"):
        atomic_torch_save({"v": 2}, path)
    monkeypatch.undo()
    assert torch.load(path)["v"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["x.pt"]


def test_foreign_file_is_rejected(tmp_path):
    p = tmp_path / "foreign.pt"
    torch.save({"weights": 1}, p)
    with pytest.raises(ValueError, match="not a checkpoint of this project"):
        load_checkpoint(p)
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")


def test_summary_reports_throughput_and_data_wait(scenes, tmp_path):
    summary = run_training(tiny_experiment(max_steps=3), scenes[:1], [], tmp_path, device="cpu", progress=False)
    assert summary["samples_per_s"] > 0 and 0 <= summary["data_wait_share"] < 1
    rows = list(csv.DictReader((tmp_path / "train_log.csv").open()))
    assert len(rows) == 3 and all(float(r["data_wait_s"]) >= 0 for r in rows)


def test_a_run_cut_between_checkpoints_resumes_bit_for_bit(scenes, tmp_path, monkeypatch):
    """A crash after step 3 with step checkpoints every 2: the resumed run redoes step 3, drops the
    log row the crashed run wrote for it, and ends equal to the run that was never cut."""
    from model import training as training_module

    straight = run_training(tiny_experiment(max_steps=5), scenes[:2], [], tmp_path / "a", device="cpu", progress=False)
    real_step, calls = training_module._train_step, {"n": 0}

    def crash_after_three(*args, **kwargs):
        if calls["n"] == 3:
            raise KeyboardInterrupt  # a kill between checkpoints, after step 3's log row
        calls["n"] += 1
        return real_step(*args, **kwargs)

    monkeypatch.setattr(training_module, "_train_step", crash_after_three)
    with pytest.raises(KeyboardInterrupt):
        run_training(tiny_experiment(max_steps=5, ckpt_every_steps=2), scenes[:2], [], tmp_path / "b",
                     device="cpu", progress=False)
    assert load_checkpoint(tmp_path / "b" / "last.pt")["step"] == 2
    monkeypatch.setattr(training_module, "_train_step", real_step)
    resumed = run_training(tiny_experiment(max_steps=5, ckpt_every_steps=2), scenes[:2], [], tmp_path / "b",
                           device="cpu", resume=True, progress=False)
    assert resumed["weights_sha256"] == straight["weights_sha256"]
    losses = [[r["loss"] for r in csv.DictReader((tmp_path / x / "train_log.csv").open())] for x in "ab"]
    assert losses[0] == losses[1] and len(losses[0]) == 5


def test_sigterm_finishes_the_step_and_writes_last(scenes, tmp_path, monkeypatch):
    import os
    import signal

    from model import training as training_module
    real_step, calls = training_module._train_step, {"n": 0}

    def terminated_during_step_two(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            os.kill(os.getpid(), signal.SIGTERM)
        return real_step(*args, **kwargs)

    monkeypatch.setattr(training_module, "_train_step", terminated_during_step_two)
    summary = run_training(tiny_experiment(max_steps=50), scenes[:2], [], tmp_path, device="cpu", progress=False)
    assert summary["stopped_by"] == "SIGTERM" and summary["steps"] == 2
    assert load_checkpoint(tmp_path / "last.pt")["step"] == 2
    assert signal.getsignal(signal.SIGTERM) is not None  # the handler was put back


def test_one_scene_is_split_in_time_with_no_shared_step():
    from model.data import TimeSlice, split_by_time
    scene = make_scene("one", 16, 20, 7 * 12, seed=5)
    train, val = split_scenes([scene], 0.25, window=7, num_windows=3)
    (tr,), (va,) = train, val
    assert isinstance(tr, TimeSlice) and isinstance(va, TimeSlice) and tr.stop == va.start
    assert va.num_steps >= 0.25 * scene.num_steps and va.stop == scene.num_steps and tr.start == 0
    # every sample's windows stay on their side of the cut
    for part in (tr, va):
        for c in sequence_starts(part, 7, 3):
            assert c - 3 >= 0 and c + 2 * 7 + 3 <= part.num_steps - 1
    assert sequence_starts(tr, 7, 3) and sequence_starts(va, 7, 3)
    # a slice reads the scene's own steps and ground truth, shifted
    assert np.array_equal(va.spikes(0, 5), scene.spikes(va.start, va.start + 5))
    assert np.array_equal(va.ground_truth(va.gt_steps[0]), scene.ground_truth(va.start + va.gt_steps[0]))
    with pytest.raises(IndexError):
        va.spikes(0, va.num_steps + 1)
    # too short for a sample on each side: no split, and split_scenes gives no validation
    short = make_scene("short", 16, 20, 7 * 4, seed=6)
    assert split_by_time(short, 7, 3, 0.1) is None
    assert split_scenes([short], 0.1, window=7, num_windows=3) == ([short], [])
    # without the window geometry (old callers) a single scene is not split
    assert split_scenes([scene], 0.25) == ([scene], [])


def test_training_on_one_scene_writes_best_pt(tmp_path, capsys):
    scene = make_scene("one", 16, 20, 7 * 12, seed=5)
    train, val = split_scenes([scene], 0.25, window=7, num_windows=3)
    run_training(tiny_experiment(max_steps=4, samples_per_epoch=2), train, val, tmp_path, device="cpu",
                 progress=False)
    err = capsys.readouterr().err
    assert "one scene, split in time" in err and (tmp_path / "best.pt").exists()


def test_validation_cadence_fits_the_run(scenes, tmp_path):
    # val_every=1000 epochs of one step each, in a 20-step run: validated 10 times (min_validations),
    # not only at the end, so best.pt is chosen from the run
    exp = tiny_experiment(max_steps=20, samples_per_epoch=2, batch_size=2, val_every=1000)
    run_training(exp, scenes[:1], scenes[1:2], tmp_path, device="cpu", progress=False)
    rows = list(csv.DictReader((tmp_path / "val_log.csv").open()))
    assert [int(r["step"]) for r in rows] == list(range(2, 21, 2))


def test_init_starts_a_run_from_other_weights_of_the_same_network(scenes, tmp_path, capsys):
    """--init (fine-tuning): the run's first weights are the given checkpoint's, the source is
    recorded in its checkpoints, and a different network or --resume is refused, naming why."""
    from model.checkpoint import state_fingerprint
    from model.training import initial_weights
    exp = tiny_experiment(max_steps=2, samples_per_epoch=2)
    run_training(exp, scenes[:1], [], tmp_path / "a", device="cpu", progress=False)
    source = tmp_path / "a" / "last.pt"
    state, record = initial_weights(str(source), exp)
    assert record["weights_sha256"] == state_fingerprint(load_checkpoint(source)["model_state"])
    # zero steps of training: the weights stay the initial ones, so the run starts exactly there
    summary = run_training(tiny_experiment(max_steps=1, samples_per_epoch=2, lr=1e-12), scenes[:1], [],
                           tmp_path / "b", device="cpu", progress=False, init=str(source))
    assert "starting from the weights of" in capsys.readouterr().err and summary["steps"] == 1
    after = load_checkpoint(tmp_path / "b" / "last.pt")
    assert after["extra"]["init_weights"]["weights_sha256"] == record["weights_sha256"]
    assert all(torch.allclose(after["model_state"][k], v, atol=1e-6) for k, v in state.items())
    other = ExperimentConfig("test", model=ModelConfig(window=7, num_features=12, num_blocks=1, deform_groups=2),
                             train=exp.train)
    with pytest.raises(ValueError, match="num_features 8 -> 12"):
        run_training(other, scenes[:1], [], tmp_path / "c", device="cpu", progress=False, init=str(source))
    with pytest.raises(ValueError, match="--resume continues"):
        run_training(exp, scenes[:1], [], tmp_path / "a", device="cpu", progress=False, init=str(source), resume=True)


def test_a_huge_epoch_is_not_held_in_memory(scenes, tmp_path):
    """`--samples-per-epoch 1000000000` was killed for memory (its permutation as a list); above
    SHUFFLE_LIMIT the order is a range and batches are made as used."""
    import tracemalloc

    from model.training import SHUFFLE_LIMIT, _epoch_order

    assert isinstance(_epoch_order(10 ** 9, 0, 0), range)
    assert sorted(_epoch_order(100, 0, 0)) == list(range(100)) and _epoch_order(100, 0, 0) != list(range(100))
    assert SHUFFLE_LIMIT >= 1 << 20  # every run made before keeps its shuffled order
    tracemalloc.start()
    summary = run_training(tiny_experiment(max_steps=2, samples_per_epoch=10 ** 9), scenes[:2], [], tmp_path,
                           device="cpu", progress=False)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert summary["steps"] == 2 and peak < 200 * 2 ** 20


def test_resume_on_the_same_scenes_in_another_order_says_so(scenes, tmp_path):
    """Refused (the samples follow the order), but it said "other content (regenerated in place?)"."""
    run_training(tiny_experiment(max_steps=2), scenes[:2], scenes[2:], tmp_path, device="cpu", progress=False)
    with pytest.raises(ValueError, match="the same scenes in another order"):
        run_training(tiny_experiment(max_steps=4), scenes[1::-1], scenes[2:], tmp_path, device="cpu", resume=True,
                     progress=False)
