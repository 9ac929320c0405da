"""A file written in place (a lock, a log, an appended CSV) is refused when it has another name:
writing through a hard link planted at its name would change a file outside the output
(docs/CONTRACTS.md, "Output paths")."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from spikesim import outputs


@pytest.fixture()
def victim(tmp_path):
    v = tmp_path / "victim.txt"
    v.write_text("the user's own text\n")
    return v


@pytest.mark.parametrize("mode", ["ab", "wb"])
def test_open_in_place_refuses_a_hard_link_and_leaves_it_untouched(tmp_path, victim, mode):
    out = tmp_path / "out"
    out.mkdir()
    os.link(victim, out / "run.log")
    with pytest.raises(ValueError, match="has 2 names"):
        outputs.open_in_place(out / "run.log", mode)
    assert victim.read_text() == "the user's own text\n"


def test_append_text_refuses_a_hard_link_and_appends_to_a_plain_file(tmp_path, victim):
    os.link(victim, tmp_path / "log.csv")
    with pytest.raises(ValueError, match="hard links"):
        outputs.append_text(tmp_path / "log.csv", "row\n")
    assert victim.read_text() == "the user's own text\n"
    outputs.append_text(tmp_path / "fresh.csv", "a\n")
    outputs.append_text(tmp_path / "fresh.csv", "b\n")
    assert (tmp_path / "fresh.csv").read_text() == "a\nb\n"


def test_open_in_place_truncates_only_after_the_checks(tmp_path):
    f = tmp_path / "x.stdout"
    f.write_text("old")
    with outputs.open_in_place(f, "wb") as h:
        h.write(b"new")
    assert f.read_text() == "new"
    with pytest.raises(ValueError, match="mode"):
        outputs.open_in_place(f, "r")


def test_generate_refuses_a_hard_linked_lock(tmp_path, victim):
    """`ln victim ds/.spikesim.lock; generate ... -o ds` rewrote the victim (rc 0); now rc 2, untouched."""
    ds = tmp_path / "ds"
    ds.mkdir()
    os.link(victim, ds / ".spikesim.lock")
    r = subprocess.run([sys.executable, "-m", "pipelines.cli", "generate", "rllr", "--pattern", "--count", "1",
                        "--quiet", "-o", str(ds)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and ".spikesim.lock" in r.stderr and "hard links" in r.stderr
    assert victim.read_text() == "the user's own text\n"
