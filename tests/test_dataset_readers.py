"""spikesim.dataset.open_dataset reads a dataset only as its manifest records it: every reader
(evaluate, train, the demo) goes through it, so a swapped, rewritten or copied file is refused or
left unread instead of scored or trained on."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

pytest.importorskip("OpenEXR")

from spikesim.dataset import DatasetDamagedError, open_dataset, write_scene
from spikesim.generation.plan import PRESETS, plan_llr, plan_rllr
from spikesim.generation.run import generate
from spikesim.stream import SpikeStream


@pytest.fixture(scope="module")
def pattern_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "rllr"
    generate(plan_rllr(PRESETS["small"], count=2, source="pattern"), root, workers=1, show_progress=False,
             info={"kind": "rllr"})
    return root


def _copy(src, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(src, dst)
    return dst


def test_an_intact_dataset_reads_every_listed_scene(pattern_dataset):
    assert [s.name for s in open_dataset(pattern_dataset)] == ["rllr_0000", "rllr_0001"]


def test_swapped_streams_are_refused_naming_the_files(pattern_dataset, tmp_path):
    root = _copy(pattern_dataset, tmp_path)
    a, b = root / "rllr_0000" / "spikes.dat", root / "rllr_0001" / "spikes.dat"
    tmp = a.read_bytes()
    a.write_bytes(b.read_bytes())
    b.write_bytes(tmp)  # same sizes: only the sha256 tells them apart
    with pytest.raises(DatasetDamagedError, match="rllr_0000/spikes.dat.*verify"):
        open_dataset(root)
    assert [s.name for s in open_dataset(root, checksums=False)] == ["rllr_0000", "rllr_0001"]  # sizes alone pass


def test_a_truncated_file_is_refused_even_without_checksums(pattern_dataset, tmp_path):
    root = _copy(pattern_dataset, tmp_path)
    f = root / "rllr_0001" / "spikes.dat"
    f.write_bytes(f.read_bytes()[:-10])
    with pytest.raises(DatasetDamagedError, match="rllr_0001/spikes.dat"):
        open_dataset(root, checksums=False)


def test_a_scene_copied_under_a_new_name_is_not_read(pattern_dataset, tmp_path):
    root = _copy(pattern_dataset, tmp_path)
    shutil.copytree(root / "rllr_0000", root / "rllr_0000_again")
    with pytest.warns(UserWarning, match="rllr_0000_again.*not in its manifest"):
        scenes = open_dataset(root)
    assert [s.name for s in scenes] == ["rllr_0000", "rllr_0001"]


def test_negative_or_nan_ground_truth_is_refused_naming_the_image(tmp_path):
    spikes = SpikeStream.from_bool(np.zeros((41, 8, 8), bool))
    from spikesim.imageio import write_exr
    for value in (-0.5, np.nan):
        root = tmp_path / f"v{value}"
        write_scene(root, "s", spikes, {20: np.zeros((8, 8), np.float32)}, meta={})
        write_exr(root / "s" / "gt" / "step_000020.exr", np.full((8, 8), value, np.float32))  # damaged after writing
        with pytest.raises(DatasetDamagedError, match="step_000020.exr"):  # the dataset's record sees the edit
            open_dataset(root)
        from spikesim.dataset import SceneRecord
        scene = SceneRecord.open(root / "s")  # and the scene's reader sees what the image holds
        with pytest.raises(ValueError, match=r"gt/.*negative or not finite"):
            scene.ground_truth(20)


def test_generate_refuses_to_add_one_kind_of_dataset_to_another(pattern_dataset, tmp_path):
    root = _copy(pattern_dataset, tmp_path)
    jobs = plan_llr(PRESETS["small"], scenes=["fan"])
    with pytest.raises(ValueError, match="is a rllr dataset.*another -o"):
        generate(jobs, root, workers=1, show_progress=False, info={"kind": "llr"})


def test_without_a_manifest_each_scene_is_checked_against_its_own_record(pattern_dataset, tmp_path):
    """A first generate run cut short leaves finished scenes and no manifest: a stream swapped
    between two of them was scored with rc 0 (issue 40, round 5). Each scene's checksums.json is
    its record then, and the reader says the set may be incomplete."""
    root = _copy(pattern_dataset, tmp_path)
    (root / "manifest.json").unlink()
    with pytest.warns(UserWarning, match="no manifest.json.*may be incomplete"):
        assert [s.name for s in open_dataset(root)] == ["rllr_0000", "rllr_0001"]
    a, b = root / "rllr_0000" / "spikes.dat", root / "rllr_0001" / "spikes.dat"
    tmp = a.read_bytes()
    a.write_bytes(b.read_bytes())
    b.write_bytes(tmp)
    with pytest.raises(DatasetDamagedError, match="own checksums.json.*rllr_0000/spikes.dat"):
        open_dataset(root)


def test_the_training_content_digest_sees_what_the_identity_does_not(pattern_dataset, tmp_path):
    """train --resume compares both: a stream swapped and the records remade keeps the names, sizes
    and job digests (data_identity), not the files' hashes (data_content)."""
    import json
    from model.training import data_content, data_identity
    root = _copy(pattern_dataset, tmp_path)
    before = open_dataset(root)
    ident, content = data_identity(before, []), data_content(before, [])
    for name in ("rllr_0000", "rllr_0001"):  # as a hand-edited set would be: each record remade for its new files
        rec = json.loads((root / name / "checksums.json").read_text())
        rec["files"]["spikes.dat"]["sha256"] = "0" * 64 if name == "rllr_0000" else "1" * 64
        (root / name / "checksums.json").write_text(json.dumps(rec))
    (root / "manifest.json").unlink()  # the manifest would see the records disagree with it
    with pytest.warns(UserWarning, match="no manifest.json"):
        after = open_dataset(root, checksums=False)
    assert data_identity(after, []) == ident and data_content(after, []) != content


def test_a_refused_scene_gives_back_the_stream_file_it_was_handed(tmp_path):
    """write_scene moved the caller's .dat into its work folder, refused the scene (no height in
    meta, a ground truth of the wrong shape) and deleted the folder with the file (round six)."""
    from spikesim.stream import write_dat
    dat = write_dat(tmp_path / "mine.dat", SpikeStream.from_bool(np.zeros((41, 8, 12), bool)), flip=False)
    data = dat.read_bytes()
    with pytest.raises(ValueError, match="meta needs 'height'"):
        write_scene(tmp_path / "root", "s1", dat, {20: np.zeros((8, 12), np.float32)}, meta={}, flip=False)
    with pytest.raises(ValueError, match="has shape"):
        write_scene(tmp_path / "root", "s1", dat, {20: np.zeros((12, 8), np.float32)},
                    meta={"height": 8, "width": 12}, flip=False)
    assert dat.read_bytes() == data and not (tmp_path / "root" / "s1").exists()


def test_a_dataset_a_generate_run_is_writing_is_not_read(pattern_dataset, tmp_path):
    """train read files a running generate --overwrite was replacing, and failed on a file that
    existed a moment later (round six)."""
    from spikesim.dataset import DatasetBusyError, writer_of
    from spikesim.generation.lock import output_lock
    root = _copy(pattern_dataset, tmp_path)
    assert writer_of(root) is None
    with output_lock(root, "generate rllr (pid 4242)"):
        assert "4242" in writer_of(root)
        with pytest.raises(DatasetBusyError, match="a generate run is writing it now.*4242"):
            open_dataset(root)
    assert [s.name for s in open_dataset(root)] == ["rllr_0000", "rllr_0001"]


def test_a_ground_truth_of_another_size_than_its_record_names_both(tmp_path):
    import json
    spikes = SpikeStream.from_bool(np.zeros((41, 8, 12), bool))
    write_scene(tmp_path, "s", spikes, {20: np.zeros((8, 12), np.float32)}, meta={}, flip=False)
    meta = json.loads((tmp_path / "s" / "meta.json").read_text())
    meta["height"], meta["width"] = 12, 8  # swapped by hand
    (tmp_path / "s" / "meta.json").write_text(json.dumps(meta))
    from spikesim.dataset import SceneRecord
    scene = SceneRecord.open(tmp_path / "s")
    with pytest.raises(ValueError, match=r"step_000020.exr: a 8 x 12 image, where .*meta.json gives 12 x 8"):
        scene.ground_truth(20)
    with pytest.raises(TypeError, match="a step is an integer"):
        scene.ground_truth(20.5)


@pytest.mark.parametrize("gt, flip, says", [
    ([(20, "ok"), (20, "ok")], False, "step 20 given twice"),
    ([(20.7, "ok")], False, "is an integer"),
    ([(True, "ok")], False, "is an integer"),
    ([(20, "nan")], False, "negative or non-finite"),
    ([(20, "ok")], "false", "flip must be True or False"),
])
def test_a_scene_write_scene_refuses_leaves_nothing_and_gives_the_stream_back(gt, flip, says, tmp_path):
    """Round seven: duplicate steps or flip="false" were written, the folder renamed into place, then
    refused on opening, so every read of the dataset failed; the user's .dat stayed inside it."""
    from spikesim.stream import write_dat
    dat = write_dat(tmp_path / "mine.dat", SpikeStream.from_bool(np.zeros((41, 8, 12), bool)), flip=False)
    images = {"ok": np.zeros((8, 12), np.float32), "nan": np.full((8, 12), np.nan, np.float32)}
    with pytest.raises(ValueError, match=says):
        write_scene(tmp_path / "root", "s", dat, [(step, images[k]) for step, k in gt],
                    meta={"height": 8, "width": 12}, flip=flip)
    assert dat.exists() and not (tmp_path / "root" / "s").exists()
    assert not (tmp_path / "root").exists() or not any(p.name.startswith(".s") for p in (tmp_path / "root").iterdir())


def test_verify_sees_a_scene_record_deleted_or_emptied(pattern_dataset, tmp_path):
    """verify said "intact" while generate rebuilt the scene as damaged (round seven)."""
    from spikesim.dataset import verify
    root = _copy(pattern_dataset, tmp_path)
    (root / "rllr_0000" / "checksums.json").unlink()
    (root / "rllr_0001" / "checksums.json").write_text('{"files": {}}')
    problems = " ".join(verify(root))
    assert "rllr_0000/checksums.json: missing" in problems and "rllr_0001/checksums.json: does not record" in problems


def test_a_held_lock_names_its_holder_once(tmp_path):
    """"another train run is writing here (pid 8195: train tiny (pid 8195))" (round eight)."""
    import os

    from spikesim.generation.lock import OutputLockedError, output_lock
    with output_lock(tmp_path, "train tiny", what="train run"):
        with pytest.raises(OutputLockedError) as info:
            with output_lock(tmp_path, "train tiny", what="train run"):
                pass
    assert f"another train run is writing here (pid {os.getpid()}: train tiny)" in str(info.value)
    assert str(info.value).count("pid") == 1


def test_a_lock_that_is_no_regular_file_is_named(tmp_path):
    """A FIFO at .spikesim.lock gave "[Errno 22] Invalid argument", naming no file (round nine)."""
    import os

    from spikesim.dataset import LOCK_FILE
    from spikesim.generation.lock import output_lock
    os.mkfifo(tmp_path / LOCK_FILE)
    with pytest.raises(ValueError, match=rf"{LOCK_FILE}: is not a regular file, where a train run keeps its lock"):
        with output_lock(tmp_path, "train x", what="train run"):
            pass
