"""Errors a user can act on. The command line prints each as one line (exit status 2) instead of
a traceback; `-v` shows the traceback."""
from __future__ import annotations


class UnavailableError(RuntimeError):
    """Something asked for is not on this machine: a Dr.Jit backend, a GPU, a cluster, an optional
    package. The message says what was asked for and what is available instead."""


class InvalidFrames(ValueError):
    """A sensor backend found NaN, infinite or negative irradiance in the frames of a call; it
    raises before any state changes, and the Simulator then names the frame."""


__all__ = ["UnavailableError", "InvalidFrames"]
