"""`spikesim compare`: configs trained with >= 3 seeds for equal steps, evaluated on one test set,
reported as mean +- std over seeds, with differences called only beyond the spread."""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent / "model"))  # modeltest_fakes

from modeltest_fakes import make_scene  # noqa: E402
from pipelines import compare as cmp  # noqa: E402
from pipelines.cli import main  # noqa: E402


@pytest.fixture(autouse=True)
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def test_seed_statistics_and_the_spread_rule():
    s = cmp.seed_stat("E", "ALL", "psnr", [30.0, 31.0, 32.0])
    assert s.mean == 31.0 and s.std == pytest.approx(1.0) and s.n == 3  # sample std (ddof 1)
    near = cmp.seed_stat("D", "ALL", "psnr", [31.5, 32.0, 32.5])      # 0.5 apart, spreads 1 + 0.5
    far = cmp.seed_stat("A", "ALL", "psnr", [27.0, 27.5, 28.0])       # 3.5 apart
    assert not cmp.difference_holds(s, near) and cmp.difference_holds(s, far)
    assert cmp.seed_stat("TFP", "ALL", "psnr", [25.0]).std == 0.0
    assert not cmp.difference_holds(s, cmp.seed_stat("X", "ALL", "psnr", [float("inf")] * 3))


def _write_dataset(root: Path, names: list[str], seed0: int) -> None:
    from spikesim.dataset import write_scene
    from spikesim.stream import SpikeStream
    for i, name in enumerate(names):
        light = 0.05 if name.endswith("_low") else 0.3
        sc = make_scene(name, 12, 16, 7 * 4, brightness=light, velocity=0.2, seed=seed0 + i)
        write_scene(root, name, SpikeStream.from_bool(sc.spike_array), {n: sc.gt[n] for n in (3, 10, 17, 24)}, meta={})


def _config(path: Path, name: str, **model) -> Path:
    path.write_text(json.dumps({"name": name, "model": {"window": 7, "num_features": 8, "num_blocks": 1,
                                                         "deform_groups": 2, **model},
                                "train": {"num_windows": 3, "crop": 8, "batch_size": 2, "epochs": 100, "lr": 3e-3,
                                          "lr_milestones": [99], "samples_per_epoch": 2, "val_every": 100}}))
    return path


def test_compare_end_to_end(tmp_path, capsys):
    _write_dataset(tmp_path / "train", ["a_normal", "b_low"], 0)
    _write_dataset(tmp_path / "test", ["c_low", "c_normal"], 10)
    e = _config(tmp_path / "e.json", "e")
    a = _config(tmp_path / "a.json", "a", representation="spike", adf=False, aif=False)
    out = tmp_path / "cmp"
    argv = ["compare", "--data", str(tmp_path / "train"), "--test-data", str(tmp_path / "test"),
            "--configs", f"E={e}", f"A={a}", "--seeds", "0", "1", "2", "--max-steps", "2", "--device", "cpu",
            "--quiet", "--out", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    # equal steps for every run
    from model.checkpoint import load_checkpoint
    steps = {(lab, s): int(load_checkpoint(out / "runs" / lab / f"seed{s}" / "last.pt")["step"])
             for lab in ("E", "A") for s in (0, 1, 2)}
    assert set(steps.values()) == {2}
    stats = {(r["label"], r["group"], r["metric"]): r for r in csv.DictReader((out / "compare.csv").open())}
    e_all = stats[("E", "ALL", "psnr")]
    values = [float(v) for v in e_all["values"].split()]
    assert e_all["seeds"] == "3" and len(set(values)) == 3  # seeds differ
    assert float(e_all["mean"]) == pytest.approx(np.mean(values), abs=1e-5)
    assert float(e_all["std"]) == pytest.approx(np.std(values, ddof=1), abs=1e-5)
    assert stats[("TFP", "ALL_low", "psnr_8bit")]["seeds"] == "1"
    # the per-run scores behind them are evaluate's
    rows = {(r["scene"], r["method"]): r for r in csv.DictReader((out / "metrics.csv").open())}
    assert float(rows[("ALL", "E#1")]["psnr"]) == pytest.approx(values[1], abs=1e-5)
    # tables: low, normal, then all; mean ± std; every pair's differences with the spread rule
    assert text.index("**Low light**") < text.index("**Normal light**") < text.index("**All scenes**")
    assert " ± " in text and "| Groups | Metric | E - A |" in text
    assert ("within spread" in text) or ("**" in text.split("| Groups |")[1])
    # a second run keeps the finished runs
    before = (out / "runs" / "E" / "seed0" / "last.pt").stat().st_mtime_ns
    assert main(argv) == 0
    assert (out / "runs" / "E" / "seed0" / "last.pt").stat().st_mtime_ns == before


def test_compare_training_data_with_one_config_and_init(tmp_path, capsys):
    """Several labelled datasets and one config: one run per dataset and seed, labelled by the data;
    --init starts each from the same weights (recorded in the checkpoint)."""
    _write_dataset(tmp_path / "one", ["a_normal", "b_low"], 0)
    _write_dataset(tmp_path / "two", ["d_normal", "e_low"], 5)
    _write_dataset(tmp_path / "test", ["c_low", "c_normal"], 10)
    e = _config(tmp_path / "e.json", "e")
    base = tmp_path / "base"
    assert main(["train", "--config", str(e), "--data", str(tmp_path / "one"), "--val-data", str(tmp_path / "test"),
                 "--max-steps", "1", "--device", "cpu", "--quiet", "-o", str(base)]) == 0
    out = tmp_path / "cmp"
    assert main(["compare", "--data", f"ONE={tmp_path / 'one'}", f"TWO={tmp_path / 'two'}", "--test-data",
                 str(tmp_path / "test"), "--configs", str(e), "--init", str(base / "last.pt"), "--seeds", "0", "1", "2",
                 "--max-steps", "2", "--device", "cpu", "--quiet", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    from model.checkpoint import load_checkpoint
    for label in ("ONE", "TWO"):
        state = load_checkpoint(out / "runs" / label / "seed1" / "last.pt")
        assert int(state["step"]) == 2 and state["extra"].get("init_weights")
    assert "| Groups | Metric | ONE - TWO |" in text
    meta = json.loads((out / "compare.json").read_text())
    assert set(meta["data"]) == {"ONE", "TWO"} and meta["init"] == str(base / "last.pt")
    assert main(["compare", "--data", f"ONE={tmp_path / 'one'}", f"TWO={tmp_path / 'two'}", "--test-data",
                 str(tmp_path / "test"), "--configs", str(e), "tiny", "--max-steps", "1", "--device", "cpu",
                 "--out", str(tmp_path / "o2")]) == 2
    assert "give one config" in capsys.readouterr().err
    # one labelled dataset: its runs take the data's label (two processes can share --out by data)
    assert main(["compare", "--data", f"TWO={tmp_path / 'two'}", "--test-data", str(tmp_path / "test"), "--configs",
                 str(e), "--init", str(base / "last.pt"), "--seeds", "0", "1", "2", "--max-steps", "2", "--device",
                 "cpu", "--quiet", "--out", str(out)]) == 0
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["ONE", "TWO"]
    # the same without --init asks for other runs than those kept: refused, not scored as if they were
    assert main(["compare", "--data", f"TWO={tmp_path / 'two'}", "--test-data", str(tmp_path / "test"), "--configs",
                 str(e), "--seeds", "0", "1", "2", "--max-steps", "2", "--device", "cpu", "--quiet", "--out",
                 str(out)]) == 2
    assert "other starting weights" in capsys.readouterr().err


@pytest.mark.parametrize("flags,msg", [
    (["--seeds", "0", "1"], "at least 3"),
    (["--seeds", "0", "0", "1"], "at least 3"),
    (["--configs", "TFP=tiny"], "baseline"),
    (["--configs", "x=tiny", "x=tiny_ablation_a"], "unique"),
])
def test_compare_refuses_comparisons_that_would_not_hold(tmp_path, capsys, flags, msg):
    _write_dataset(tmp_path / "d", ["a_low"], 0)
    base = {"--configs": ["tiny", "tiny_ablation_a"], "--seeds": ["0", "1", "2"]}
    for i in range(0, len(flags)):
        if flags[i].startswith("--"):
            vals = []
            for f in flags[i + 1:]:
                if f.startswith("--"):
                    break
                vals.append(f)
            base[flags[i]] = vals
    argv = ["compare", "--data", str(tmp_path / "d"), "--test-data", str(tmp_path / "d"), "--max-steps", "1",
            "--device", "cpu", "--out", str(tmp_path / "o")]
    for k, v in base.items():
        argv += [k, *v]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err and not (tmp_path / "o" / "runs").exists()


def test_compare_names_an_unknown_config_in_the_parser(tmp_path, capsys):
    assert main(["compare", "--data", "d", "--test-data", "d", "--max-steps", "1", "--out", str(tmp_path / "o"),
                 "--configs", "nope"]) == 2
    assert "argument --configs" in capsys.readouterr().err


def test_compare_checks_every_config_before_training_any(tmp_path, capsys):
    _write_dataset(tmp_path / "d", ["a_low"], 0)  # 4 windows of 7 steps: too short for K = 21
    e = _config(tmp_path / "e.json", "e")
    long = json.loads(e.read_text())
    long["name"], long["train"]["num_windows"] = "long", 21
    (tmp_path / "long.json").write_text(json.dumps(long))
    assert main(["compare", "--data", str(tmp_path / "d"), "--test-data", str(tmp_path / "d"), "--max-steps", "1",
                 "--device", "cpu", "--out", str(tmp_path / "o"), "--configs", f"E={e}", str(tmp_path / "long.json")]) == 2
    err = capsys.readouterr().err
    assert "--configs long: no scene has 21 consecutive windows" in err and not (tmp_path / "o" / "runs").exists()


def test_a_baseline_is_a_seedless_method_spec():
    import argparse

    from pipelines.compare import baseline_label, baseline_spec
    assert baseline_spec("tfp:205") == "tfp:205" and baseline_label("tfp:205") == "TFP-205"
    for bad, why in (("lrrep", "a baseline is"), ("x=tfp", "a baseline is"), ("tfp:1_2", "digits"),
                     ("runs/best.pt", "a baseline is")):
        with pytest.raises(argparse.ArgumentTypeError, match=why):
            baseline_spec(bad)
    # the span is checked against the configs' window once they are read, before any run trains
    assert baseline_spec("tfp:82") == "tfp:82" and baseline_label("tfp:21", 7) == "TFP-21"
    with pytest.raises(ValueError, match="odd number"):
        baseline_label("tfp:82", 41)


def test_a_second_compare_into_a_folder_in_use_is_refused_before_training(tmp_path, capsys):
    """Two compares into one folder would train the same runs and write each other's tables."""
    from spikesim.generation.lock import output_lock
    _write_dataset(tmp_path / "d", ["a_low", "b_normal"], 0)
    _write_dataset(tmp_path / "t", ["c_low"], 1)
    e = _config(tmp_path / "e.json", "e")
    out = tmp_path / "o"
    out.mkdir()
    with output_lock(out, "compare other (pid 4242)", what="compare run"):
        assert main(["compare", "--data", str(tmp_path / "d"), "--test-data", str(tmp_path / "t"), "--max-steps", "1",
                     "--device", "cpu", "--quiet", "--out", str(out), "--configs", f"E={e}", "--seeds", "0", "1",
                     "2"]) == 2
    err = capsys.readouterr().err
    assert "another compare run" in err and "4242" in err and not (out / "runs").exists()


@pytest.mark.parametrize("spec, says", [("=d", "not blank"), ("   =d", "not blank"), ("a" * 300 + "=d", "at most 64"),
                                        ("x=", "no ROOT")])
def test_compare_data_labels_are_checked_in_the_parser(spec, says, tmp_path, capsys):
    """Blank and 300-character labels were accepted (the long one left an empty runs/); LABEL=ROOT
    splits at the first "=", as evaluate's LABEL=SPEC does."""
    assert main(["compare", "--data", spec, "--test-data", "d", "--max-steps", "1", "--out", str(tmp_path / "o"),
                 "--configs", "lrrep_finetune"]) == 2
    assert says in capsys.readouterr().err and not (tmp_path / "o").exists()
    assert cmp.data_spec("x=y=z") == ("x", Path("y=z"))


def test_compare_and_train_refuse_to_score_training_scenes_as_held_out(tmp_path, capsys):
    """compare --test-data D --data D and train --val-data D --data D ran, rc 0, and reported
    training-set scores as test and validation scores (round six)."""
    _write_dataset(tmp_path / "d", ["a_low", "b_normal"], 0)
    e = _config(tmp_path / "e.json", "e")
    assert main(["compare", "--data", str(tmp_path / "d"), "--test-data", str(tmp_path / "d"), "--max-steps", "1",
                 "--device", "cpu", "--quiet", "--out", str(tmp_path / "o"), "--configs", f"E={e}"]) == 2
    err = capsys.readouterr().err
    assert "--test-data: 2 scene(s) are also in --data" in err and not (tmp_path / "o").exists()
    assert main(["train", "--config", str(e), "--data", str(tmp_path / "d"), "--val-data", str(tmp_path / "d"),
                 "--max-steps", "1", "--device", "cpu", "--out", str(tmp_path / "r")]) == 2
    assert "--val-data: 2 scene(s) are also in --data" in capsys.readouterr().err


def test_a_copy_of_the_training_set_is_no_held_out_data(tmp_path, capsys):
    """`cp -r d copy; train --data d --val-data copy` reported training scores as validation (round seven)."""
    import shutil
    _write_dataset(tmp_path / "d", ["a_low", "b_normal"], 0)
    shutil.copytree(tmp_path / "d", tmp_path / "copy")
    e = _config(tmp_path / "e.json", "e")
    assert main(["train", "--config", str(e), "--data", str(tmp_path / "d"), "--val-data", str(tmp_path / "copy"),
                 "--max-steps", "1", "--device", "cpu", "--out", str(tmp_path / "r")]) == 2
    assert "--val-data: 2 scene(s) are also in --data" in capsys.readouterr().err


def test_run_training_refuses_training_scenes_as_validation_and_keeps_time_splits(tmp_path):
    """The Python API took run_training(exp, scenes, scenes) and chose best.pt by training-set scores
    (round seven, left low); one scene split in time (split_by_time) still trains."""
    from model.config import load_config
    from model.data import open_scenes, shared_scenes, split_by_time
    from model.training import run_training
    _write_dataset(tmp_path / "d", ["a_low", "b_normal"], 0)
    scenes = open_scenes(tmp_path / "d")
    exp = load_config(str(_config(tmp_path / "e.json", "e")))
    with pytest.raises(ValueError, match="validation scenes: 1 are also training scenes"):
        run_training(exp, scenes, scenes[1:], tmp_path / "r", "cpu", progress=False)
    assert not (tmp_path / "r").exists()
    parts = split_by_time(scenes[0], exp.model.window, 1, 0.5)
    assert parts is not None and shared_scenes([parts[0]], [parts[1]]) == []
    assert shared_scenes([parts[0]], [scenes[0]]) == [parts[0].name]
