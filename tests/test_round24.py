"""Round twenty-four: `compare` asked to stop (SIGTERM, Ctrl-C) went on training. Each training
worker took the signal as a run does (finished its step, wrote last.pt, returned) and the pool
handed it the next run, and the parent, leaving the pool, waited for every run left; with one job,
the stopped run was reported as a config whose epochs end too early."""
from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from model import comparison
from spikesim.signals import Terminated, sigterm_raises

pytestmark = pytest.mark.timeout(120)


def _run_that_stops_on_sigterm(task: tuple[str, int]) -> int:
    """A task that takes SIGTERM as a training run does: it notes the signal, ends its step, and
    stops; else it would go on for a minute."""
    folder, i = task
    asked = []
    signal.signal(signal.SIGTERM, lambda signum, frame: asked.append(signum))
    Path(folder, f"started_{i}").write_text("")
    end = time.monotonic() + 60
    while not asked and time.monotonic() < end:
        time.sleep(0.05)
    if asked:
        raise Terminated("stopped by SIGTERM")
    return i


def test_compare_asked_to_stop_starts_no_further_run(tmp_path):
    def stop_once_two_run():
        while len(list(tmp_path.glob("started_*"))) < 2:
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGTERM)

    watcher = threading.Thread(target=stop_once_two_run, daemon=True)
    start = time.monotonic()
    with pytest.raises(Terminated):
        with sigterm_raises():
            watcher.start()
            comparison._run_parallel(_run_that_stops_on_sigterm, [(str(tmp_path), i) for i in range(5)], 2,
                                     lambda result: None)
    assert time.monotonic() - start < 45  # the runs left would take a minute each
    assert sorted(p.name for p in tmp_path.glob("started_*")) == ["started_0", "started_1"]


@pytest.mark.parametrize("signal_name,expected", [("SIGTERM", Terminated), ("SIGINT", KeyboardInterrupt)])
def test_a_run_stopped_by_a_signal_stops_the_comparison(tmp_path, monkeypatch, signal_name, expected):
    """With one job the stop came back as "config A: its 100 epochs end after 3 steps, before --steps
    10; raise its epochs", an error about the config, and the next run started."""
    import model.training

    monkeypatch.setattr(model.training, "run_training",
                        lambda *a, **k: {"steps": 3, "stopped_by": signal_name, "weights_sha256": "0"})
    task = comparison.RunTask(label="A", seed=0, experiment=None, folder=tmp_path / "A", data=[], device="cpu",
                              resume=False, init=None, steps=10, threads=1, progress=False)
    (tmp_path / "A").mkdir()
    with pytest.raises(expected) as info:
        comparison._train_task(task)
    assert info.type is expected
    assert comparison.read_compute(tmp_path / "A")["steps"] == 3  # its cost is still recorded
