"""The default torch thread count: the cores not busy now (model/threads.py; the measurement it
rests on is in docs/performance.md, "Threads")."""
from __future__ import annotations

import math

import pytest
import torch

from model.threads import free_cores, set_cpu_threads


@pytest.mark.parametrize("cores, load, expected", [
    (2, 0.0, 2), (2, 0.4, 2), (2, 0.6, 1), (2, 1.3, 1), (2, 7.0, 1), (16, 3.2, 13), (1, 0.0, 1),
    (4, math.nan, 4), (4, -1.0, 4),
])
def test_free_cores_takes_only_cores_that_are_not_busy(cores, load, expected):
    assert free_cores(cores, load) == expected


def test_set_cpu_threads_uses_a_given_count_and_restores(monkeypatch):
    before = torch.get_num_threads()
    try:
        assert set_cpu_threads(1).startswith("1 thread(s), as asked")
        assert torch.get_num_threads() == 1
        monkeypatch.setattr("model.threads._cores", lambda: 2)
        monkeypatch.setattr("model.threads._load_1min", lambda: 1.3)  # one other busy process
        reason = set_cpu_threads(0)
        assert torch.get_num_threads() == 1 and "2 cores, load average 1.3" in reason and "--threads" in reason
        from model.threads import describe_threads
        assert describe_threads() == reason
        torch.set_num_threads(2)
        assert describe_threads() == "2 thread(s)"  # changed behind its back: the count, no stale reason
        for bad in (-1, 99999):  # 99999 crashed the process (round nine)
            with pytest.raises(ValueError, match="threads must be 0 to 1024"):
                set_cpu_threads(bad)
    finally:
        torch.set_num_threads(before)


def test_train_help_says_how_the_default_is_chosen(capsys):
    from pipelines.cli import main
    assert main(["train", "--help"]) == 0 and "cores not busy" in " ".join(capsys.readouterr().out.split())
