"""`spikesim camera --write`: a camera file to start from, with every field, its meaning and the
published default, that loads back as the camera it describes."""
from __future__ import annotations

import dataclasses
import tomllib

import pytest

from spikesim.camera import SpikeCamera
from spikesim.camera_file import GEOMETRY_FIELDS, camera_toml, field_docs
from tests.cli_testing import one_line, run_cli


def test_every_field_is_documented_in_the_code():
    names = {f.name for f in dataclasses.fields(SpikeCamera)}
    docs = field_docs()
    assert set(docs) == names and all(len(d) > 10 for d in docs.values())


@pytest.mark.parametrize("preset", ["realistic", "noiseless"])
def test_the_written_file_loads_back_as_its_camera(tmp_path, capsys, preset):
    path = tmp_path / "mine.toml"
    rc, err = run_cli(["camera", "--write", path, "--preset", preset], capsys)
    assert rc == 0 and str(path) in err
    text = path.read_text()
    data = tomllib.loads(text)
    expected = SpikeCamera.noiseless() if preset == "noiseless" else SpikeCamera.realistic()
    assert SpikeCamera.from_file(path) == expected
    assert set(data) == {f.name for f in dataclasses.fields(SpikeCamera)} - set(GEOMETRY_FIELDS)
    lines = text.splitlines()
    for name in data:  # each field is preceded by its comment
        i = next(i for i, line in enumerate(lines) if line.startswith(f"{name} = "))
        assert lines[i - 1].startswith("# ")
    if preset == "noiseless":
        assert "dark_current_hz = 0.0  # the published value: 94.0" in text
    for name in GEOMETRY_FIELDS:
        assert f"# {name} = " in text


def test_write_refuses_to_replace_and_wants_toml(tmp_path, capsys):
    path = tmp_path / "mine.toml"
    path.write_text("keep")
    rc, err = run_cli(["camera", "--write", path], capsys)
    assert rc == 2 and "--overwrite" in one_line(err) and path.read_text() == "keep"
    rc, err = run_cli(["camera", "--write", path, "--overwrite"], capsys)
    assert rc == 0 and SpikeCamera.from_file(path) == SpikeCamera.realistic()
    rc, err = run_cli(["camera", "--write", tmp_path / "mine.json"], capsys)
    assert rc == 2 and "TOML" in one_line(err) and not (tmp_path / "mine.json").exists()


def test_checking_a_camera_file(tmp_path, capsys):
    path = tmp_path / "mine.toml"
    path.write_text(camera_toml().replace("gain_spread = 0.058", "gain_spread = 0.9"))
    rc, err = run_cli(["camera", path], capsys)
    assert rc == 2 and "gain_spread" in one_line(err)
