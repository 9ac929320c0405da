"""Round twelve: the results record (`.spikesim-results.json`) under interruption, a full disk and
concurrent commands. A sweep stopped while plotting left its new tables unrecorded beside the last
run's plot, and every rerun refused them (H1); concurrent `inspect --preview` runs into one folder
lost record entries (M1); a full disk at the record write orphaned the results just written (M2).
Each result is now recorded, under a lock, before it is renamed into place (spikesim.outputs.
results_writing), and a rerun's own earlier results are removed before the new ones are written."""
from __future__ import annotations

import errno
import json
import multiprocessing
import os
from argparse import Namespace

import numpy as np
import pytest

from cli_testing import one_line, run_cli

import spikesim.outputs as outputs
from spikesim.outputs import RESULTS_RECORD, _results_record

RESULTS_LOCK = getattr(outputs, "RESULTS_LOCK", ".spikesim-results.lock")


def _record_write_fails(monkeypatch):
    """The record write fails as on a full disk (the results themselves still fit)."""
    real = outputs.atomic_write_json

    def full(path, *a, **k):
        if os.path.basename(path) == RESULTS_RECORD:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, *a, **k)

    monkeypatch.setattr(outputs, "atomic_write_json", full)


@pytest.fixture(scope="module")
def dat16(tmp_path_factory):
    from spikesim.stream import SpikeStream, write_dat
    rng = np.random.default_rng(3)
    spikes = rng.random((41 * 3, 16, 16)) < np.linspace(0.05, 0.6, 16)[None, None, :]
    return write_dat(tmp_path_factory.mktemp("dat16") / "s.dat", SpikeStream.from_bool(spikes))


# ---- H1: an interrupted writer leaves results its rerun replaces, and no mix of two runs ----------

def test_a_sweep_stopped_while_plotting_is_replaced_by_its_rerun(tmp_path, monkeypatch):
    import pipelines.sweep as sweep_mod
    kw = dict(levels=[1.0], windows=1, spp=1, gt_spp=1, out=tmp_path, progress=False)
    sweep_mod.run_sweep(["fan"], ["tfp"], **kw)
    old_plot = (tmp_path / "sweep.png").read_bytes()
    real = sweep_mod.plot

    def stopped(*a, **k):
        raise KeyboardInterrupt  # SIGTERM while drawing (sigterm_raises makes it this)

    monkeypatch.setattr(sweep_mod, "plot", stopped)
    with pytest.raises(KeyboardInterrupt):
        sweep_mod.run_sweep(["fan"], ["tfi", "mean"], **kw)
    # only the stopped run's own tables: the earlier run's plot is not left beside them
    assert not (tmp_path / "sweep.png").exists()
    assert "TFI" in (tmp_path / "sweep.md").read_text()
    assert set(_results_record(tmp_path)) == {"sweep.csv", "sweep.md", "sweep.json"}
    monkeypatch.setattr(sweep_mod, "plot", real)
    sweep_mod.run_sweep(["fan"], ["tfi", "mean"], **kw)  # was: "holds sweep.csv, sweep.md, sweep.json, which no ..."
    assert (tmp_path / "sweep.png").read_bytes() != old_plot
    assert set(_results_record(tmp_path)) == {"sweep.csv", "sweep.md", "sweep.json", "sweep.png"}
    assert not (tmp_path / RESULTS_LOCK).exists()


def test_tradeoff_report_interrupted_at_its_plot_is_replaced_by_the_rerun(tmp_path, monkeypatch):
    import pipelines.tradeoff_study as study
    rows = [{"scene": "ball", "light": "low", "run": "spp=1"}]
    monkeypatch.setattr(study, "markdown_table", lambda rows, gt_rows=(): "the table\n")
    monkeypatch.setattr(study, "plot", lambda rows, path, gt_rows=(): outputs.atomic_write_bytes(path, b"plot 1"))
    study.write_report(rows, tmp_path)

    def stopped(*a, **k):
        raise SystemExit(143)

    monkeypatch.setattr(study, "plot", stopped)
    with pytest.raises(SystemExit):
        study.write_report(rows, tmp_path)
    assert not (tmp_path / "tradeoff.png").exists()  # no earlier run's plot beside the new table
    monkeypatch.setattr(study, "plot", lambda rows, path, gt_rows=(): outputs.atomic_write_bytes(path, b"plot 2"))
    study.write_report(rows, tmp_path)  # was: refused, tradeoff.csv and tradeoff.md unrecorded
    assert (tmp_path / "tradeoff.png").read_bytes() == b"plot 2"


def test_an_interruption_between_the_record_and_the_rename_keeps_the_file_its_own(tmp_path, monkeypatch):
    """A result written twice in one run, stopped between recording the second content and renaming
    it in: the file still holds the first, which the record still accepts."""
    real = os.replace

    def stop_at(src, dst, *a, **k):
        if os.path.basename(dst) == "a.txt":
            raise KeyboardInterrupt
        return real(src, dst, *a, **k)

    with outputs.results_writing(tmp_path, ["a.txt"], "sweep"):
        outputs.atomic_write_text(tmp_path / "a.txt", "first")
        monkeypatch.setattr(outputs.os, "replace", stop_at)
        with pytest.raises(KeyboardInterrupt):
            outputs.atomic_write_text(tmp_path / "a.txt", "second")
        monkeypatch.setattr(outputs.os, "replace", real)
    assert (tmp_path / "a.txt").read_text() == "first"
    assert outputs.check_results_owned(tmp_path, ["a.txt"], "sweep") == ["a.txt"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".a.txt")] == []  # no temporary file left


# ---- M2: a full disk at the record write ---------------------------------------------------------

def test_evaluate_with_a_full_disk_at_the_record_leaves_nothing_its_rerun_refuses(tmp_path, monkeypatch):
    from model.evaluation import Score
    from pipelines.evaluate import _write
    args = Namespace(out=str(tmp_path), json=False)
    rows = [Score("fan", "tfp", 20.0, 0.5, 1)]
    _record_write_fails(monkeypatch)
    with pytest.raises(OSError) as failed:
        _write(args, rows, ["tfp"], markdown="the table\n")
    assert failed.value.errno == errno.ENOSPC and RESULTS_RECORD in str(failed.value)
    monkeypatch.undo()  # space freed
    _write(args, rows, ["tfp"], markdown="the table\n")  # was: "holds metrics.csv, metrics.md, which no ..."
    assert set(_results_record(tmp_path)) == {"metrics.csv", "metrics.md"}
    assert (tmp_path / "metrics.md").read_text() == "the table\n"


def test_inspect_with_a_full_disk_at_the_record_then_reruns(dat16, tmp_path, capsys, monkeypatch):
    preview = tmp_path / "p.png"
    _record_write_fails(monkeypatch)
    code, err = run_cli(["inspect", dat16, "--height", 16, "--width", 16, "--preview", preview], capsys)
    assert code == 2 and "No space left" in one_line(err), err
    assert not preview.exists()  # never written unrecorded
    monkeypatch.undo()
    code, err = run_cli(["inspect", dat16, "--height", 16, "--width", 16, "--preview", preview], capsys)
    assert code == 0, err
    assert preview.exists() and "p.png" in _results_record(tmp_path)


def test_panel_with_a_full_disk_at_the_record_then_reruns(dat16, tmp_path, capsys, monkeypatch):
    out = tmp_path / "p.png"
    argv = ["panel", dat16, "--height", 16, "--width", 16, "--methods", "tfp", "-o", out, "--device", "cpu"]
    _record_write_fails(monkeypatch)
    code, err = run_cli(argv, capsys)
    assert code == 2 and "No space left" in one_line(err), err
    assert not out.exists()  # never written unrecorded
    monkeypatch.undo()
    code, err = run_cli(argv, capsys)
    assert code == 0 and out.exists(), err


# ---- M1: concurrent writers ----------------------------------------------------------------------

def _write_many(folder: str, worker: int, count: int, start) -> None:
    start.wait()
    for i in range(count):
        name = f"p{worker}_{i}.png"
        with outputs.results_writing(folder, [name], "inspect", "--preview"):
            outputs.atomic_write_bytes(os.path.join(folder, name), f"{worker} {i}".encode())


def _record_many(folder: str, worker: int, count: int, start) -> None:
    start.wait()
    for i in range(count):
        name = f"r{worker}_{i}.png"
        outputs.atomic_write_bytes(os.path.join(folder, name), f"{worker} {i}".encode())
        outputs.record_results_owned(folder, [name], "inspect")


@pytest.mark.parametrize("writer", [_write_many, _record_many])
def test_concurrent_writers_lose_no_record_entries(tmp_path, writer):
    ctx = multiprocessing.get_context("fork")
    workers, count = 6, 12
    start = ctx.Barrier(workers)
    procs = [ctx.Process(target=writer, args=(str(tmp_path), w, count, start)) for w in range(workers)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    assert all(p.exitcode == 0 for p in procs)
    listed = _results_record(tmp_path)
    files = {p.name for p in tmp_path.iterdir() if p.name.endswith(".png")}
    assert len(files) == workers * count and set(listed) == files  # was: entries lost
    assert outputs.check_results_owned(tmp_path, sorted(files), "inspect") == sorted(files)
    assert not (tmp_path / RESULTS_LOCK).exists()


# ---- the lock file is the toolkit's; the record's protections hold -------------------------------

def test_a_lock_left_by_a_killed_command_is_reused_and_never_refused(tmp_path):
    (tmp_path / RESULTS_LOCK).write_text("")  # a command killed while updating the record
    with outputs.results_writing(tmp_path, ["a.md"], "evaluate"):
        outputs.atomic_write_text(tmp_path / "a.md", "table")
    assert outputs.check_results_owned(tmp_path, ["a.md"], "evaluate") == ["a.md"]
    assert json.loads((tmp_path / RESULTS_RECORD).read_text())["files"]["a.md"]["command"] == "evaluate"


def test_the_lock_name_is_no_result_name_and_a_fifo_there_is_refused_before_work(tmp_path):
    with pytest.raises(ValueError, match="no golden result may take that name"):
        outputs.check_results_owned(tmp_path, [RESULTS_LOCK], "golden")
    os.mkfifo(tmp_path / RESULTS_LOCK)
    with pytest.raises(FileExistsError, match="is not a regular file"):
        outputs.check_results_owned(tmp_path, ["metrics.md"], "evaluate")


def test_a_file_the_user_puts_there_during_the_block_is_refused_at_the_rename(tmp_path):
    with pytest.raises(FileExistsError, match="holds a.md, which no earlier evaluate run wrote"):
        with outputs.results_writing(tmp_path, ["a.md"], "evaluate"):
            (tmp_path / "a.md").write_text("the user's notes")
            outputs.atomic_write_text(tmp_path / "a.md", "table")
    assert (tmp_path / "a.md").read_text() == "the user's notes"
    assert "a.md" not in _results_record(tmp_path)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".a.md")] == []


def test_a_users_file_named_like_an_unwritten_result_is_still_refused(tmp_path):
    """An interrupted run leaves its unwritten results unlisted: a user's file of that name later
    is refused, not taken as the command's."""
    with pytest.raises(KeyboardInterrupt):
        with outputs.results_writing(tmp_path, ["a.md", "a.png"], "sweep"):
            outputs.atomic_write_text(tmp_path / "a.md", "table")
            raise KeyboardInterrupt
    (tmp_path / "a.png").write_bytes(b"the user's plot")
    with pytest.raises(FileExistsError, match="holds a.png"):
        outputs.check_results_owned(tmp_path, ["a.md", "a.png"], "sweep")
