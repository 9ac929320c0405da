"""Exit statuses of `spikesim`: documented in --help, one line and 2 for a missing resource (a
GPU backend, memory), 130 for Ctrl-C, a traceback (1) only for a bug."""
from __future__ import annotations

import sys
import types

import pytest

from pipelines import cli
from pipelines.cli import main


def fake_command(monkeypatch, func) -> None:
    """Register `spikesim fake`, which calls `func(args)`."""
    module = types.ModuleType("fake_command")

    def add_parser(sub):
        sub.add_parser("fake").set_defaults(func=func)

    module.add_parser = add_parser
    monkeypatch.setitem(sys.modules, "fake_command", module)
    monkeypatch.setitem(cli._COMMAND_MODULE, "fake", "fake_command")


def test_help_documents_the_exit_statuses(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "exit status:" in out
    for status, meaning in (("0", "success"), ("2", "bad input"), ("1", "bug"), ("130", "interrupted")):
        assert any(line.split()[:1] == [status] and meaning in line for line in out.splitlines()), out


def test_ctrl_c_is_one_line_and_130(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    fake_command(monkeypatch, interrupted)
    assert main(["fake"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "spikesim fake: interrupted"


def test_out_of_memory_is_one_line_and_2(monkeypatch, capsys):
    def huge(args):
        raise MemoryError("Unable to allocate 74.5 GiB for an array")

    fake_command(monkeypatch, huge)
    assert main(["fake"]) == 2
    assert capsys.readouterr().err.strip() == "spikesim fake: error: out of memory: Unable to allocate 74.5 GiB for an array"


def test_a_bug_keeps_its_traceback(monkeypatch):
    def bug(args):
        raise ZeroDivisionError("a bug")

    fake_command(monkeypatch, bug)
    with pytest.raises(ZeroDivisionError):  # Python prints it and exits with status 1
        main(["fake"])


def test_refused_arguments_return_2_in_process(capsys):
    assert main(["simulate", "--steps", "0"]) == 2
    assert "argument --steps" in capsys.readouterr().err


def _has_cuda() -> bool:
    from spikesim.simulate import available_backends
    return "cuda" in available_backends()


@pytest.mark.skipif(_has_cuda(), reason="this machine has CUDA")
@pytest.mark.parametrize("command", [
    "simulate --height 8 --width 16 --steps 4 --quiet --backend cuda -o {out}/s.dat",
    "golden --backend cuda",
    "tradeoff --scenes ball --light low --height 11 --width 11 --windows 1 --backend cuda -o {out}/t --quiet",
], ids=["simulate", "golden", "tradeoff"])
def test_cuda_without_a_gpu_is_one_line(command, tmp_path, capsys):
    rc = main(command.format(out=tmp_path).split())
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "error:" in lines[0] and "'cuda' is not available" in lines[0], err
    assert list(tmp_path.iterdir()) == []  # it fails before writing anything


def test_ctrl_c_while_the_command_loads_is_one_line_and_130(monkeypatch, capsys):
    def interrupted_import(command=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted_import)
    assert main(["simulate", "--steps", "5"]) == 130
    assert capsys.readouterr().err.strip() == "spikesim simulate: interrupted"
