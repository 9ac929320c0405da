"""The repository stands alone: no tracked file cites a document or a path users do not have.

A design note kept outside the repository (the upper-case design notes file) and a folder beside the checkout
(`../shared`) are not part of what users get; the facts once cited from them live in docs/
(docs/design.md above all), and a citation must point there.
"""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
THIS = Path(__file__).resolve()

#: Citations of files outside the repository. Case-sensitive: docs/design.md is fine.
#: The outside design note's file name, spelt so that this file does not match itself.
NOTE_NAME = "DES" + "IGN.md"
FORBIDDEN = re.compile(re.escape(NOTE_NAME) + r"|\.\.[/\\]shared\b")


def tracked_files() -> list[Path]:
    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    result = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True)
    if result.returncode != 0:
        pytest.skip(f"not a git checkout: {result.stderr.decode(errors='replace').strip()}")
    return [ROOT / name for name in result.stdout.decode().split("\0") if name]


def text_of(path: Path) -> str | None:
    """The file's text, or None for binary files and files missing from the working tree."""
    try:
        data = path.read_bytes()
    except (FileNotFoundError, IsADirectoryError, PermissionError):
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def citations(paths: list[Path]) -> list[str]:
    hits = []
    for path in paths:
        if path.resolve() == THIS:
            continue
        text = text_of(path)
        if text is None:
            continue
        for lineno, line in enumerate(text.splitlines(), 1):
            if FORBIDDEN.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{lineno}: {line.strip()}")
    return hits


def test_no_tracked_file_cites_files_outside_the_repository():
    files = tracked_files()
    assert len(files) > 10, "git ls-files listed almost nothing: is this the repository root?"
    hits = citations(files)
    assert not hits, (f"these lines cite files users do not have ({NOTE_NAME} or ../shared); cite the "
                      "docs/ page that holds the fact, e.g. docs/design.md section N:\n" + "\n".join(hits))


def test_the_check_finds_a_citation(tmp_path):
    """The pattern catches both kinds of citation and leaves docs/design.md alone."""
    bad = tmp_path / "bad.py"
    bad.write_text(f"# the rate is y + d ({NOTE_NAME} section 2)\nDATA = '../shared/data'\n")
    good = tmp_path / "good.py"
    good.write_text("# the rate is y + d (docs/design.md section 2)\n")
    binary = tmp_path / "blob.bin"
    binary.write_bytes(b"\0" + NOTE_NAME.encode())
    found = [FORBIDDEN.search(line) is not None for line in bad.read_text().splitlines()]
    assert found == [True, True]
    assert FORBIDDEN.search(good.read_text()) is None
    assert text_of(binary) is None
