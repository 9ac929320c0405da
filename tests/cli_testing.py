"""Helpers for tests that run the command line in-process (a uniquely named module: sub-folders
have their own conftest.py, so `from conftest import ...` would be ambiguous)."""
from __future__ import annotations

from pipelines.cli import main


def run_cli(argv, capsys) -> tuple[int, str]:
    """Exit status and stderr of one in-process run (main returns argparse's status too)."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    return rc, capsys.readouterr().err


def one_line(err: str) -> str:
    """The single line on stderr, asserting there is exactly one and no traceback."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]
