"""What a user gets from the package itself: its version, its licence, and a command line that
says which one it is without loading every pipeline."""
from __future__ import annotations

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
