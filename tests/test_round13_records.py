"""Round thirteen (docs/robustness.md): the results record under `spikesim.outputs.results_writing`.
Two commands writing one folder at once no longer mix their results (the block holds the folder's
record lock), a record of many entries is still read, a record that cannot be read is refused
rather than rewritten, and SIGTERM inside the block leaves no temporary file or lock."""
from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
import signal
import time
from pathlib import Path

import pytest

from spikesim import outputs
from spikesim.outputs import RESULTS_LOCK, RESULTS_RECORD, atomic_write_text, results_writing

NAMES = ["metrics.csv", "metrics.md"]


def _run(out: str, tag: str, entered, go_on, pause_s: float) -> None:
    """One 'evaluate': writes metrics.csv, pauses (a slow write), then metrics.md, both tagged."""
    with results_writing(out, NAMES, "evaluate"):
        atomic_write_text(Path(out) / "metrics.csv", f"csv of {tag}\n")
        if entered is not None:
            entered.set()
        if go_on is not None:
            go_on.wait(10)
        time.sleep(pause_s)
        atomic_write_text(Path(out) / "metrics.md", f"md of {tag}\n")


def test_two_writers_into_one_folder_never_mix_their_results(tmp_path):
    ctx = mp.get_context("fork")
    entered = ctx.Event()
    a = ctx.Process(target=_run, args=(str(tmp_path), "A", entered, None, 1.0))
    a.start()
    assert entered.wait(20)
    # B starts while A is between its two results; it waits for A's block, then writes its own pair
    b = ctx.Process(target=_run, args=(str(tmp_path), "B", None, None, 0.0))
    b.start()
    a.join(30)
    b.join(30)
    assert a.exitcode == 0 and b.exitcode == 0
    csv, md = (tmp_path / "metrics.csv").read_text(), (tmp_path / "metrics.md").read_text()
    assert csv.split()[-1] == md.split()[-1] == "B", (csv, md)  # one run whole: the one that wrote last
    record = json.loads((tmp_path / RESULTS_RECORD).read_text())["files"]
    for name in NAMES:
        assert record[name]["sha256"] == hashlib.sha256((tmp_path / name).read_bytes()).hexdigest()
    assert not (tmp_path / RESULTS_LOCK).exists()


def test_a_record_of_thousands_of_entries_is_read_and_kept(tmp_path):
    files = {}
    for i in range(7000):  # about 1.2 MiB: over the 1 MiB a small file may hold
        name = f"preview_of_recording_number_{i:06d}_with_a_descriptive_suffix.png"
        data = f"png {i}".encode()
        (tmp_path / name).write_bytes(data)
        files[name] = {"command": "inspect", "sha256": hashlib.sha256(data).hexdigest()}
    (tmp_path / RESULTS_RECORD).write_text(json.dumps({"files": files}, indent=1) + "\n")
    assert (tmp_path / RESULTS_RECORD).stat().st_size > 2**20
    own = "preview_of_recording_number_000001_with_a_descriptive_suffix.png"
    with results_writing(tmp_path, [own], "inspect", "--preview"):  # its own earlier result: replaced
        atomic_write_text(tmp_path / own, "new png")
    with results_writing(tmp_path, ["new_one.png"], "inspect", "--preview"):
        atomic_write_text(tmp_path / "new_one.png", "png")
    record = json.loads((tmp_path / RESULTS_RECORD).read_text())["files"]
    assert len(record) == 7001 and record[own]["sha256"] == hashlib.sha256(b"new png").hexdigest()


@pytest.mark.parametrize("text", ["my own notes, not JSON\n", '{"notes": "mine"}\n'])
def test_a_record_that_cannot_be_read_is_refused_and_left_as_it_was(tmp_path, text):
    (tmp_path / RESULTS_RECORD).write_text(text)
    with pytest.raises(ValueError, match=r"\.spikesim-results\.json.*move it away"):
        with results_writing(tmp_path, ["metrics.csv"], "evaluate"):
            atomic_write_text(tmp_path / "metrics.csv", "x")
    assert (tmp_path / RESULTS_RECORD).read_text() == text and not (tmp_path / "metrics.csv").exists()


def test_sigterm_while_writing_results_leaves_no_temporary_file_or_lock(tmp_path):
    from spikesim.signals import Terminated

    def write(tmp: Path) -> None:
        tmp.write_text("half")
        os.kill(os.getpid(), signal.SIGTERM)  # as `kill PID` while the result is being written
        time.sleep(1)

    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Terminated):
        with results_writing(tmp_path, ["metrics.md"], "evaluate"):
            outputs.atomic_write_with(tmp_path / "metrics.md", write)
    assert signal.getsignal(signal.SIGTERM) == previous
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != RESULTS_RECORD) == []
