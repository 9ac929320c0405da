"""Data flows one way: scenes -> spikesim (render, sensor, stream, dataset) -> model -> pipelines.
No module imports from a package above its own, even inside a function, so a layer can be used
(and tested) without the ones that consume it."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ORDER = ["scenes", "spikesim", "model", "pipelines"]  # each may import only from those before it


def _imports(path: Path) -> list[tuple[str, int]]:
    """Every absolute module a file imports (top level or inside functions), with its line."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.module, node.lineno))
    return found


def _upstream_imports(package: str) -> list[str]:
    above = set(ORDER[ORDER.index(package) + 1:])
    return [f"{path.relative_to(ROOT)}:{line} imports {module}"
            for path in sorted((ROOT / package).rglob("*.py"))
            for module, line in _imports(path) if module.split(".")[0] in above]


@pytest.mark.parametrize("package", ORDER)
def test_no_package_imports_a_layer_above_it(package: str) -> None:
    assert _upstream_imports(package) == []


def test_the_layering_check_sees_an_upstream_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from pipelines.cli import main\n")
    assert _imports(bad) == [("pipelines.cli", 2)]


@pytest.mark.parametrize("module", ["spikesim/signals.py", "spikesim/outputs.py"])
def test_the_output_writers_sit_below_the_generators(module: str) -> None:
    """`spikesim.outputs` (every command's writer) and the SIGTERM rule it uses import nothing from
    the generation pipeline that uses them (the SIGTERM rule lived there until round fourteen)."""
    path = ROOT / module
    relative = [node.module for node in ast.walk(ast.parse(path.read_text()))
                if isinstance(node, ast.ImportFrom) and node.level > 0 and node.module]
    absolute = [name for name, _ in _imports(path)]
    assert not [m for m in relative + absolute if "generation" in m.split(".")]
