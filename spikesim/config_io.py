"""Configuration files: one loader for every config dataclass (camera, exposure, render settings).

JSON or TOML by suffix; every error names the file, so a typo in a config never surfaces as a
bare KeyError deep inside a pipeline.
"""
from __future__ import annotations

import errno
import json
import math
import os
import stat
from pathlib import Path
from typing import Any, Callable, TypeVar

T = TypeVar("T")

#: The most a small text file the tools read (a sidecar, a config, a camera, a light or motion
#: file, a record) may hold: they are a few KiB; a larger one is not what it claims to be.
SMALL_FILE_LIMIT = 1 << 20
#: Integers with more digits than this in a config are refused (2**128, the widest seed, has 39).
MAX_INT_DIGITS = 40

_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


def file_problem(path: str | Path) -> str | None:
    """None for an existing regular file (symlinks followed), else what it is instead, in words:
    "does not exist", "is a FIFO (named pipe), not a regular file", ... A FIFO or device handed
    to a reader blocks or never ends, so callers refuse it by this rather than call it missing."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "does not exist" + (" (a symlink to nothing)" if os.path.islink(path) else "")
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if stat.S_ISREG(mode):
        return None
    kind = next((name for test, name in _KINDS if test(mode)), "not a plain file")
    return f"is {kind}, not a regular file"


def read_small_file(path: str | Path, what: str, limit: int = SMALL_FILE_LIMIT) -> str:
    """The UTF-8 text of a small regular file, read whole; otherwise an error naming `what` and the file.

    A FIFO, a device (/dev/zero), a socket or a directory is refused before anything is read (a
    FIFO would block forever, /dev/zero never ends), and so is a file over `limit` bytes (checked
    on the bytes read, so a file that grows while read cannot slip past it)."""
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a FIFO's open would block
    except FileNotFoundError:
        raise FileNotFoundError(errno.ENOENT, f"{what} does not exist", str(path)) from None
    except OSError as exc:
        raise OSError(exc.errno, f"{what}: {exc.strerror}", str(path)) from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = next((name for test, name in _KINDS if test(mode)), "not a plain file")
            raise ValueError(f"{what} {path} is {kind}, not a regular file; give a regular file")
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(limit + 1)
    finally:
        os.close(fd)
    if len(data) > limit:
        size = f"{limit / 2**20:g} MiB" if limit >= 2**20 else f"{limit / 2**10:g} KiB"
        raise ValueError(f"{what} {path} is larger than {size}, too large for {what}: "
                         "it is not the small text file expected")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{what} {path} is not UTF-8 text") from None


def check_numbers(data: Any, where: str, finite: bool = True, _field: str = "") -> None:
    """Refuse integers of more than MAX_INT_DIGITS digits and (with `finite`) NaN or infinite
    numbers anywhere in parsed JSON/TOML, naming the field (`a.b[2]`): no setting needs them, and
    a 400-digit integer overflows every float conversion after it. Data nested deeper than
    MAX_NESTING (a damaged or hostile checkpoint's stored config) is refused first: walking it
    would exhaust the interpreter's recursion."""
    if not _field and nesting_depth(data) > MAX_NESTING:
        raise ValueError(f"{where}: nested deeper than {MAX_NESTING} levels; no setting nests that deep "
                         "(the file is damaged or not a config)")
    if isinstance(data, dict):
        for k, v in data.items():
            check_numbers(v, where, finite, f"{_field}.{k}" if _field else str(k))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            check_numbers(v, where, finite, f"{_field}[{i}]")
    elif isinstance(data, int) and not isinstance(data, bool):
        if abs(data) >= 10 ** MAX_INT_DIGITS:
            digits = int(abs(data).bit_length() * math.log10(2)) + 1
            raise ValueError(f"{where}: {_field or 'the value'} is an integer of about {digits} digits; "
                             "no setting takes numbers that large")
    elif isinstance(data, float) and finite and not math.isfinite(data):
        raise ValueError(f"{where}: {_field or 'the value'} is {data}; numbers must be finite")


#: The deepest nesting of objects and arrays a small file may have: no setting nests more than a
#: few levels, and a file nested ~1000 deep made the parsers raise RecursionError (a traceback).
MAX_NESTING = 64


def nesting_depth(data: Any) -> int:
    """How deeply lists and dicts nest in parsed data (0 for a scalar), without recursion."""
    depth, stack = 0, [(data, 1)]
    while stack:
        item, d = stack.pop()
        if isinstance(item, (dict, list)):
            depth = max(depth, d)
            stack.extend((v, d + 1) for v in (item.values() if isinstance(item, dict) else item))
    return depth


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object, refusing a key given twice (the last would win silently; TOML refuses it too)."""
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"the key {k!r} is given twice")
        out[k] = v
    return out


def parse_text(text: str, where: str, toml: bool = False) -> Any:
    """JSON (or TOML) text parsed, nesting bounded by MAX_NESTING: the one parser of every small
    file (configs, records, sidecars, manifests, meta.json), so none can crash a command with a
    RecursionError. Syntax errors stay ValueErrors for the caller to word."""
    try:
        if toml:
            import tomllib
            data = tomllib.loads(text)
        else:
            data = json.loads(text, object_pairs_hook=_unique_keys)
    except RecursionError:
        raise ValueError(f"{where}: nested deeper than {MAX_NESTING} levels (no setting needs that)") from None
    if nesting_depth(data) > MAX_NESTING:
        raise ValueError(f"{where}: nested deeper than {MAX_NESTING} levels (no setting needs that)")
    return data


def standard_json(doc: Any, **dumps: Any) -> str:
    """`doc` as standard JSON text: a NaN or infinite number (a perfect frame's PSNR, an undefined
    statistic) becomes null, and a top-level "non_finite" object says what each was
    ({"scores.TFP.psnr": "inf"}), since JSON has no NaN or Infinity and strict readers refuse them."""
    notes: dict[str, str] = {}

    def clean(item: Any, where: str) -> Any:
        if isinstance(item, dict):
            return {k: clean(v, f"{where}.{k}" if where else str(k)) for k, v in item.items()}
        if isinstance(item, (list, tuple)):
            return [clean(v, f"{where}[{i}]") for i, v in enumerate(item)]
        if isinstance(item, float) and not math.isfinite(item):
            notes[where or "value"] = str(item)
            return None
        return item

    out = clean(doc, "")
    if notes and isinstance(out, dict):
        out = {**out, "non_finite": notes}
    return json.dumps(out, allow_nan=False, **dumps)


def read_json_file(path: str | Path, what: str, limit: int = SMALL_FILE_LIMIT, finite: bool = True) -> Any:
    """Parsed JSON of a small regular file (`read_small_file`), numbers checked (`check_numbers`);
    errors name `what` and the file."""
    text = read_small_file(path, what, limit)
    try:
        data = parse_text(text, f"{what} {path}")
    except ValueError as exc:
        if str(exc).startswith(f"{what} {path}:"):
            raise
        raise ValueError(f"{what} {path} is not valid JSON: {exc}") from None
    check_numbers(data, f"{what} {path}", finite)
    return data


def read_json_object(path: str | Path, what: str, finite: bool = True, limit: int = SMALL_FILE_LIMIT) -> dict[str, Any]:
    """A JSON file that must hold an object (a sidecar, a cache file, a description); otherwise a
    ValueError that names `what` and the file."""
    data = read_json_file(path, what, limit, finite)
    if not isinstance(data, dict):
        raise ValueError(f"{what} {path} is not a JSON object")
    return data


def read_config_file(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    text = read_small_file(path, "config")
    try:
        data = parse_text(text, f"config {path}", toml=path.suffix == ".toml")
    except ValueError as exc:
        if str(exc).startswith(f"config {path}:"):
            raise
        raise ValueError(f"config {path} is not valid {path.suffix.lstrip('.').upper() or 'JSON'}: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"config {path}: expected a table/object at the top level, got {type(data).__name__}")
    check_numbers(data, f"config {path}")
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


__all__ = ["read_config_file", "load_config_file", "check_known_fields", "read_small_file", "read_json_file",
           "read_json_object", "check_numbers", "SMALL_FILE_LIMIT", "file_problem"]
