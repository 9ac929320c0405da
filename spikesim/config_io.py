"""Configuration files: one loader for every config dataclass (camera, exposure, render settings).

JSON or TOML by suffix; every error names the file, so a typo in a config never surfaces as a
bare KeyError deep inside a pipeline.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, TypeVar

T = TypeVar("T")


def read_json_object(path: str | Path, what: str) -> dict[str, Any]:
    """A JSON file that must hold an object (a sidecar, a cache file, a description); otherwise a
    ValueError that names `what` and the file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"{what} {path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{what} {path} is not a JSON object")
    return data


def read_config_file(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise FileNotFoundError(f"config {path}: {exc.strerror}") from exc
    try:
        if path.suffix == ".toml":
            import tomllib
            data = tomllib.loads(text)
        else:
            data = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"config {path} is not valid {path.suffix.lstrip('.').upper() or 'JSON'}: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"config {path}: expected a table/object at the top level, got {type(data).__name__}")
    return data


def load_config_file(path: str | Path, from_dict: Callable[[dict[str, Any]], T]) -> T:
    """Read `path` and build the config with `from_dict`; its errors are re-raised naming the file."""
    data = read_config_file(path)
    try:
        return from_dict(data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"config {path}: {exc}") from exc


def check_known_fields(cls: type, data: dict[str, Any], what: str) -> dict[str, Any]:
    """`data` unchanged if every key is a field of dataclass `cls`, else a ValueError naming them."""
    import dataclasses
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f"unknown {what} {unknown}; known: {sorted(names)}")
    return data


__all__ = ["read_config_file", "load_config_file", "check_known_fields"]
