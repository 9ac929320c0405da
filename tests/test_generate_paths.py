"""Generation writes and deletes only inside its output root, and `verify` reads only inside the
dataset root: scene names are plain names, and every path goes through one guard that follows
`..`, absolute paths and symlinks."""
import hashlib
import json
import shutil

import pytest

from pipelines.cli import build_parser
from spikesim.generation import PRESETS, SceneJob, generate, plan_llr, plan_user
from spikesim.dataset import inside_root, verify
from test_generate import tiny_jobs


def test_inside_root_gives_the_resolved_path_under_the_root(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "alias").symlink_to(tmp_path / "sub")  # a symlink that stays inside is fine
    assert inside_root(tmp_path, "a", "b.dat") == tmp_path.resolve() / "a" / "b.dat"
    assert inside_root(tmp_path, "alias", "x") == tmp_path.resolve() / "sub" / "x"


@pytest.mark.parametrize("parts", [("..", "x"), ("a", "..", "..", "x"), ("/etc/passwd",), ("a/../../x",)])
def test_inside_root_refuses_paths_that_leave_the_root(tmp_path, parts):
    with pytest.raises(ValueError, match="outside"):
        inside_root(tmp_path / "root", *parts)


@pytest.mark.parametrize("parts", [(), (".",), ("a", "..")])
def test_inside_root_refuses_the_root_itself(tmp_path, parts):
    with pytest.raises(ValueError, match="root itself"):
        inside_root(tmp_path, *parts)


def test_inside_root_follows_symlinks(tmp_path):
    root, elsewhere = tmp_path / "root", tmp_path / "elsewhere"
    root.mkdir()
    elsewhere.mkdir()
    (root / "link").symlink_to(elsewhere)
    (root / "file_link").symlink_to(tmp_path / "victim.txt")
    for parts in (("link",), ("link", "spikes.dat"), ("file_link",)):
        with pytest.raises(ValueError, match="outside"):
            inside_root(root, *parts)


@pytest.mark.parametrize("scene", ["../sc/x", "/tmp/x", "sc/x.xml", "fan/../../x", "..", ".hidden"])
def test_a_path_given_as_an_llr_scene_is_refused_by_the_parser(tmp_path, capsys, scene):
    with pytest.raises(SystemExit) as exc:
        build_parser("generate").parse_args(["generate", "llr", "--scenes", scene, "-o", str(tmp_path / "out")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --scenes" in err and "generate scene --xml" in err
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_scene_name_is_refused_naming_the_bundled_ones(tmp_path, capsys):
    with pytest.raises(SystemExit):
        build_parser("generate").parse_args(["generate", "llr", "--scenes", "nosuch", "-o", str(tmp_path)])
    err = capsys.readouterr().err
    assert "nosuch" in err and "ball" in err and "fan" in err


@pytest.mark.parametrize("scene", ["../sc/x", "/abs/x", "sc/x"])
def test_planning_refuses_a_path_as_a_scene_name(scene):
    preset = PRESETS["small"].replace(height=8, width=8, llr_windows=1)
    with pytest.raises(ValueError, match="generate scene --xml"):
        plan_llr(preset, scenes=[scene])


@pytest.mark.parametrize("name", ["../x", "/tmp/x", "a/b", ".", "..", ".part", "", "manifest.json"])
def test_a_job_name_must_be_a_plain_folder_name(name):
    job = tiny_jobs(1)[0]
    with pytest.raises(ValueError, match="scene name"):
        SceneJob(**{**job.__dict__, "name": name})


def test_a_user_scene_light_cannot_smuggle_a_path_into_the_name(tmp_path):
    xml = tmp_path / "mine" / "scene.xml"
    xml.parent.mkdir()
    xml.write_text("<scene version='3.0.0'/>")
    with pytest.raises(ValueError, match="scene name"):
        plan_user(str(xml), "../../x", PRESETS["small"])


def test_generate_does_not_write_through_a_symlink_that_leaves_the_root(tmp_path):
    root = tmp_path / "out"
    root.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    (root / ".manifest.json.part").symlink_to(victim)  # the manifest's temporary file, when its name was fixed
    # temporary files now have random names and are created exclusively: a planted name is never
    # opened, so the run succeeds, the victim is untouched and the link (not ours) stays
    generate(tiny_jobs(1), root, workers=1, show_progress=False)
    assert victim.read_text() == "keep" and (root / ".manifest.json.part").is_symlink()
    assert (root / "manifest.json").is_file() and not (root / "manifest.json").is_symlink()


def test_overwrite_never_deletes_through_a_symlinked_scene_folder(tmp_path):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "meta.json").write_text('{"job_digest": "from other parameters"}')
    (victim / "precious.txt").write_text("keep")
    root = tmp_path / "out"
    root.mkdir()
    (root / "rllr_0000").symlink_to(victim)
    with pytest.raises(ValueError, match="outside"):
        generate(tiny_jobs(1), root, workers=1, show_progress=False, overwrite_stale=True)
    assert (victim / "precious.txt").read_text() == "keep" and (victim / "meta.json").exists()


def _dataset(tmp_path):
    root = tmp_path / "data"
    generate(tiny_jobs(1), root, workers=1, show_progress=False)
    return root


def _add_to_manifest(root, scene, entries):
    m = json.loads((root / "manifest.json").read_text())
    m["scenes"].setdefault(scene, {}).update(entries)
    (root / "manifest.json").write_text(json.dumps(m))


def test_verify_reports_manifest_entries_outside_the_root_without_reading_them(tmp_path):
    root = _dataset(tmp_path)
    secret = tmp_path / "secret.bin"
    secret.write_bytes(b"abc")
    entry = {"bytes": 3, "sha256": hashlib.sha256(b"abc").hexdigest()}  # would pass if read
    _add_to_manifest(root, "rllr_0000", {"../secret.bin": entry, str(secret): entry})
    problems = verify(root)
    assert any(p.startswith("../secret.bin:") and "outside" in p for p in problems), problems
    assert any(p.startswith(f"{secret}:") and "outside" in p for p in problems), problems


def test_verify_reports_a_scene_named_outside_the_root(tmp_path):
    root = _dataset(tmp_path)
    (tmp_path / "evil").mkdir()
    _add_to_manifest(root, "../evil", {})
    assert any("../evil" in p and "outside" in p for p in verify(root))


def test_verify_does_not_follow_a_symlinked_file_out_of_the_root(tmp_path):
    root = _dataset(tmp_path)
    dat = root / "rllr_0000" / "spikes.dat"
    copy = tmp_path / "copy.dat"
    shutil.copy(dat, copy)  # identical bytes: it would pass if it were read
    dat.unlink()
    dat.symlink_to(copy)
    assert any(p.startswith("rllr_0000/spikes.dat:") and "outside" in p for p in verify(root))
