"""Round twenty-two (issue 40): what a hostile round found on round twenty-one's code, each checked
here on the behaviour it broke (docs/robustness.md, "Round twenty-two")."""
from __future__ import annotations

import json

import numpy as np
import pytest
from test_round20 import _dataset

from spikesim import SpikeCamera, Simulator
from spikesim.simulate import BatchSimulator, TwinSimulator
from spikesim.stream import read_dat


def test_a_baseline_given_twice_is_refused(tmp_path):
    """`compare --baselines tfp tfp` scored TFP twice and pooled it as a two-seed mean (17.059 ± 0.000)."""
    from model.comparison import check_baselines, evaluate_runs
    from model.data import open_scenes
    assert check_baselines(["tfp", "tfi", "tfp:205"], 41) == ["TFP", "TFI", "TFP-205"]
    for twice in (["tfp", "tfp"], ["tfp:123", "tfp:123"]):
        with pytest.raises(ValueError, match="given more than once"):
            check_baselines(twice, 41)
    scenes = open_scenes(_dataset(tmp_path / "t", 0.3))
    with pytest.raises(ValueError, match=r"--baselines: TFP given more than once"):
        evaluate_runs({}, scenes, 21, ["tfp", "tfp"])


def test_compare_refuses_a_repeated_baseline_before_training(tmp_path, capsys):
    from pipelines.cli import main
    data = _dataset(tmp_path / "d", 0.3)
    rc = main(["compare", "--data", str(data), "--test-data", str(data), "--configs", "tiny", "--max-steps", "1",
               "--baselines", "tfp", "tfp", "-o", str(tmp_path / "cmp"), "--quiet"])
    assert rc == 2 and "TFP given more than once" in capsys.readouterr().err
    assert not (tmp_path / "cmp" / "runs").exists()


def _frames(n=6):
    return np.full((n, 8, 8), 0.3, np.float32)


@pytest.mark.parametrize("second", ["x.dat", "x.dat.json", "sub/../x.dat"])
def test_two_outputs_of_one_run_at_one_file_are_refused_before_simulating(tmp_path, second):
    """Two streams at one path (or one at the other's record name) lost a stream with no error."""
    (tmp_path / "sub").mkdir()
    cam = SpikeCamera.realistic(height=8, width=8)
    with pytest.raises(ValueError, match="output paths collide"):
        BatchSimulator(cam, [0, 1]).run_to_dat(_frames(), [tmp_path / "x.dat", tmp_path / second])
    with pytest.raises(ValueError, match="output paths collide"):
        TwinSimulator(Simulator(cam, seed=0), None).run_to_dat(_frames(), tmp_path / "x.dat", tmp_path / second)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub"]


@pytest.mark.parametrize("extra,words", [({"height": 4, "width": 16}, "height, width are the stream's own record"),
                                         ({"twin_of": "a"}, "twin_of is the stream's own record"),
                                         ({"x": {1, 2}}, "not plain JSON")])
def test_the_twins_extra_fields_are_checked_before_its_streams_are_replaced(tmp_path, extra, words):
    """The twin took extra={"height": 4, "width": 16} into both records of an 8 x 8 stream (the
    reader then failed), and a non-JSON extra failed after both streams were replaced."""
    cam = SpikeCamera.realistic(height=8, width=8)
    a, b = TwinSimulator(Simulator(cam, seed=0), None).run_to_dat(_frames(5), tmp_path / "g.dat", tmp_path / "t.dat")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(ValueError, match=words):
        TwinSimulator(Simulator(cam, seed=0), None).run_to_dat(_frames(20), a, b, extra=extra)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    assert read_dat(a, 8, 8).num_steps == 5


def test_a_failed_simulate_overwrite_keeps_the_users_record_file(tmp_path, capsys):
    """`simulate --overwrite -o u.dat` removed the user's u.dat.json before simulating; a bad frame
    then failed the run, and the file was gone."""
    from pipelines.cli import main
    bad = _frames(30)
    bad[25] = np.nan
    np.save(tmp_path / "bad.npy", bad)
    (tmp_path / "u.dat").write_text("user data")
    (tmp_path / "u.dat.json").write_text('{"note": "my notes on u.dat"}')
    rc = main(["simulate", "--frames", str(tmp_path / "bad.npy"), "--quiet", "--overwrite", "-o", str(tmp_path / "u.dat")])
    assert rc == 2 and "frame 25" in capsys.readouterr().err
    assert json.loads((tmp_path / "u.dat.json").read_text()) == {"note": "my notes on u.dat"}
    assert (tmp_path / "u.dat").read_text() == "user data"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npy", "u.dat", "u.dat.json"]  # nothing left aside
    np.save(tmp_path / "good.npy", _frames(30))
    assert main(["simulate", "--frames", str(tmp_path / "good.npy"), "--quiet", "--overwrite",
                 "-o", str(tmp_path / "u.dat")]) == 0  # a run that succeeds replaces it, as --overwrite says
    assert json.loads((tmp_path / "u.dat.json").read_text())["num_steps"] == 30
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npy", "good.npy", "u.dat", "u.dat.json"]
