"""Round twenty-three (issue 40): what a hostile round found on round twenty-two's code
(docs/robustness.md, "Round twenty-three")."""
from __future__ import annotations

import json

from pipelines.cli import main

SIMULATE = ["simulate", "--steps", "30", "--height", "16", "--width", "24", "--backend", "numpy", "--quiet"]


def _killed_overwrite(folder):
    """What a `simulate --overwrite -o u.dat` killed by SIGKILL leaves: its lock record, and the user's
    u.dat.json moved aside."""
    folder.mkdir()
    (folder / ".u.dat.spikesim-lock").write_text("pid 4242: spikesim simulate --overwrite -o u.dat\n")
    (folder / ".u.dat.json.0123abcd.aside").write_text('{"note": "mine"}')


def test_a_record_a_killed_overwrite_moved_aside_is_put_back_and_guards_again(tmp_path, capsys, caplog):
    """The user's record stayed hidden, and a rerun without --overwrite went ahead, rc 0, where the
    file would have stopped it ("exists beside no stream")."""
    folder = tmp_path / "s"
    _killed_overwrite(folder)
    assert main([*SIMULATE, "-o", str(folder / "u.dat")]) == 2
    assert "exists beside no stream" in capsys.readouterr().err
    assert "u.dat.json: put back from .u.dat.json.0123abcd.aside" in caplog.text
    assert json.loads((folder / "u.dat.json").read_text()) == {"note": "mine"}
    assert not (folder / "u.dat").exists() and not list(folder.glob("*.aside"))
    assert main([*SIMULATE, "--overwrite", "-o", str(folder / "u.dat")]) == 0  # asked for: replaced
    assert json.loads((folder / "u.dat.json").read_text())["num_steps"] == 30


def test_a_hidden_copy_is_kept_and_named_where_the_name_is_taken_again(tmp_path, caplog):
    folder = tmp_path / "s"
    _killed_overwrite(folder)
    (folder / "u.dat.json").write_text('{"note": "newer"}')
    assert main([*SIMULATE, "--overwrite", "-o", str(folder / "u.dat")]) == 0
    assert "a copy of u.dat.json that a killed simulate --overwrite had moved aside; kept" in caplog.text
    assert json.loads((folder / ".u.dat.json.0123abcd.aside").read_text()) == {"note": "mine"}
