"""What a user gets from the package itself: its version, its licence, and a command line that
says which one it is without loading every pipeline."""
from __future__ import annotations

import subprocess
import sys
from importlib import metadata
from pathlib import Path

from pipelines.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_version_prints_the_installed_distribution_version(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"spikesim {metadata.version('spikesim')}"


def test_version_does_not_load_the_pipelines(monkeypatch, capsys):
    """`--version` answers at once: no subcommand module (torch, Mitsuba) is imported for it."""
    for name in [m for m in sys.modules if m.startswith("pipelines.") and m != "pipelines.cli"]:
        monkeypatch.delitem(sys.modules, name)
    assert main(["--version"]) == 0
    assert not [m for m in sys.modules if m.startswith("pipelines.") and m not in ("pipelines.cli", "pipelines.argtypes")]


def test_the_licence_the_metadata_names_is_in_the_repository():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "spikesim contributors" in text
    assert 'license = "MIT"' in (ROOT / "pyproject.toml").read_text()


def _fresh(code: str) -> subprocess.CompletedProcess:
    """Run `code` in a new interpreter (nothing imported yet), from the checkout."""
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_the_package_exports_the_simulator_lazily_in_a_fresh_interpreter():
    """`import spikesim` stays light (no Dr.Jit) and `spikesim.Simulator` then loads it."""
    result = _fresh("import sys, spikesim; light = 'drjit' not in sys.modules; lazy = spikesim.Simulator; "
                    "from spikesim.simulate import Simulator; "
                    "print(light, lazy is Simulator, callable(spikesim.available_backends))")
    assert result.returncode == 0 and result.stdout.split() == ["True", "True", "True"], result.stderr[-2000:]


def test_the_package_version_is_the_distribution_version():
    import spikesim
    assert spikesim.__version__ == metadata.version("spikesim")


def test_the_python_floor_allows_every_standard_module_the_code_imports():
    """tomllib (camera TOML files) is new in Python 3.11: requires-python must not promise less."""
    import ast
    import tomllib
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    floor = tuple(int(x) for x in declared.removeprefix(">=").split("."))
    since = {"tomllib": (3, 11)}  # standard modules newer than 3.10 the project may import
    needed = {}
    for package in ("spikesim", "model", "pipelines", "scenes"):
        for path in (ROOT / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else []
                for name in names:
                    if name.split(".")[0] in since:
                        needed[path.relative_to(ROOT).as_posix()] = since[name.split(".")[0]]
    assert needed, "no module imports tomllib any more: drop it from `since` or lower the floor deliberately"
    too_low = {where: v for where, v in needed.items() if v > floor}
    assert not too_low, f"requires-python {declared} but {too_low} need a newer Python"


def test_the_simulator_library_imports_nothing_of_the_model():
    """Data flows one way (scene -> render -> sensor -> stream -> dataset -> model): a study that
    joins the simulator and the model sits above both, in pipelines/."""
    import ast
    from pathlib import Path
    root = Path(__file__).resolve().parents[1] / "spikesim"
    offenders = []
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            offenders += [f"{path.relative_to(root.parent)}: {n}" for n in names
                          if n.split(".")[0] in ("model", "pipelines")]
    assert offenders == []
