"""Argument types for the command line: a bad value is refused by the parser with a message
that names the flag (argparse adds it), never silently treated as "not given".

Use them as `type=` in `add_argument`; argparse turns the `ArgumentTypeError` into
`spikesim CMD: error: argument --flag: <message>` and exit status 2.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path


def _number(text: str, kind: type) -> float | int:
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None


def positive_int(text: str) -> int:
    """An integer >= 1 (a count, a size, a step)."""
    v = _number(text, int)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return v


def nonnegative_int(text: str) -> int:
    """An integer >= 0 (an index, a start step, a seed)."""
    v = _number(text, int)
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text}")
    return v


def positive_float(text: str) -> float:
    """A finite number > 0 (a rate, a gamma, a scale)."""
    v = _number(text, float)
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return v


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    v = _number(text, float)
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return v


def existing_file(text: str) -> Path:
    """A path to a readable regular file (not a directory)."""
    p = Path(text)
    if not p.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a directory, expected a file")
    try:
        with open(p, "rb"):
            pass
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"{text}: cannot be read ({exc.strerror})") from None
    return p


__all__ = ["positive_int", "nonnegative_int", "positive_float", "nonnegative_float", "existing_file"]
