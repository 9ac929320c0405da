"""Every command that prints results can print them as JSON (stdout holds only the document)."""
from __future__ import annotations

import json

from pipelines.cli import main


def _json(argv, capsys) -> tuple[int, object]:
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    out = capsys.readouterr().out
    return rc, json.loads(out)


def test_simulate_generate_and_verify_print_json(tmp_path, capsys) -> None:
    rc, doc = _json(["simulate", "--height", 8, "--width", 16, "--steps", 50, "--keyframe-every", 4, "--backend",
                     "numpy", "--quiet", "-o", tmp_path / "s.dat", "--json"], capsys)
    assert rc == 0 and doc["num_steps"] == 50 and doc["height"] == 8
    rc, doc = _json(["generate", "rllr", "--pattern", "--count", 1, "--steps", 30, "--height", 8, "--width", 16,
                     "--workers", 1, "--quiet", "-o", tmp_path / "d", "--json"], capsys)
    assert rc == 0 and len(doc["generated"]) == 1 and doc["settings"]["height"]["value"] == 8
    rc, doc = _json(["verify", tmp_path / "d", "--json"], capsys)
    assert rc == 0 and doc["status"] == 0 and doc["scenes"] == 1 and doc["problems"] == []
    (tmp_path / "d" / "stray.txt").write_text("x")
    rc, doc = _json(["verify", tmp_path / "d", "--json"], capsys)
    assert rc == 3 and doc["extras"]
