"""docs/CONTRACTS.md agrees with the code: every name it lists imports, and every signature it
writes out names real parameters, in their order, with the defaults the code has.

Conventions the doc follows (so that this test can read it):
- a section heading names its modules in backticks: "## Spike streams (`spikesim.stream`)";
- a name is resolved in those modules (`read_dat`), from a package (`spikesim.stream.read_dat`),
  through a module of the section's package (`camera.Y_MAX`), or as a method of the last class
  named in the same bullet (`.unpack(...)`); `sim.` stands for a `Simulator`;
- `f(a, b=1, c="x"|"y")` lists parameters in order; a literal default is compared with the code's
  (the first of "x"|"y" alternatives); `...` means "more parameters follow" (the code's required
  parameters are then not all listed); `f(...)` states no parameters.
"""
from __future__ import annotations

import ast
import importlib
import inspect
import re
from pathlib import Path
from typing import Any

import pytest

DOC = Path(__file__).resolve().parents[1] / "docs" / "CONTRACTS.md"
PACKAGES = ("spikesim", "model", "pipelines", "scenes")
#: Instance names the doc uses for readability.
INSTANCES = {"sim": "spikesim.simulate.Simulator"}
CALL = re.compile(r"^(?P<name>\.?[A-Za-z_][\w.]*)\((?P<args>[^()]*(?:\([^()]*\)[^()]*)*)\)(?:\s*->.*)?$")
NAME = re.compile(r"^[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*$")
MISSING = object()


def sections(text: str) -> list[tuple[list[str], list[str]]]:
    """(modules named in the heading, bullets) per `## ` section."""
    out = []
    for block in re.split(r"^## ", text, flags=re.M)[1:]:
        heading, _, body = block.partition("\n")
        modules = re.findall(r"`([\w.]+)`", heading)
        bullets, current = [], []
        for line in body.splitlines():
            if line.startswith("- ") and current:
                bullets.append(" ".join(current))
                current = []
            if line.strip() and not line.startswith("```"):
                current.append(line.strip())
        if current:
            bullets.append(" ".join(current))
        out.append((modules, bullets))
    return out


def attr_chain(obj: Any, parts: list[str]) -> Any:
    for part in parts:
        obj = getattr(obj, part, MISSING)
        if obj is MISSING:
            return MISSING
    return obj


def import_qualified(dotted: str) -> Any:
    """`pkg.mod.attr.attr` -> the object, importing the longest module prefix."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            module = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        return attr_chain(module, parts[cut:])
    return MISSING


def resolve(name: str, modules: list[str], current: Any) -> Any:
    if name.startswith("."):
        return MISSING if current is None else attr_chain(current, name[1:].split("."))
    first, *rest = name.split(".")
    if first in INSTANCES:
        return attr_chain(import_qualified(INSTANCES[first]), rest)
    if first in PACKAGES:
        return import_qualified(name)
    for module in modules:
        found = import_qualified(f"{module}.{name}")
        if found is MISSING and "." in module:  # `camera.Y_MAX` in a section on `spikesim.camera`
            found = import_qualified(f"{module.rsplit('.', 1)[0]}.{name}")
        if found is not MISSING:
            return found
    return MISSING


def split_args(text: str) -> list[str]:
    """Top-level comma-separated pieces (brackets and quotes kept whole)."""
    pieces, depth, quote, start = [], 0, None, 0
    for i, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == "," and depth == 0:
            pieces.append(text[start:i].strip())
            start = i + 1
    pieces.append(text[start:].strip())
    return [p for p in pieces if p]


def documented_default(text: str) -> Any:
    """The literal default the doc states (first of `"a"|"b"`), or MISSING when it is prose."""
    first = text.split("|")[0].strip() if re.fullmatch(r'(\s*"[^"]*"\s*\|?)+', text) else text
    try:
        value = ast.literal_eval(first)
    except (ValueError, SyntaxError):
        return MISSING
    return MISSING if value is Ellipsis else value


def signature_problems(span: str, obj: Any, args: str) -> list[str]:
    if args.strip() in ("", "..."):
        return []
    try:
        params = inspect.signature(obj).parameters
    except (TypeError, ValueError):
        return [f"`{span}`: no signature to check"]
    names = [n for n, p in params.items() if n != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    problems, order, more = [], [], False
    for piece in split_args(args):
        if piece == "...":
            more = True
            continue
        name, eq, default = piece.partition("=")
        name = name.strip()
        if name not in names:
            problems.append(f"`{span}`: no parameter {name!r} (the code has {names})")
            continue
        order.append(names.index(name))
        want = documented_default(default) if eq else MISSING
        have = params[name].default
        if want is not MISSING and have != want:
            problems.append(f"`{span}`: {name} defaults to {have!r} in the code, {want!r} in the doc")
    if order != sorted(order):
        problems.append(f"`{span}`: parameters out of the code's order {names}")
    required = [n for n in names if params[n].default is inspect.Parameter.empty]
    listed = {names[i] for i in order}
    if not more and not set(required) <= listed:
        problems.append(f"`{span}`: required parameter(s) {sorted(set(required) - listed)} not listed")
    return problems


def checked_spans(text: str) -> tuple[list[str], list[str]]:
    """(every span checked, the problems found)."""
    checked, problems = [], []
    for modules, bullets in sections(text):
        for bullet in bullets:
            current = None
            for span in re.findall(r"`([^`]+)`", bullet):
                call = CALL.match(span)
                name = call["name"] if call else span
                if not call and not (NAME.match(span) and (span.split(".")[0] in PACKAGES | INSTANCES.keys()
                                                           or span[0].isupper() or "." in span and
                                                           any(m.endswith("." + span.split(".")[0]) for m in modules))):
                    continue  # a value, a field or a file name, not an API name
                if not call and span in modules:
                    continue
                obj = resolve(name, modules, current)
                checked.append(span)
                if obj is MISSING:
                    problems.append(f"`{span}`: not found in {modules or 'any module'}")
                    continue
                owner = resolve(name.rsplit(".", 1)[0], modules, current) if "." in name.lstrip(".") else None
                if inspect.isclass(obj):
                    current = obj
                elif inspect.isclass(owner):  # `SceneRecord.open(path)`: later `.name`s are SceneRecord's
                    current = owner
                if call:
                    problems += signature_problems(span, obj, call["args"])
    return checked, problems


def test_every_name_and_signature_in_the_contracts_agrees_with_the_code():
    checked, problems = checked_spans(DOC.read_text())
    assert len(checked) > 40, f"the doc's conventions changed? only {len(checked)} spans checked"
    assert not problems, "docs/CONTRACTS.md disagrees with the code:\n" + "\n".join(problems)


@pytest.mark.parametrize("doc, problem", [
    ("## S (`spikesim.stream`)\n- `read_dat(path, height=None, width=None, header_columns=16)`\n", "defaults to 0"),
    ("## S (`spikesim.stream`)\n- `read_dat(path, num_steps=5)`\n", "no parameter 'num_steps'"),
    ("## S (`spikesim.stream`)\n- `read_dat(height=250, path)`\n", "out of the code's order"),
    ("## S (`spikesim.stream`)\n- `detect_header_columns(path, height)`\n", "['width'] not listed"),
    ("## S (`spikesim.stream`)\n- `read_everything(path)`\n", "not found"),
    ("## S (`spikesim.stream`)\n- `SpikeStream`: `.unpacked(start=0)`\n", "not found"),
    ("## S (`spikesim.simulate`)\n- `sim.run(frames, keyframe_every=2)`\n", "defaults to 1"),
    ("## S (`spikesim.simulate`)\n- `Simulator(camera, backend=\"numpy\"|\"auto\")`\n", "defaults to 'auto'"),
])
def test_the_check_finds_each_kind_of_disagreement(doc, problem):
    checked, problems = checked_spans(doc)
    assert checked and any(problem in p for p in problems), problems


def test_the_check_accepts_what_agrees():
    doc = ("## S (`spikesim.stream`, `spikesim.camera`)\n- `SpikeStream`: `.unpack(start=0, stop=None)`,"
           " `read_dat(path, height=None, ..., header_columns=0)`, `camera.Y_MAX`, `write_dat(...)`, `meta.json`\n")
    checked, problems = checked_spans(doc)
    assert not problems and len(checked) == 5, (checked, problems)
