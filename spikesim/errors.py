"""Errors a user can act on. The command line prints each as one line (exit status 2) instead of
a traceback; `-v` shows the traceback."""
from __future__ import annotations


class UnavailableError(RuntimeError):
    """Something asked for is not on this machine: a Dr.Jit backend, a GPU, a cluster, an optional
    package. The message says what was asked for and what is available instead."""


__all__ = ["UnavailableError"]
