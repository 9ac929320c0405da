"""Round fourteen (docs/robustness.md): the results block locks a folder it makes, a malformed
record entry is a refusal, a waiting writer names the holder, a killed writer's temporaries go,
every command takes SIGTERM as Ctrl-C, `compare` stops its workers, one campaign call per --work,
and `golden --seeds` refused where it does nothing."""
from __future__ import annotations

import fcntl
import json
import logging
import multiprocessing as mp
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from spikesim import outputs
from spikesim.outputs import RESULTS_LOCK, RESULTS_RECORD, atomic_write_text, results_writing

NAMES = ["metrics.csv", "metrics.md"]


def _first_run(out: str, entered, tag: str) -> None:
    with results_writing(out, NAMES, "evaluate"):
        atomic_write_text(Path(out) / "metrics.csv", f"csv of {tag}\n")
        entered.set()
        time.sleep(1.5)
        atomic_write_text(Path(out) / "metrics.md", f"md of {tag}\n")


def test_two_first_runs_into_a_new_folder_never_mix_their_results(tmp_path):
    """The folder did not exist: the first block could not make its lock there, wrote unlocked, and
    a second run's csv landed beside the first's md."""
    out = tmp_path / "new" / "results"
    ctx = mp.get_context("fork")
    entered = ctx.Event()
    a = ctx.Process(target=_first_run, args=(str(out), entered, "A"))
    a.start()
    assert entered.wait(20)
    assert (out / RESULTS_LOCK).is_file()  # held while A writes
    b = ctx.Process(target=_first_run, args=(str(out), ctx.Event(), "B"))
    b.start()
    a.join(30)
    b.join(30)
    assert a.exitcode == 0 and b.exitcode == 0
    csv, md = (out / "metrics.csv").read_text(), (out / "metrics.md").read_text()
    assert csv.split()[-1] == md.split()[-1] == "B", (csv, md)


def test_a_failed_block_removes_the_folder_it_made(tmp_path):
    out = tmp_path / "a" / "b"
    with pytest.raises(RuntimeError):
        with results_writing(out, NAMES, "evaluate"):
            raise RuntimeError("scoring failed")
    assert not (tmp_path / "a").exists()


@pytest.mark.parametrize("field,value", [("sha256", ["x"]), ("previous", {"a": 1}), ("sha256", 5)])
def test_a_record_entry_of_the_wrong_type_is_refused_not_a_traceback(tmp_path, field, value):
    with results_writing(tmp_path, NAMES, "evaluate"):
        for name in NAMES:
            atomic_write_text(tmp_path / name, "x\n")
    record = json.loads((tmp_path / RESULTS_RECORD).read_text())
    record["files"]["metrics.md"][field] = value
    (tmp_path / RESULTS_RECORD).write_text(json.dumps(record))
    if field == "sha256":  # no hash to match: the user's file, refused by name
        with pytest.raises(FileExistsError, match="metrics.md, which no earlier evaluate run wrote there"):
            outputs.check_results_owned(tmp_path, NAMES, "evaluate")
    else:  # the file still matches its recorded hash: a malformed `previous` is only not a match
        assert outputs.check_results_owned(tmp_path, NAMES, "evaluate") == NAMES


def test_a_writer_that_waits_names_the_holder(tmp_path, caplog):
    lock = tmp_path / RESULTS_LOCK
    fd = os.open(lock, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX)
    os.write(fd, b"pid 4242: spikesim sweep -o here\n")
    done = threading.Event()

    def write() -> None:
        with results_writing(tmp_path, NAMES, "evaluate"):
            atomic_write_text(tmp_path / "metrics.csv", "x\n")
        done.set()

    with caplog.at_level(logging.WARNING, logger="spikesim.outputs"):
        t = threading.Thread(target=write)
        t.start()
        for _ in range(100):
            if "waiting for" in caplog.text:
                break
            time.sleep(0.05)
        assert not done.is_set()
        os.close(fd)  # the holder ends: the writer goes on
        t.join(20)
    assert done.is_set()
    assert f"{tmp_path}: waiting for pid 4242: spikesim sweep -o here to finish writing its results there" in caplog.text


def test_the_holder_records_its_pid_in_the_lock(tmp_path):
    with results_writing(tmp_path, NAMES, "evaluate"):
        assert (tmp_path / RESULTS_LOCK).read_text().startswith(f"pid {os.getpid()}: ")


def test_a_killed_writers_temporaries_are_removed_by_the_next(tmp_path):
    with results_writing(tmp_path, NAMES, "evaluate"):  # an earlier run: its record says spikesim writes here
        atomic_write_text(tmp_path / "metrics.md", "earlier\n")
    left = [tmp_path / ".metrics.csv.0123abcd.part", tmp_path / f".{RESULTS_RECORD}.89abcdef.part"]
    kept = [tmp_path / ".notes.txt.0123abcd.part", tmp_path / ".metrics.csv.part", tmp_path / "metrics.csv.0123abcd.part"]
    for p in left + kept:
        p.write_text("partial")
    link = tmp_path / ".metrics.md.fedcba98.part"
    link.symlink_to(tmp_path / "elsewhere")
    with results_writing(tmp_path, NAMES, "evaluate"):
        atomic_write_text(tmp_path / "metrics.csv", "x\n")
    assert not any(p.exists() for p in left)
    assert all(p.exists() for p in kept) and link.is_symlink()


def test_sigterm_to_any_command_is_taken_as_ctrl_c(monkeypatch, capsys):
    """The command line's rule: a Terminated (KeyboardInterrupt) runs the command's clean-up, then
    one line and the shell's status for SIGTERM."""
    from pipelines import cli

    cleaned = []

    def command(argv, name):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(10)
        finally:
            cleaned.append(name)
        return 0

    monkeypatch.setattr(cli, "_run", command)
    assert cli.main(["compare", "--data", "x"]) == 143
    assert cleaned == ["compare"]
    assert capsys.readouterr().err.strip() == "spikesim compare: terminated (SIGTERM)"
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL or callable(signal.getsignal(signal.SIGTERM))


def test_compare_stops_its_workers_on_sigterm_rather_than_waiting_for_their_runs():
    from model.comparison import _run_parallel
    from spikesim.signals import Terminated, sigterm_raises

    timer = threading.Timer(3.0, os.kill, (os.getpid(), signal.SIGTERM))
    start = time.monotonic()
    with pytest.raises(Terminated):
        with sigterm_raises():
            timer.start()
            _run_parallel(time.sleep, [60, 60], 2, lambda result: None)
    assert time.monotonic() - start < 30  # not the 60 s each worker's task would take


def test_one_campaign_call_per_work_folder(tmp_path):
    from pipelines.gpu_campaign import PROFILES, Options, runner
    from spikesim.generation.lock import OutputLockedError, output_lock

    work = tmp_path / "W"
    work.mkdir()
    o = Options(out=tmp_path / "o", work=work, profile=PROFILES["dry-run"], part="all", stages=("bench_sensor",))
    with output_lock(work, "gpu-campaign --part all -o o1 --work W", what="gpu-campaign call"):
        with pytest.raises(OutputLockedError, match=r"another gpu-campaign \w+ is writing here \(pid \d+: gpu-campaign"):
            runner.run_campaign(o)
    assert not (tmp_path / "o").exists()


def test_golden_refuses_seeds_without_write_or_power(capsys):
    from pipelines.cli import main

    assert main(["golden", "--seeds", "7"]) == 2
    assert "--seeds 7 goes with --write" in capsys.readouterr().err



def _one_scene_dataset(root: Path, info: dict) -> None:
    import numpy as np

    from spikesim.dataset import write_manifest, write_scene
    from spikesim.stream import SpikeStream

    rng = np.random.default_rng(0)
    write_scene(root, "s_low", SpikeStream.from_bool(rng.random((8, 4, 6)) < 0.3),
                {4: rng.random((4, 6)).astype(np.float32)}, meta={})
    write_manifest(root, info)


@pytest.mark.parametrize("field,value", [("total_bytes", -1), ("total_bytes", "3"), ("seed", float("nan")),
                                         ("seed", -5), ("seed", True), ("kind", 7), ("kind", "x y"),
                                         ("preset", "small"), ("jobs", [])])
def test_verify_reports_an_edited_manifest_field(tmp_path, field, value):
    from spikesim.dataset import MANIFEST, verify

    root = tmp_path / "ds"
    _one_scene_dataset(root, {"kind": "llr", "seed": 3, "preset": {"steps": 8}, "jobs": {"s_low": "ab12"}})
    assert verify(root) == []
    doc = json.loads((root / MANIFEST).read_text())
    doc[field] = value
    (root / MANIFEST).write_text(json.dumps(doc, allow_nan=True))
    assert any(p.startswith(f"{MANIFEST}: {field}") for p in verify(root)), verify(root)


def test_verify_reports_a_job_digest_that_is_not_a_string(tmp_path):
    from spikesim.dataset import MANIFEST, verify

    root = tmp_path / "ds"
    _one_scene_dataset(root, {"jobs": {"s_low": 123}})
    assert verify(root) == [f"{MANIFEST}: jobs.s_low: 123, expected the scene's job digest (a string)"]


# ---- round fifteen ------------------------------------------------------------------------------

def _fail_after_making(out: str, entered, release) -> None:
    """A writer that makes the folder, holds the lock, then fails: its folder, now empty, is removed."""
    try:
        with results_writing(out, NAMES, "evaluate"):
            entered.set()
            release.wait(20)
            raise RuntimeError("scoring failed")
    except RuntimeError:
        pass


def test_a_writer_waiting_on_one_that_fails_and_removes_the_folder_still_takes_the_lock(tmp_path, monkeypatch):
    out = tmp_path / "new"
    ctx = mp.get_context("fork")
    entered, release = ctx.Event(), ctx.Event()
    a = ctx.Process(target=_fail_after_making, args=(str(out), entered, release))
    a.start()
    assert entered.wait(20)
    opened = []
    real = outputs.in_place_fd

    def watch(path, flags):
        try:
            return real(path, flags)
        except FileNotFoundError:
            opened.append(path)
            raise

    monkeypatch.setattr(outputs, "in_place_fd", watch)
    held = []

    def write() -> None:
        with results_writing(out, NAMES, "evaluate"):
            held.append((out / RESULTS_LOCK).is_file())
            for name in NAMES:
                atomic_write_text(out / name, "B\n")

    t = threading.Thread(target=write)
    t.start()
    time.sleep(1.0)  # B waits on A's lock
    release.set()
    a.join(20)
    t.join(20)
    assert held == [True]  # B wrote under the lock, in the folder made again
    assert (out / "metrics.csv").read_text() == (out / "metrics.md").read_text() == "B\n"


def test_a_temporary_looking_file_is_kept_where_spikesim_never_wrote_results(tmp_path):
    user = tmp_path / ".metrics.csv.0123abcd.part"
    user.write_text("my notes")
    with results_writing(tmp_path, NAMES, "evaluate"):
        atomic_write_text(tmp_path / "metrics.csv", "x\n")
    assert user.read_text() == "my notes"


def _make_cache_and_report() -> str:
    from spikesim.render import mono
    return str(mono._cache_dir())


def test_a_generation_worker_stopped_by_sigterm_removes_its_temporary_folders():
    import concurrent.futures

    from spikesim.generation.pool import _worker_init
    from spikesim.signals import stop_pool_workers

    with concurrent.futures.ProcessPoolExecutor(1, mp_context=mp.get_context("spawn"), initializer=_worker_init,
                                                initargs=(1, None, os.getpid())) as pool:
        cache = Path(pool.submit(_make_cache_and_report).result(timeout=60))
        assert cache.is_dir()
        pool.submit(time.sleep, 60)
        time.sleep(0.5)
        stop_pool_workers(pool)
        for _ in range(100):
            if not cache.exists():
                break
            time.sleep(0.1)
    assert not cache.exists()


def test_resume_refuses_a_config_record_that_is_a_folder_before_saying_anything(tmp_path, capsys):
    from model.training import _restore_config_record

    (tmp_path / "config.json").mkdir()
    with pytest.raises(IsADirectoryError, match="config.json"):
        _restore_config_record(tmp_path, None)
    assert "rewritten" not in capsys.readouterr().err


def test_one_campaign_call_per_output_folder(tmp_path):
    from pipelines.gpu_campaign import PROFILES, Options, runner
    from spikesim.generation.lock import OutputLockedError, output_lock

    out = tmp_path / "o"
    out.mkdir()
    o = Options(out=out, work=tmp_path / "W2", profile=PROFILES["dry-run"], part="all", stages=("bench_sensor",))
    with output_lock(out, "gpu-campaign --part all -o o --work W1", what="gpu-campaign call"):
        with pytest.raises(OutputLockedError, match="pid"):
            runner.run_campaign(o)
