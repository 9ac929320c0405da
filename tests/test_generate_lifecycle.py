"""How a `generate` run begins and ends: the lock file exists only while a run holds it, a failed
run leaves no output folder it created, and SIGTERM stops it like Ctrl-C, with a message, its
workers stopped and no `.work` folders left."""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import spikesim.generation.lock as lock_module
import spikesim.generation.pool as pool
from spikesim.dataset import LOCK_FILE
from spikesim.generation import generate
from spikesim.generation.lock import output_lock
from test_generate import tiny_jobs
from test_generate_processes import _children, _running

REPO = Path(__file__).resolve().parents[1]


def test_the_lock_file_holds_the_run_and_is_gone_after_it(tmp_path):
    root = tmp_path / "data"
    with output_lock(tmp_path, "first"):
        assert "first" in (tmp_path / LOCK_FILE).read_text()
    assert not (tmp_path / LOCK_FILE).exists()
    generate(tiny_jobs(1), root, workers=1, show_progress=False, command="spikesim generate x")
    assert not (root / LOCK_FILE).exists()


def test_a_lock_file_removed_as_it_was_locked_is_locked_afresh(tmp_path, monkeypatch):
    """The holder removes the file just after a second run opened it: the second run must not
    hold a lock on the removed file while a third one locks a new file at the same path."""
    real = lock_module.fcntl.flock
    calls = []

    def flock(fd, op):
        real(fd, op)
        if not calls:  # the first holder ends right now: it removes the file
            (tmp_path / LOCK_FILE).unlink()
        calls.append(fd)

    monkeypatch.setattr(lock_module.fcntl, "flock", flock)
    with output_lock(tmp_path, "second"):
        assert len(calls) == 2  # locked the new file at the path
        assert "second" in (tmp_path / LOCK_FILE).read_text()


def _failing(job, root, **kw):
    raise ValueError(f"{job.name}: a bad scene")


@pytest.mark.parametrize("existed", [False, True])
def test_a_failed_run_leaves_no_folder_it_created(tmp_path, monkeypatch, existed):
    monkeypatch.setattr(pool, "run_job", _failing)
    root = tmp_path / "new" / "data"
    if existed:
        root.mkdir(parents=True)
    with pytest.raises(ValueError, match="a bad scene"):
        generate(tiny_jobs(1), root, workers=1, show_progress=False)
    if existed:
        assert root.is_dir() and list(root.iterdir()) == []
    else:
        assert not (tmp_path / "new").exists()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.timeout(120)
@pytest.mark.parametrize("workers", [1, 2])
def test_sigterm_stops_the_run_says_so_and_leaves_no_work_folders(tmp_path, workers):
    root = tmp_path / "data"
    # long pattern scenes (minutes each), stopped once every worker has started one
    cmd = [sys.executable, "-m", "pipelines.cli", "generate", "rllr", "--pattern", "--count", "2", "--steps",
           "100000", "--gt-stride", "99999", "--height", "128", "--width", "128", "--quiet", "--workers", str(workers),
           "-o", str(root)]
    run = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    kids = []
    try:
        deadline = time.monotonic() + 60
        while len(list(root.glob(".rllr_*.work"))) < workers:
            assert time.monotonic() < deadline and run.poll() is None, "the run did not start"
            time.sleep(0.2)
        kids = _children(run.pid)
        run.send_signal(signal.SIGTERM)
        out, err = run.communicate(timeout=30)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 143, err
    assert err.strip().splitlines()[-1].startswith("spikesim generate: terminated (SIGTERM): the scenes in progress")
    deadline = time.monotonic() + 5
    while any(_running(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [k for k in kids if _running(k)], "workers kept running"
    assert not root.exists()  # it created the folder and nothing in it was finished


def test_a_sigterm_wrapped_by_a_library_is_still_a_termination():
    import os
    import signal

    from spikesim.signals import Terminated, sigterm_raises

    def library_call():  # what Dr.Jit's frozen functions do with an exception raised inside them
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(10 ** 7):
                pass
        except BaseException as exc:
            raise RuntimeError("FlatVariables::assign(): error encountered while processing an argument") from exc

    with pytest.raises(Terminated, match="terminated"):
        with sigterm_raises():
            library_call()
    with pytest.raises(RuntimeError):  # without a signal a library's error stays what it is
        with sigterm_raises():
            raise RuntimeError("a real failure")
