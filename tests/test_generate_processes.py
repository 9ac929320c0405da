"""Processes around `generate`: one run per output folder (a lock that names its holder and that a
dead process cannot leave behind), and workers that die with their parent."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipelines.cli import main
from spikesim.generation.lock import output_lock
from spikesim.dataset import LOCK_FILE

REPO = Path(__file__).resolve().parents[1]
TINY = ["rllr", "--pattern", "--count", "1", "--steps", "10", "--gt-stride", "9", "--height", "8", "--width", "8",
        "--workers", "1", "--quiet"]


def test_a_second_run_on_a_locked_folder_fails_at_once_naming_the_holder(tmp_path, capsys):
    root = tmp_path / "data"
    root.mkdir()
    with output_lock(root, "spikesim generate llr -o data"):
        t0 = time.monotonic()
        assert main(["generate", *TINY, "-o", str(root)]) == 2
        assert time.monotonic() - t0 < 5
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert f"pid {os.getpid()}" in err and "spikesim generate llr -o data" in err and str(root) in err
    assert sorted(p.name for p in root.iterdir()) == []  # nothing generated, and the lock is gone with its holder
    assert main(["generate", *TINY, "-o", str(root)]) == 0  # released with the context


def test_the_lock_file_is_readable_and_keeps_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        with output_lock(tmp_path, "cmd"):
            text = (tmp_path / LOCK_FILE).read_text()
            mode = (tmp_path / LOCK_FILE).stat().st_mode & 0o777
    finally:
        os.umask(old)
    assert f"pid {os.getpid()}" in text and "cmd" in text
    assert mode == 0o644


def test_a_lock_left_by_a_killed_process_does_not_block(tmp_path):
    root = tmp_path / "data"
    root.mkdir()
    code = ("import sys, time; from spikesim.generation.lock import output_lock\n"
            "with output_lock(sys.argv[1], 'holder'):\n    print('locked', flush=True); time.sleep(60)\n")
    holder = subprocess.Popen([sys.executable, "-c", code, str(root)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(OSError, match=f"pid {holder.pid}"):
            with output_lock(root, "second"):
                pass
    finally:
        holder.kill()
        holder.wait()
    assert f"pid {holder.pid}" in (root / LOCK_FILE).read_text()  # the dead holder's record is still there
    assert main(["generate", *TINY, "-o", str(root)]) == 0


def _children(pid):
    """Process ids whose parent is `pid` (Linux /proc)."""
    kids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                kids.append(int(d.name))
    return kids


def _running(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.timeout(120)
def test_workers_die_when_the_parent_is_killed(tmp_path):
    root = tmp_path / "data"
    # two long pattern scenes in two workers (about a minute each), killed once both have started
    cmd = [sys.executable, "-m", "pipelines.cli", "generate", "rllr", "--pattern", "--count", "2", "--workers", "2",
           "--steps", "100000", "--gt-stride", "99999", "--height", "128", "--width", "128", "--quiet", "-o", str(root)]
    parent = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    kids = []
    try:
        deadline = time.monotonic() + 60
        while len(list(root.glob(".rllr_*.work"))) < 2:
            assert time.monotonic() < deadline and parent.poll() is None, "the workers did not start"
            time.sleep(0.2)
        kids = _children(parent.pid)
        assert kids
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 5
        while any(_running(k) for k in kids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [k for k in kids if _running(k)], "workers outlived their parent"
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        for k in kids:
            if _running(k):
                os.kill(k, signal.SIGKILL)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_parent_watchdog_alone_ends_an_orphaned_worker(tmp_path):
    # The portable fallback (no prctl, as off Linux): a grandchild that polls its parent's pid
    # exits once its parent is SIGKILLed.
    worker = ("import os, sys, time; sys.platform = 'darwin'\n"
              "from spikesim.generation.pool import die_with_parent\n"
              "die_with_parent(os.getppid(), poll_s=0.1); print('ready', flush=True); time.sleep(60)\n")
    parent_code = ("import subprocess, sys, time\n"
                   "w = subprocess.Popen([sys.executable, '-c', sys.argv[1]], stdout=subprocess.PIPE, text=True)\n"
                   "assert w.stdout.readline().strip() == 'ready'\n"
                   "print(w.pid, flush=True); time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", parent_code, worker], cwd=REPO, stdout=subprocess.PIPE, text=True)
    pid = None
    try:
        pid = int(parent.stdout.readline())
        assert _running(pid)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 3
        while _running(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _running(pid), "the orphaned worker kept running"
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        if pid is not None and _running(pid):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_a_worker_killed_from_outside_is_one_line_and_the_finished_scenes_stay(tmp_path):
    """The kernel's out-of-memory killer ends a worker: generate says so in one MemoryError (the
    CLI's one-line exit 2) naming the scenes, and keeps every finished scene for a rerun."""
    import threading

    from spikesim.dataset import scene_folders
    from spikesim.generation import PRESETS, generate, plan_rllr

    preset = PRESETS["small"].replace(height=64, width=64, rllr_steps=40_000, rllr_gt_stride=41)
    jobs = plan_rllr(preset, seed=1, count=6, source="pattern")

    def workers() -> list[int]:
        found = []
        for pid in os.listdir("/proc"):
            try:
                stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
            except (OSError, IndexError):
                continue
            if int(stat[1]) == os.getpid() and b"spawn_main" in cmd:
                found.append(int(pid))
        return found

    def kill_a_worker_after_the_first_scene() -> None:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not scene_folders(tmp_path):
            time.sleep(0.05)
        for pid in workers()[:1]:
            os.kill(pid, signal.SIGKILL)

    killer = threading.Thread(target=kill_a_worker_after_the_first_scene, daemon=True)
    killer.start()
    with pytest.raises(MemoryError, match="worker process was killed while on rllr_.*run the same command again"):
        generate(jobs, tmp_path, workers=2, show_progress=False)
    killer.join()
    assert 1 <= len(scene_folders(tmp_path)) < 6
