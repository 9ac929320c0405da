"""The paper's comparisons as studies: configs built on a base, the cost of a network counted
(FLOP, parameters), each run's CPU time recorded, runs trained and scored in parallel and kept
between calls, one run serving every label of the same config, and the study table's verdicts."""
from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))

from test_targets_compare import _config, _one_thread, _write_dataset  # noqa: E402,F401  (_one_thread: autouse)

from model.comparison import COMPUTE_FILE, read_compute, seed_stat  # noqa: E402
from model.config import TrainConfig, load_config  # noqa: E402
from model.flops import network_cost  # noqa: E402
from model.studies import STUDIES, get_study, ordering_verdict, study_markdown  # noqa: E402
from pipelines.cli import main  # noqa: E402


# ---- configs on a base ------------------------------------------------------------------------

def test_a_config_on_a_base_takes_its_fields_and_overrides_some(tmp_path):
    (tmp_path / "b.json").write_text(json.dumps({"name": "b", "base": "lrrep_cpu", "model": {"representation": "tfp"},
                                                 "train": {"lr": 0.002}}))
    (tmp_path / "c.json").write_text(json.dumps({"name": "c", "base": "b.json", "model": {"num_blocks": 3}}))
    base, c = load_config("lrrep_cpu"), load_config(tmp_path / "c.json")
    assert c.name == "c" and c.description == ""  # the base's name and description are not inherited
    assert (c.model.representation, c.model.num_blocks, c.train.lr) == ("tfp", 3, 0.002)
    assert dataclasses.replace(c.model, representation=base.model.representation, num_blocks=base.model.num_blocks) == base.model
    assert c.train.crop == base.train.crop and c.train.num_windows == base.train.num_windows


@pytest.mark.parametrize("text, msg", [
    ('{"name": "x", "base": "x.json", "model": {}}', "loops"),
    ('{"name": "x", "base": 3, "model": {}}', "must name a config"),
    ('{"name": "x", "base": "no_such_config", "model": {}}', "x.json: \"base\" 'no_such_config' names no shipped"),
    ('{"name": "x", "base": "y.json", "model": {}}', "x.json: \"base\" 'y.json' is not a file beside it"),
])
def test_a_bad_base_is_refused_with_its_reason(tmp_path, monkeypatch, text, msg):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "x.json").write_text(text)
    (tmp_path / "y.json").write_text('{"name": "y", "model": {"num_features": 8}}')
    monkeypatch.chdir(tmp_path)  # a y.json in the folder the command runs in is not the one beside x.json
    with pytest.raises((ValueError, FileNotFoundError), match=msg):
        load_config(tmp_path / "sub" / "x.json")


def test_every_study_config_that_ships_loads_at_the_shipped_size():
    shipped = load_config("lrrep_cpu")
    for study in STUDIES.values():
        for label, name in study.configs:
            exp = load_config(name)  # every study's config ships: a missing one fails here, not in a night's run
            assert exp.train.num_windows == shipped.train.num_windows and exp.train.crop == shipped.train.crop, label


# ---- cost -------------------------------------------------------------------------------------

def test_flop_count_scales_with_pixels_and_training_costs_about_three_forwards():
    exp = load_config("cpu_ablation_a")  # no deformable sampling: every FLOP is a convolution
    small, big = network_cost(exp, 32, 48), network_cost(exp, 64, 48)
    assert big.flop_per_frame == 2 * small.flop_per_frame  # convolutions: FLOP per output pixel
    assert small.sampling_flop_per_frame == 0
    same = network_cost(exp, exp.train.crop, exp.train.crop)
    per_sample = exp.train.batch_size * exp.train.num_windows * same.flop_per_frame
    # backward: the input gradient and the weight gradient, each one forward's FLOP, except that the
    # first convolution's input (spikes) needs no gradient
    assert 2.5 * per_sample < same.train_flop_per_step <= 3 * per_sample
    assert same.parameters == sum(p.numel() for p in __import__("model.arch", fromlist=["x"]).build_model(exp.model).parameters())


def test_the_paper_network_costs_the_papers_flop_per_window():
    full = load_config("full")
    # the per-frame cost does not depend on the train section; its K = 21, batch-8 training step
    # alone took a minute to count, so the step counted here is the smallest (1 sample of 2 windows)
    cost = network_cost(dataclasses.replace(full, train=dataclasses.replace(full.train, num_windows=2, batch_size=1)),
                        250, 400)
    assert cost.parameters == pytest.approx(5.6e6, rel=0.01)  # the paper: 5.6 M parameters
    assert cost.flop_per_frame / 1e12 == pytest.approx(1.16, rel=0.01)  # the paper: 1.16 TFLOP per window
    assert 0 < cost.sampling_flop_per_frame < 0.01 * cost.flop_per_frame  # alignment's sampling, counted apart


# ---- verdicts ---------------------------------------------------------------------------------

def test_each_paper_ordering_is_marked_from_the_seeds():
    stats = {("A", "ALL_low", "psnr_aligned"): seed_stat("A", "ALL_low", "psnr_aligned", [20.0, 20.1, 19.9]),
             ("B", "ALL_low", "psnr_aligned"): seed_stat("B", "ALL_low", "psnr_aligned", [21.0, 21.1, 20.9]),
             ("C", "ALL_low", "psnr_aligned"): seed_stat("C", "ALL_low", "psnr_aligned", [20.0, 21.0, 19.0])}
    assert ordering_verdict(stats, "B", "A", "ALL_low") == "held"
    assert ordering_verdict(stats, "A", "B", "ALL_low") == "not held"
    assert ordering_verdict(stats, "C", "A", "ALL_low") == "within spread"
    assert ordering_verdict(stats, "D", "A", "ALL_low") == "not measured"
    study = get_study("ablation")
    assert ("E", "A") in study.orderings and ("A", "E") not in study.orderings  # the paper: E 45.08 > A 42.74
    with pytest.raises(ValueError, match="unknown study 'nope'; known: representations, ablation, table1"):
        get_study("nope")


def test_the_study_table_puts_the_papers_figures_beside_ours():
    study = get_study("ablation")
    stats = [seed_stat(label, g, m, [20.0 + i, 20.5 + i, 21.0 + i])
             for i, label in enumerate("ABCDEF") for g in ("ALL_low", "ALL_normal", "ALL")
             for m in ("psnr_aligned", "psnr_8bit", "ssim_8bit")]
    costs = {label: {"parameters": 1000, "gflop_per_frame": 1.5, "steps": 300, "cpu_minutes": 2.0, "seeds": 3}
             for label in "ABCDEF"}
    text = study_markdown(study, stats, costs, {})
    row_a = next(line for line in text.splitlines() if line.startswith("| A |"))
    assert "20.50 ± 0.50" in row_a and "42.74" in row_a and "0.9740" in row_a and "1,000" in row_a
    assert "| E > A | held | held |" in text  # E is 4 dB above A, spreads 0.5 each


# ---- compare: CPU time, parallel runs, kept scores, shared runs --------------------------------

def test_compare_records_cpu_time_trains_in_parallel_keeps_scores_and_shares_a_run(tmp_path, capsys):
    _write_dataset(tmp_path / "train", ["a_normal", "b_low"], 0)
    _write_dataset(tmp_path / "test", ["c_low", "c_normal"], 10)
    e = _config(tmp_path / "e.json", "e")
    out = tmp_path / "cmp"
    argv = ["compare", "--data", str(tmp_path / "train"), "--test-data", str(tmp_path / "test"),
            "--configs", f"E={e}", "--seeds", "0", "1", "2", "--max-steps", "2", "--device", "cpu",
            "--quiet", "--jobs", "2", "--threads", "2", "--out", str(out)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "3 of 3 runs to train (2 steps each), 2 at a time" in err
    for s in (0, 1, 2):
        record = read_compute(out / "runs" / "E" / f"seed{s}")
        assert record["steps"] == 2 and record["cpu_seconds"] > 0 and record["threads"] == [1]
    text = (out / "compare.md").read_text()
    assert "GFLOP per 16 x 12 frame" in text and "CPU-minutes per run" in text
    # again, with the same config under a second label: nothing trains, nothing is scored again
    stamp = (out / "runs" / "E" / "seed0" / "last.pt").stat().st_mtime_ns
    assert main(argv[:6] + [f"E={e}", f"SAME={e}"] + argv[7:]) == 0
    err = capsys.readouterr().err
    assert "runs to train" not in err and "scoring" not in err
    assert "SAME seed 0: the same config and seed already trained as" in err
    assert not (out / "runs" / "SAME").exists() or not (out / "runs" / "SAME" / "seed0" / COMPUTE_FILE).exists()
    assert (out / "runs" / "E" / "seed0" / "last.pt").stat().st_mtime_ns == stamp
    stats = {(r["label"], r["metric"], r["group"]): r["values"] for r in
             __import__("csv").DictReader((out / "compare.csv").open())}
    assert stats[("SAME", "psnr_aligned", "ALL")] == stats[("E", "psnr_aligned", "ALL")]


def test_compare_names_an_unknown_study_and_asks_for_configs(tmp_path, capsys):
    assert main(["compare", "--study", "nope", "--data", "d", "--test-data", "d", "--max-steps", "1",
                 "-o", str(tmp_path / "o")]) == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err
    assert main(["compare", "--data", "d", "--test-data", "d", "--max-steps", "1", "-o", str(tmp_path / "o")]) == 2
    assert "name the configs to compare, or a --study" in capsys.readouterr().err


def test_a_study_with_its_rows_given_writes_its_table_and_equal_flop_shares_out_the_steps(tmp_path, capsys):
    _write_dataset(tmp_path / "train", ["a_normal", "b_low"], 0)
    _write_dataset(tmp_path / "test", ["c_low", "c_normal"], 10)
    e = _config(tmp_path / "e.json", "e")
    a = _config(tmp_path / "a.json", "a", representation="spike", adf=False, aif=False)
    out = tmp_path / "cmp"
    assert main(["compare", "--study", "ablation", "--equal", "flop", "--data", str(tmp_path / "train"),
                 "--test-data", str(tmp_path / "test"), "--configs", f"E={e}", f"A={a}", "--seeds", "0", "1", "2",
                 "--max-steps", "2", "--device", "cpu", "--quiet", "--threads", "1", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    from model.comparison import equal_flop_steps
    want = equal_flop_steps([("E", load_config(e)), ("A", load_config(a))], 2, "E")
    assert want["E"] == 2 and want["A"] > 2  # (A) has no LR-Rep, no fusion state: a cheaper step, more of them
    assert f"equal training FLOP: 2 steps of E -> E 2, A {want['A']}" in err
    assert read_compute(out / "runs" / "A" / "seed0")["steps"] == want["A"]
    table = (out / "study_ablation.md").read_text()
    assert table.startswith("**The ablation at the shipped size (paper Table 4)**")
    row_b = next(line for line in table.splitlines() if line.startswith("| B |"))
    assert "n/a" in row_b and "44.15" in row_b  # not run here; the paper's figure beside it
    assert "| E > A |" in table and "| TFP-21 |" in table  # K = 3 windows of 7 steps
    meta = json.loads((out / "study_ablation.json").read_text())
    assert meta["study"] == "ablation" and meta["equal"] == "flop" and meta["costs"]["A"]["steps"] == want["A"]


def test_a_baseline_the_window_cannot_take_is_refused_before_any_run_trains(tmp_path, capsys):
    _write_dataset(tmp_path / "train", ["a_normal"], 0)
    e = _config(tmp_path / "e.json", "e")  # 7-step windows
    out = tmp_path / "cmp"
    assert main(["compare", "--data", str(tmp_path / "train"), "--test-data", str(tmp_path / "train"), "--configs",
                 f"E={e}", "--baselines", "tfp:205", "--max-steps", "1", "--quiet", "--out", str(out)]) == 2
    assert "tfp:205: the span must be an odd number of 7-step windows" in capsys.readouterr().err
    assert not (out / "runs").exists()


def test_a_published_network_by_name_says_how_to_get_its_weights():
    from model.methods import method_from_spec
    with pytest.raises(ValueError, match=r"no weights of s2i ship .*--config cpu_s2i .*S2I=runs/s2i/last.pt"):
        method_from_spec("s2i")
    with pytest.raises(ValueError, match="expected one of"):
        method_from_spec("nonsense")


@pytest.mark.parametrize("argv, msg", [
    (["--configs", "x|y=tiny"], "a label is a plain, printable name"),
    (["--configs", "n\nl=tiny"], "a label is a plain, printable name"),
    (["--configs", "tfp=tiny"], "name a baseline"),
    (["--configs", "a=tiny", "A=tiny_ablation_a"], "unique (case aside)"),
    (["--configs", "tiny", "--seeds", "0", "1", "100000000000000000000000000000"], "a seed is at most 2**63 - 1"),
])
def test_compare_refuses_labels_and_seeds_that_cannot_be(tmp_path, capsys, argv, msg):
    _write_dataset(tmp_path / "d", ["a_normal"], 0)
    rc = main(["compare", "--data", str(tmp_path / "d"), "--test-data", str(tmp_path / "d"), "--max-steps", "1",
               "--quiet", "--out", str(tmp_path / "o"), *argv])
    assert rc == 2 and msg in capsys.readouterr().err
    assert not (tmp_path / "o" / "runs").exists()


def test_a_score_cache_or_compute_record_that_is_not_a_file_is_not_read(tmp_path):
    import os

    from model.comparison import _read_scores
    fifo = tmp_path / "scores.json"
    os.mkfifo(fifo)
    assert _read_scores(fifo, [1, 2]) is None  # would block on open without the guard
    os.mkfifo(tmp_path / COMPUTE_FILE)
    assert read_compute(tmp_path) == {}


def test_a_span_longer_than_the_stream_is_said(caplog):
    from model.methods import method_from_spec
    from model.streaming import TensorWindows
    spikes = torch.rand(4, 41, 3, 5) < 0.3
    with caplog.at_level("WARNING", logger="spikesim.methods"):
        frames = [f for _, f in method_from_spec("tfp:861").frames(TensorWindows(spikes))]
    assert "longer than the 4 window(s) of 41 steps read" in caplog.text
    whole = spikes.float().mean(dim=(0, 1))
    assert all(torch.allclose(f, whole) for f in frames)  # every frame reaches all 4 windows


def test_compare_keeps_a_run_only_for_the_run_it_would_train(tmp_path, capsys):
    _write_dataset(tmp_path / "train", ["a_normal", "b_low"], 0)
    _write_dataset(tmp_path / "other", ["a_normal"], 5)
    _write_dataset(tmp_path / "test", ["c_low"], 6)
    e = _config(tmp_path / "e.json", "e")
    out = tmp_path / "cmp"
    argv = ["compare", "--data", str(tmp_path / "train"), "--test-data", str(tmp_path / "test"), "--configs", f"E={e}",
            "--max-steps", "1", "--quiet", "--threads", "1", "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    # the config edited under the same label: refused, naming the field, not scored as the new config
    _config(e, "e", num_features=4, deform_groups=2)
    assert main(argv) == 2
    assert "holds a run trained with another network or recipe (model.num_features)" in capsys.readouterr().err
    _config(e, "e")
    # other data, or other starting weights: refused
    assert main(argv[:2] + [str(tmp_path / "other")] + argv[3:]) == 2
    assert "other training data" in capsys.readouterr().err
    assert main(argv + ["--init", str(out / "runs" / "E" / "seed0" / "last.pt")]) == 2
    assert "other starting weights" in capsys.readouterr().err
    # a run cut before its first checkpoint (a folder without last.pt) is started again
    (out / "runs" / "E" / "seed1" / "last.pt").unlink()
    assert main(argv) == 0 and (out / "runs" / "E" / "seed1" / "last.pt").exists()


def test_a_named_base_is_a_plain_name(tmp_path):
    (tmp_path / "x.json").write_text('{"name": "x", "base": "../../../../tmp/evil", "model": {}}')
    with pytest.raises(ValueError, match="a shipped config is a plain name"):
        load_config(tmp_path / "x.json")


def test_a_seed_in_a_config_file_has_the_range_of_the_flag():
    for bad in (2 ** 63, 10 ** 30, -5):
        with pytest.raises(ValueError, match=r"train.seed must be an integer in 0..2\*\*63 - 1"):
            TrainConfig(seed=bad)
    assert TrainConfig(seed=2 ** 63 - 1).seed == 2 ** 63 - 1


def test_a_worker_killed_from_outside_is_said_and_what_finished_is_kept():
    from model.comparison import _run_parallel
    done = []
    with pytest.raises(MemoryError, match="a worker process was killed .* run the same command again"):
        _run_parallel(_die_if_one, [0, 1], 2, done.append)


def _die_if_one(x: int) -> int:  # a worker the kernel kills (SIGKILL), as the OOM killer does
    import os
    import signal
    import time
    if x == 1:
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(0.5)
    return x


def test_an_infinite_8bit_psnr_is_shown_plainly_and_gives_no_difference():
    """A dark scene's 8-bit frames can equal the ground truth's (both all zeros): PSNR inf. The
    table said "inf ± nan" and "-inf (within spread)"; it says inf, and that no gap is measured."""
    from model.comparison import NO_DIFFERENCE, markdown
    from model.evaluation import ALL, TABLE_ROWS
    inf = float("inf")
    stats = [seed_stat(label, ALL, metric, ([inf, 40.0, inf] if (label, metric) == ("A", "psnr_8bit")
                                            else [20.0 + i, 20.5 + i, 21.0 + i]))
             for i, label in enumerate(("A", "B")) for metric in TABLE_ROWS]
    text = markdown(stats, ["A", "B"], [], [0, 1, 2], 10)
    row = next(line for line in text.splitlines() if line.startswith("| PSNR 8-bit |"))
    assert row.split(" | ")[1] == "inf" and "nan" not in text
    diff = next(line for line in text.splitlines() if line.startswith(f"| {ALL} | PSNR 8-bit |"))
    assert NO_DIFFERENCE in diff and "inf (within" not in text
    # the finite rows keep their spread and their called differences
    aligned = next(line for line in text.splitlines() if line.startswith(f"| {ALL} | ") and "-1.000" in line)
    assert "within spread" in aligned
