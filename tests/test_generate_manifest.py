"""The manifest keeps its own hashes: a scene whose files and checksum record were both rewritten
is rebuilt, not absorbed; a folder no run planned and the manifest never listed (a copy) is not
added to it; and a plain rerun, which checks finished scenes by size, says how to check contents."""
from __future__ import annotations

import hashlib
import json
import logging
import shutil

from pipelines.cli import main
from spikesim.dataset import CHECKSUMS, MANIFEST, check_dataset, verify
from spikesim.generation import generate
from test_generate import tiny_jobs
from test_generate_resume import tree


def _flip_and_cover(root, name="rllr_0000"):
    """Flip a bit of spikes.dat and rewrite the scene's checksums.json to match the damage."""
    dat = root / name / "spikes.dat"
    data = bytearray(dat.read_bytes())
    data[10] ^= 0x01
    dat.write_bytes(bytes(data))
    sums = json.loads((root / name / CHECKSUMS).read_text())
    sums["files"]["spikes.dat"]["sha256"] = hashlib.sha256(bytes(data)).hexdigest()
    (root / name / CHECKSUMS).write_text(json.dumps(sums))


def test_a_rewritten_checksum_record_does_not_make_the_manifest_absorb_damage(tmp_path):
    jobs = tiny_jobs(1)
    generate(jobs, tmp_path / "clean", workers=1, show_progress=False)
    for check in (False, True):
        root = tmp_path / f"data_{check}"
        generate(jobs, root, workers=1, show_progress=False)
        _flip_and_cover(root)
        report = generate(jobs, root, workers=1, show_progress=False, check=check)
        assert [r["name"] for r in report["generated"]] == ["rllr_0000"]
        assert "checksums.json records another sha256 than manifest.json" in report["rebuilt"]["rllr_0000"]
        assert verify(root) == [] and tree(root) == tree(tmp_path / "clean")


def test_an_unplanned_scene_keeps_its_manifest_entries_or_is_left_out(tmp_path, caplog):
    jobs = tiny_jobs(2)
    root = tmp_path / "data"
    generate(jobs[:1], root, workers=1, show_progress=False)
    generate(jobs[1:], root, workers=1, show_progress=False)  # another run adds a scene
    before = json.loads((root / MANIFEST).read_text())["scenes"]
    assert sorted(before) == ["rllr_0000", "rllr_0001"]
    _flip_and_cover(root, "rllr_0000")
    caplog.set_level(logging.WARNING, logger="spikesim.generate")
    generate(jobs[1:], root, workers=1, show_progress=False)
    after = json.loads((root / MANIFEST).read_text())["scenes"]
    assert sorted(after) == ["rllr_0001"] and after["rllr_0001"] == before["rllr_0001"]
    assert "rllr_0000 is not planned here and fails its check" in caplog.text


def test_a_copied_scene_folder_is_not_added_to_the_manifest(tmp_path, caplog):
    jobs = tiny_jobs(1)
    root = tmp_path / "data"
    generate(jobs, root, workers=1, show_progress=False)
    shutil.copytree(root / "rllr_0000", root / "rllr_0000_copy")
    caplog.set_level(logging.WARNING, logger="spikesim.generate")
    generate(jobs, root, workers=1, show_progress=False, check=True)
    assert sorted(json.loads((root / MANIFEST).read_text())["scenes"]) == ["rllr_0000"]
    assert "rllr_0000_copy is a scene folder that this run did not plan" in caplog.text
    assert "names rllr_0000: a copy?" in caplog.text
    found = check_dataset(root)
    assert found.problems == [] and any(e.startswith("rllr_0000_copy/") for e in found.extras)


def test_a_plain_rerun_says_how_to_check_contents(tmp_path, capsys):
    argv = ["generate", "rllr", "--pattern", "--count", "1", "--steps", "41", "--gt-stride", "41",
            "--height", "8", "--width", "12", "--quiet", "-o", str(tmp_path / "d")]
    assert main(argv) == 0
    assert "checked by file size only" not in capsys.readouterr().out
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "1 finished scene(s) were checked by file size only" in out and "--check" in out and "verify" in out
    assert main(argv + ["--check"]) == 0
    assert "checked by file size only" not in capsys.readouterr().out
