"""A camera file to start from: every `SpikeCamera` field with its value, unit, meaning and the
published default, as commented TOML (`spikesim camera --write mine.toml`).

The comments are the fields' own docstrings in spikesim/camera.py, read from its source, so the
file and the code cannot say different things. Geometry (height, width) is written commented
out: without it a command takes the frame size from the scene's film or the dataset preset; with
it, the file's size wins over those and `--height/--width` over the file.
"""
from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
from typing import Any

from .camera import SpikeCamera

#: Fields the written file leaves commented out (the frame size is the scene's or the preset's).
GEOMETRY_FIELDS = ("height", "width")


def field_docs() -> dict[str, str]:
    """Each SpikeCamera field's docstring (the string literal right after its annotation)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(SpikeCamera)))
    body = tree.body[0].body
    docs: dict[str, str] = {}
    for stmt, nxt in zip(body, body[1:]):
        if (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and isinstance(nxt, ast.Expr)
                and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str)):
            docs[stmt.target.id] = " ".join(nxt.value.value.split())
    return docs


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    raise TypeError(f"no TOML form for {value!r}")


def camera_toml(camera: SpikeCamera | None = None, preset: str = "realistic") -> str:
    """The commented TOML text of `camera` (default: the `preset`'s), every field present."""
    camera = camera or SpikeCamera.preset(preset)
    default = SpikeCamera()
    docs = field_docs()
    lines = ["# A spike camera for spikesim (SpikeCamera fields; docs/sensor.md explains each term).",
             "# Light and charge are in thresholds: y is the expected number of spikes per readout step.",
             "# A noise term set to 0 (shot_noise = \"off\", random_initial_state = false) is switched off",
             "# and left out of the simulation. Use it with --camera FILE in simulate, generate, demo",
             "# and golden.", ""]
    for f in dataclasses.fields(SpikeCamera):
        value, published = getattr(camera, f.name), getattr(default, f.name)
        doc = docs.get(f.name, "")
        for text in textwrap.wrap(doc, 96):
            lines.append(f"# {text}")
        note = "" if value == published else f"  # the published value: {_toml_value(published)}"
        if f.name in GEOMETRY_FIELDS:
            lines.append(f"# {f.name} = {_toml_value(value)}   (uncomment to fix the frame size; else the scene's film "
                         f"or the preset's, and --{f.name} wins over both)")
        else:
            lines.append(f"{f.name} = {_toml_value(value)}{note}")
        lines.append("")
    return "\n".join(lines)
