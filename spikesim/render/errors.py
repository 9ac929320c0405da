"""Errors for bad scene input: each names the offending file and says what is wrong with it."""
from __future__ import annotations

from pathlib import Path


class SceneError(ValueError):
    """A scene, motion or light file that cannot be used as given.

    The message always starts with the file, so a user can fix the input without reading code.
    """

    def __init__(self, path: str | Path | None, problem: str):
        self.path = None if path is None else Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path is not None else problem)


class MotionError(SceneError):
    """A motion file that is malformed or names objects the scene does not have."""


class LightError(SceneError):
    """A light file with an unknown spectrum, a non-physical power or a malformed emitter."""


def read_json(path: str | Path, error: type[SceneError], what: str) -> object:
    """Parse a scene's JSON side file (motion, lights), or raise `error` naming the file."""
    from ..config_io import read_json_file

    path = Path(path)
    if not path.exists() and not path.is_symlink():
        raise error(path, f"{what} does not exist")
    try:
        return read_json_file(path, what)
    except OSError as exc:  # a link to nothing, no permission
        raise error(path, exc.strerror or str(exc)) from None
    except ValueError as exc:  # not a regular file, too large, not JSON, a 400-digit number
        raise error(path, str(exc).replace(f"{what} {path} ", "", 1)) from None


__all__ = ["SceneError", "MotionError", "LightError", "read_json"]
