"""Every output path stays inside -o: the one guard (`spikesim.outputs`) every writing command
uses. Nothing is written, replaced or deleted outside the resolved root; a link inside it is
refused, naming it, never followed; a failed write leaves no partial file and names the target."""
from __future__ import annotations

import errno
import os

import numpy as np
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


# ---- the commands: a planted link is refused (rc 2, one line naming it), the file it leads to is
# byte-identical afterwards and nothing beside it is deleted -------------------------------------
import json  # noqa: E402

from cli_testing import one_line, run_cli  # noqa: E402

SIM = ["simulate", "--steps", "20", "--height", "4", "--width", "8", "--backend", "numpy", "--quiet"]


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize("which", ["stream", "sidecar"])
def test_simulate_refuses_a_link_at_its_output_or_sidecar(tmp_path, outside, capsys, which):
    out = tmp_path / "o" / "s.dat"
    out.parent.mkdir()
    link = out if which == "stream" else out.with_name("s.dat.json")
    link.symlink_to(outside / "keep.txt")
    code, err = run_cli([*SIM, "-o", out], capsys)
    assert code == 2 and link.name in one_line(err) and "symlink" in one_line(err), err
    _untouched(outside)
    assert link.is_symlink()


def test_simulate_replaces_its_own_stream_but_not_another_file(tmp_path, capsys):
    out = tmp_path / "s.dat"
    assert run_cli([*SIM, "-o", out], capsys)[0] == 0
    assert run_cli([*SIM, "--seed", "1", "-o", out], capsys)[0] == 0  # its own stream: replaced, as always
    notes = tmp_path / "notes.dat"
    notes.write_text("the user's notes")
    code, err = run_cli([*SIM, "-o", notes], capsys)
    assert code == 2 and "notes.dat exists and is not a spike stream" in one_line(err), err
    assert notes.read_text() == "the user's notes" and not (tmp_path / "notes.dat.json").exists()
    assert run_cli([*SIM, "--overwrite", "-o", notes], capsys)[0] == 0
    assert notes.stat().st_size == 20 * 4


def test_simulate_on_a_full_disk_names_the_stream_and_leaves_nothing(tmp_path, monkeypatch, capsys):
    import spikesim.stream as stream

    class FullDisk:
        def __init__(self, f):
            self.f = f

        def write(self, data):
            raise OSError(errno.ENOSPC, "No space left on device")

        def __getattr__(self, name):
            return getattr(self.f, name)

    real = stream.open_temp_beside
    monkeypatch.setattr(stream, "open_temp_beside", lambda *a, **k: (lambda f, t: (FullDisk(f), t))(*real(*a, **k)))
    out = tmp_path / "new" / "s.dat"
    code, err = run_cli([*SIM, "-o", out], capsys)
    assert code == 2 and f"{out}: No space left on device" in one_line(err), err
    assert not (tmp_path / "new").exists()


def test_golden_write_names_the_target_not_its_temporary_file(tmp_path, monkeypatch, capsys):
    from spikesim import golden
    monkeypatch.setattr(golden, "measure_reference", lambda *a, **k: {"backend": "numpy", "stats": {}})
    (tmp_path / "ro").mkdir()
    target = tmp_path / "ro" / "ref.json"
    os.chmod(tmp_path / "ro", 0o500)
    try:
        if os.access(tmp_path / "ro", os.W_OK):  # root writes anywhere: /proc is never writable
            target = "/proc/ref.json"
        code, err = run_cli(["golden", "--write", "--seeds", "1", "--backend", "numpy", "-o", target], capsys)
    finally:
        os.chmod(tmp_path / "ro", 0o700)
    line = one_line(err)
    assert code == 2 and f"{target}:" in line and ".part" not in line, line


def test_a_file_of_another_kind_is_not_written_over(tmp_path, capsys):
    """golden --write -o, panel -o and inspect --preview wrote JSON or a PNG over a camera file
    (round seven): the name must have the suffix of what is written."""
    import argparse

    from pipelines.argtypes import output_file_in
    (tmp_path / "victim.toml").write_text("height = 4\n")
    for default in ("golden_stats.json", "panel.png", "preview.png"):
        with pytest.raises(argparse.ArgumentTypeError, match="name it"):
            output_file_in(default)(str(tmp_path / "victim.toml"))
    assert (tmp_path / "victim.toml").read_text() == "height = 4\n"


def test_golden_write_into_a_folder_names_its_file(tmp_path, capsys):
    from pipelines.argtypes import output_file_in
    (tmp_path / "refs").mkdir()
    parse = output_file_in("golden_stats.json")
    assert parse(str(tmp_path / "refs")) == tmp_path / "refs" / "golden_stats.json"
    assert parse(str(tmp_path / "made") + "/") == tmp_path / "made" / "golden_stats.json"
    assert parse(str(tmp_path / "ref.json")) == tmp_path / "ref.json"


def test_golden_write_refuses_a_link(tmp_path, outside, capsys):
    (tmp_path / "ref.json").symlink_to(outside / "keep.txt")
    code, err = run_cli(["golden", "--write", "--seeds", "1", "--backend", "numpy", "-o", tmp_path / "ref.json"],
                        capsys)
    assert code == 2 and "ref.json: is a symlink" in one_line(err), err
    _untouched(outside)


def test_inspect_preview_refuses_a_link(tmp_path, outside, capsys):
    out = tmp_path / "s.dat"
    assert run_cli([*SIM, "-o", out], capsys)[0] == 0
    (tmp_path / "p.png").symlink_to(outside / "keep.txt")
    code, err = run_cli(["inspect", out, "--window", "5", "--preview", tmp_path / "p.png"], capsys)
    assert code == 2 and "p.png: is a symlink" in one_line(err), err
    _untouched(outside)


RENDER = ["render", "--height", "8", "--width", "12", "--spp", "1", "--steps", "0:2"]


@pytest.fixture
def xml(tmp_path):
    from identity_testing import make_user_scene
    return make_user_scene(tmp_path / "sc")


@pytest.mark.parametrize("link, to", [("frames", "."), ("render.json", "keep.txt"), ("gt", ".")])
@pytest.mark.parametrize("rerun", [False, True])
def test_render_refuses_a_link_in_its_output(xml, tmp_path, outside, capsys, link, to, rerun):
    d = tmp_path / "D"
    if rerun:
        assert run_cli([*RENDER, xml, "-o", d], capsys)[0] == 0
        import shutil
        shutil.rmtree(d / link) if (d / link).is_dir() else (d / link).unlink(missing_ok=True)
    d.mkdir(exist_ok=True)
    (d / link).symlink_to(outside / to if to != "." else outside)
    code, err = run_cli([*RENDER, xml, "-o", d], capsys)
    assert code == 2 and link in one_line(err), err
    _untouched(outside)
    assert (d / link).is_symlink()


def test_render_does_not_write_through_a_link_at_its_records_temporary_name(xml, tmp_path, outside, capsys):
    d = tmp_path / "D"
    d.mkdir()
    (d / ".render.json.part").symlink_to(outside / "keep.txt")  # the fixed name the record was written to
    assert run_cli([*RENDER, xml, "-o", d], capsys)[0] == 0
    _untouched(outside)
    assert json.loads((d / "render.json").read_text())["kind"] == "frames"


def test_render_never_deletes_what_a_record_names_outside(xml, tmp_path, outside, capsys):
    d = tmp_path / "D"
    assert run_cli([*RENDER, xml, "-o", d], capsys)[0] == 0
    record = json.loads((d / "render.json").read_text())
    record["files"].append("../elsewhere/keep.txt")  # a crafted record: a rerun removes what it lists
    (d / "render.json").write_text(json.dumps(record))
    code, err = run_cli([*RENDER, xml, "-o", d], capsys)
    assert code == 2 and "outside the output root" in one_line(err), err
    _untouched(outside)


def test_render_on_a_full_disk_names_the_frame_and_leaves_no_folder(xml, tmp_path, monkeypatch, capsys):
    from PIL import Image

    def full(self, fp, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(Image.Image, "save", full)
    d = tmp_path / "new" / "D"
    code, err = run_cli([*RENDER, xml, "-o", d], capsys)
    line = one_line(err)
    assert code == 2 and f"{d / 'frames' / 'step_000000.png'}: No space left on device" in line, line
    assert not (tmp_path / "new").exists()


def test_a_users_file_of_a_results_name_is_refused_and_a_rerun_replaces_its_own(tmp_path, capsys):
    """evaluate -o, panel -o, inspect --preview and golden --write -o replaced a user's metrics.md,
    PNG or JSON of the same name, evaluate saying "replacing an earlier evaluation's" (round eight).
    A rerun still replaces what the command itself wrote there, as the folder's record says."""
    dat = tmp_path / "s.dat"
    assert run_cli(["simulate", "--steps", 60, "--height", 16, "--width", 16, "--backend", "numpy", "--quiet",
                    "-o", dat], capsys)[0] == 0
    gt = tmp_path / "gt.npy"
    np.save(gt, np.full((16, 16), 0.2, np.float32) + np.eye(16, dtype=np.float32) * 0.1)
    cases = {
        "evaluate": (tmp_path / "ev" / "metrics.md",
                     ["evaluate", "--dat", dat, "--gt", gt, "--center", 30, "--window", 21, "--methods", "tfp",
                      "--height", 16, "--width", 16, "-o", tmp_path / "ev", "--quiet"]),
        "panel": (tmp_path / "pa" / "panel.png",
                  ["panel", dat, "--methods", "tfp", "--window", 21, "--num-windows", 2, "-o", tmp_path / "pa" / "panel.png"]),
        "inspect": (tmp_path / "in" / "p.png", ["inspect", dat, "--window", 5, "--preview", tmp_path / "in" / "p.png"]),
        "golden": (tmp_path / "go" / "ref.json",
                   ["golden", "--write", "--seeds", "1", "--backend", "numpy", "-o", tmp_path / "go" / "ref.json"]),
    }
    for command, (target, argv) in cases.items():
        target.parent.mkdir()
        target.write_bytes(b"the user's own")
        code, err = run_cli(argv, capsys)
        assert code == 2 and f"holds {target.name}, which no earlier {command} run wrote there" in err, (command, err)
        assert target.read_bytes() == b"the user's own"
        target.unlink()
        code, err = run_cli(argv, capsys)
        assert code == 0, (command, err)
        first = target.read_bytes()
        assert run_cli(argv, capsys)[0] == 0, command  # its own result: replaced without a word
        assert target.read_bytes()[:4] == first[:4]


def test_a_sweep_refuses_a_users_sweep_md_before_rendering(tmp_path):
    from pipelines.sweep import run_sweep
    (tmp_path / "sweep.md").write_text("my own notes")
    with pytest.raises(FileExistsError, match="holds sweep.md, which no earlier sweep run wrote there"):
        run_sweep(["fan"], ["tfp"], [1.0], out=tmp_path, progress=False)
    assert (tmp_path / "sweep.md").read_text() == "my own notes"


def test_a_results_record_that_is_no_regular_file_is_refused_before_work(tmp_path):
    """A FIFO at .spikesim-results.json hung every command that checks it; a link to /dev/zero grew
    without bound (round nine); a folder there failed only after the results were written, leaving
    them unrecorded (round ten). Each is refused at the check, unread, naming the path."""
    from spikesim.outputs import RESULTS_RECORD, check_results_owned
    os.mkfifo(tmp_path / RESULTS_RECORD)
    with pytest.raises(FileExistsError, match="is not a regular file"):
        check_results_owned(tmp_path, ["metrics.md"], "evaluate")
    other = tmp_path / "z"
    other.mkdir()
    (other / RESULTS_RECORD).symlink_to("/dev/zero")
    with pytest.raises(FileExistsError, match="is not a regular file"):
        check_results_owned(other, ["metrics.md"], "evaluate")
    third = tmp_path / "y"
    (third / RESULTS_RECORD).mkdir(parents=True)
    with pytest.raises(FileExistsError, match="is not a regular file"):
        check_results_owned(third, ["metrics.md"], "evaluate")


def test_the_record_name_is_no_result_name(tmp_path):
    """golden --write -o DIR/.spikesim-results.json wrote its reference, then the record over it (round ten)."""
    from spikesim.outputs import RESULTS_RECORD, check_results_owned
    with pytest.raises(ValueError, match="no golden result may take that name"):
        check_results_owned(tmp_path, [RESULTS_RECORD], "golden")


def test_a_rerun_removes_its_own_stale_result_and_keeps_a_changed_one(tmp_path):
    """sweep --no-plot left the earlier run's sweep.png listed as the new run's (round ten)."""
    from spikesim.outputs import check_results_owned, record_results_owned, _results_record
    for name in ("a.md", "a.png", "b.png"):
        (tmp_path / name).write_text(name)
    record_results_owned(tmp_path, ["a.md", "a.png", "b.png"], "sweep")
    (tmp_path / "b.png").write_text("the user's edit")  # changed since: no longer the command's
    with pytest.raises(FileExistsError, match="holds b.png"):
        check_results_owned(tmp_path, ["a.md", "a.png", "b.png"], "sweep")
    ours = check_results_owned(tmp_path, ["a.md", "a.png"], "sweep")
    assert ours == ["a.md", "a.png"]
    (tmp_path / "a.md").write_text("new table")
    record_results_owned(tmp_path, ["a.md"], "sweep", stale=[*ours, "b.png"])
    assert not (tmp_path / "a.png").exists() and (tmp_path / "b.png").read_text() == "the user's edit"
    listed = _results_record(tmp_path)
    assert "a.png" not in listed and listed["a.md"]["command"] == "sweep"
