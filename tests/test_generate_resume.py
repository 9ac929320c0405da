"""A rerun of `generate` checks each finished scene against the checksums recorded when it was
written, rebuilds what is damaged (or lost its meta.json), and never writes a manifest from
damaged files."""
import json

import pytest

from spikesim.generation import generate, job_status
from spikesim.dataset import LOCK_FILE, MANIFEST, verify
from test_generate import tiny_jobs


def tree(root):
    """Every file under root and its bytes (the lock file holds a pid, so it is left out)."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != LOCK_FILE}


@pytest.fixture
def clean_and_copy(tmp_path):
    """The same two-scene dataset generated twice: a reference and one to damage."""
    jobs = tiny_jobs(2)
    generate(jobs, tmp_path / "clean", workers=1, show_progress=False)
    generate(jobs, tmp_path / "data", workers=1, show_progress=False)
    assert tree(tmp_path / "clean") == tree(tmp_path / "data")
    return jobs, tmp_path / "clean", tmp_path / "data"


def generated(report):
    return sorted(r["name"] for r in report["generated"])


def test_quick_resume_rebuilds_truncated_and_deleted_files(clean_and_copy):
    jobs, clean, root = clean_and_copy
    dat = root / "rllr_0000" / "spikes.dat"
    dat.write_bytes(dat.read_bytes()[:-1])
    (root / "rllr_0001" / "gt" / "step_000061.exr").unlink()
    assert len(verify(root)) == 2
    assert job_status(jobs[0], root) == "damaged" and job_status(jobs[1], root) == "damaged"
    report = generate(jobs, root, workers=1, show_progress=False)
    assert generated(report) == ["rllr_0000", "rllr_0001"] and report["skipped"] == 0
    assert verify(root) == [] and tree(root) == tree(clean)


def test_a_flipped_bit_is_rebuilt_with_check_and_never_absorbed_into_the_manifest(clean_and_copy):
    jobs, clean, root = clean_and_copy
    dat = root / "rllr_0000" / "spikes.dat"
    data = bytearray(dat.read_bytes())
    data[10] ^= 0x01
    dat.write_bytes(bytes(data))
    # the quick check (sizes) cannot see a flipped bit; the manifest must keep the recorded checksum
    assert generated(generate(jobs, root, workers=1, show_progress=False)) == []
    assert any(p.startswith("rllr_0000/spikes.dat:") and "checksum" in p for p in verify(root))
    assert job_status(jobs[0], root, full=True) == "damaged"
    report = generate(jobs, root, workers=1, show_progress=False, check=True)
    assert generated(report) == ["rllr_0000"] and report["skipped"] == 1
    assert verify(root) == [] and tree(root) == tree(clean)


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_scene_whose_meta_json_was_deleted_is_rebuilt(clean_and_copy, overwrite):
    jobs, clean, root = clean_and_copy
    (root / "rllr_0000" / "meta.json").unlink()
    report = generate(jobs, root, workers=1, show_progress=False, overwrite_stale=overwrite)
    assert generated(report) == ["rllr_0000"]
    assert verify(root) == [] and tree(root) == tree(clean)


def test_a_scene_whose_checksum_record_was_deleted_is_rebuilt(clean_and_copy):
    jobs, clean, root = clean_and_copy
    (root / "rllr_0001" / "checksums.json").unlink()
    assert generated(generate(jobs, root, workers=1, show_progress=False)) == ["rllr_0001"]
    assert tree(root) == tree(clean)


def test_the_manifest_lists_only_scenes_that_pass(clean_and_copy):
    jobs, clean, root = clean_and_copy
    dat = root / "rllr_0001" / "spikes.dat"
    dat.write_bytes(dat.read_bytes()[:-3])
    generate(jobs[:1], root, workers=1, show_progress=False)  # rllr_0001 is not planned: left as it is
    manifest = json.loads((root / MANIFEST).read_text())
    assert sorted(manifest["scenes"]) == ["rllr_0000"]
    assert manifest["scenes"]["rllr_0000"] == json.loads((clean / MANIFEST).read_text())["scenes"]["rllr_0000"]


def test_a_folder_the_generator_did_not_write_is_never_deleted(tmp_path):
    mine = tmp_path / "data" / "rllr_0000"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("keep")
    for overwrite in (False, True):
        with pytest.raises(FileExistsError, match="not a scene folder"):
            generate(tiny_jobs(1), tmp_path / "data", workers=1, show_progress=False, overwrite_stale=overwrite)
    assert (mine / "notes.txt").read_text() == "keep"


def test_stale_scenes_still_need_overwrite(clean_and_copy):
    jobs, clean, root = clean_and_copy
    meta = json.loads((root / "rllr_0000" / "meta.json").read_text())
    meta["job_digest"] = "0" * 16
    (root / "rllr_0000" / "meta.json").write_text(json.dumps(meta))
    assert job_status(jobs[0], root) == "stale"
    with pytest.raises(FileExistsError, match="other parameters"):
        generate(jobs, root, workers=1, show_progress=False)


def test_a_refusal_removes_nothing(clean_and_copy):
    # rllr_0000 is damaged (rebuilt on a normal rerun), but rllr_0001 is from other parameters
    # and --overwrite is not given: the run stops before removing either.
    jobs, clean, root = clean_and_copy
    (root / "rllr_0000" / "gt" / "step_000061.exr").unlink()
    meta = json.loads((root / "rllr_0001" / "meta.json").read_text())
    (root / "rllr_0001" / "meta.json").write_text(json.dumps({**meta, "job_digest": "0" * 16}))
    with pytest.raises(FileExistsError, match="rllr_0001 was generated with other parameters"):
        generate(jobs, root, workers=1, show_progress=False)
    assert (root / "rllr_0000" / "spikes.dat").exists() and (root / "rllr_0001" / "spikes.dat").exists()
