"""Every output path stays inside -o: the one guard (`spikesim.outputs`) every writing command
uses. Nothing is written, replaced or deleted outside the resolved root; a link inside it is
refused, naming it, never followed; a failed write leaves no partial file and names the target."""
from __future__ import annotations

import errno
import os

import pytest

from spikesim import outputs


@pytest.fixture
def outside(tmp_path):
    """A user's folder outside the output root, with a file in it."""
    d = tmp_path / "elsewhere"
    d.mkdir()
    (d / "keep.txt").write_text("the user's")
    return d


def _untouched(outside):
    assert sorted(p.name for p in outside.iterdir()) == ["keep.txt"]
    assert (outside / "keep.txt").read_text() == "the user's"


@pytest.mark.parametrize("parts", [("..", "x"), ("a", "..", "..", "x")])
def test_dotdot_cannot_leave_the_root(tmp_path, parts):
    with pytest.raises(ValueError, match="outside the output root"):
        outputs.writable(tmp_path / "root", *parts)


def test_an_absolute_part_cannot_leave_the_root(tmp_path, outside):
    with pytest.raises(ValueError, match="outside the output root"):
        outputs.writable(tmp_path / "root", outside / "keep.txt")


def test_a_symlinked_file_inside_is_refused_for_writes_and_named(tmp_path, outside):
    root = tmp_path / "root"
    root.mkdir()
    (root / "in.txt").write_text("inside")
    (root / "alias.txt").symlink_to(root / "in.txt")  # stays inside, still refused for writes
    with pytest.raises(ValueError, match=r"alias\.txt: is a symlink"):
        outputs.writable(root, "alias.txt")
    assert outputs.inside(root, "alias.txt") == (root / "in.txt").resolve()  # reads may follow it


def test_a_symlinked_folder_inside_is_refused_for_writes(tmp_path):
    root = tmp_path / "root"
    (root / "real").mkdir(parents=True)
    (root / "png").symlink_to(root / "real")
    with pytest.raises(ValueError, match=r"png: is a symlink"):
        outputs.writable(root, "png", "step_000001.png")
    with pytest.raises(ValueError, match=r"png: is a symlink"):
        outputs.make_dirs(root, "png")


def test_a_link_to_a_file_outside_is_neither_written_nor_deleted(tmp_path, outside):
    root = tmp_path / "root"
    root.mkdir()
    (root / "config.json").symlink_to(outside / "keep.txt")
    (root / "tb").symlink_to(outside)
    with pytest.raises(ValueError, match="outside the output root"):
        outputs.writable(root, "config.json")
    with pytest.raises(ValueError):
        outputs.remove(root, "tb")
    with pytest.raises(ValueError, match="is a symlink"):
        outputs.atomic_write_text(root / "config.json", "{}")
    with pytest.raises(ValueError, match="is a symlink"):
        outputs.append_text(root / "config.json", "x")
    _untouched(outside)
    assert (root / "config.json").is_symlink() and (root / "tb").is_symlink()


def test_a_dangling_link_is_not_written_through(tmp_path, outside):
    root = tmp_path / "root"
    root.mkdir()
    (root / "log.csv").symlink_to(outside / "new.csv")
    with pytest.raises(ValueError, match="is a symlink"):
        outputs.atomic_write_text(root / "log.csv", "x")
    with pytest.raises(ValueError, match="is a symlink"):
        outputs.append_text(root / "log.csv", "x")
    _untouched(outside)


def test_the_root_may_be_a_link_the_user_named(tmp_path, outside):
    (tmp_path / "out").symlink_to(outside)
    assert outputs.writable(tmp_path / "out", "new.txt") == outside.resolve() / "new.txt"


def test_remove_deletes_inside_only(tmp_path):
    root = tmp_path / "root"
    (root / "d").mkdir(parents=True)
    (root / "d" / "f").write_text("x")
    (root / "g").write_text("x")
    outputs.remove(root, "d")
    outputs.remove(root, "g")
    outputs.remove(root, "missing")
    assert list(root.iterdir()) == []


def test_a_failed_atomic_write_leaves_no_partial_file_and_names_the_target(tmp_path):
    target = tmp_path / "frame.png"
    target.write_bytes(b"previous")

    def full_disk(tmp):
        tmp.write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OSError) as info:
        outputs.atomic_write_with(target, full_disk)
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(target)
    assert target.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame.png"]


def test_an_unwritable_folder_names_the_target_not_the_temporary_file(tmp_path):
    target = tmp_path / "no_such_folder" / "ref.json"
    with pytest.raises(OSError) as info:
        outputs.atomic_write_text(target, "{}")
    assert info.value.filename == str(target) and ".part" not in str(info.value)


def test_atomic_writes_keep_the_users_umask(tmp_path):
    old = os.umask(0o027)
    try:
        path = outputs.atomic_write_json(tmp_path / "a.json", {"a": 1})
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o640
    assert path.read_text() == '{\n  "a": 1\n}\n'


def test_output_folder_removes_the_folders_it_made_when_the_block_fails(tmp_path):
    (tmp_path / "existing").mkdir()
    with pytest.raises(RuntimeError):
        with outputs.output_folder(tmp_path / "existing" / "new" / "deeper"):
            raise RuntimeError("the command failed")
    assert list((tmp_path / "existing").iterdir()) == []
    with pytest.raises(RuntimeError):
        with outputs.output_folder(tmp_path / "existing"):
            raise RuntimeError("the command failed")
    assert (tmp_path / "existing").is_dir()  # it was there before: kept


def test_output_folder_keeps_what_a_failed_block_wrote(tmp_path):
    with pytest.raises(RuntimeError):
        with outputs.output_folder(tmp_path / "o") as o:
            (o / "log.csv").write_text("x")
            raise RuntimeError("the command failed")
    assert (tmp_path / "o" / "log.csv").exists()


def test_output_folder_on_a_file_names_it(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(NotADirectoryError) as info:
        with outputs.output_folder(tmp_path / "f"):
            pass
    assert info.value.filename == str(tmp_path / "f")
