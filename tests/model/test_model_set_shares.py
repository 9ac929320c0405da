"""train.set_shares: the share of the training samples drawn from each --data root (issue 39's
photo-share lever), its validation, and what it does to the samples a run sees."""
from __future__ import annotations

import collections
import math

import pytest

from model.config import TrainConfig
from model.data import SequenceDataset, set_probabilities
from model.training import run_training
from modeltest_fakes import make_scene
from test_model_training import tiny_experiment

WINDOW, K = 7, 3


@pytest.fixture(scope="module")
def two_sets():
    """Set `photo` with 8 scenes, set `nat` with 1: drawn alike, `nat` gives 1 sample in 9."""
    photo = [make_scene(f"photo:s{i}", 16, 20, WINDOW * 6, brightness=0.3, seed=i) for i in range(8)]
    nat = [make_scene("nat:s0", 16, 20, WINDOW * 6, brightness=0.05, seed=99)]
    return photo + nat


def test_named_shares_stand_and_the_rest_split_by_samples():
    probs = set_probabilities({"a": 10, "b": 30, "c": 60}, {"a": 0.5})
    assert probs == pytest.approx({"a": 0.5, "b": 0.5 * 0.3 / 0.9, "c": 0.5 * 0.6 / 0.9})
    assert math.fsum(probs.values()) == pytest.approx(1.0)
    # every set named: the shares are the probabilities
    assert set_probabilities({"a": 1, "b": 99}, {"a": 0.25, "b": 0.75}) == pytest.approx({"a": 0.25, "b": 0.75})


@pytest.mark.parametrize("shares, match", [
    ({"nat8": 0.2}, r"names \['nat8'\], not among the training sets \['a', 'b'\]"),
    ({"a": 1.0}, r"leaving nothing for \['b'\]"),
    ({"a": 0.3, "b": 0.3}, "not 1, and name every training set"),
])
def test_shares_that_cannot_be_met_are_errors_naming_the_sets(shares, match):
    with pytest.raises(ValueError, match=match):
        set_probabilities({"a": 5, "b": 5}, shares)


@pytest.mark.parametrize("bad", [{}, {"a": 0}, {"a": -0.1}, {"a": 1.5}, {"a": float("nan")}, {"a": True},
                                 {"a": 0.7, "b": 0.7}, {"x:y": 0.5}, [0.5]])
def test_the_config_field_is_checked(bad):
    with pytest.raises(ValueError, match="train.set_shares"):
        TrainConfig(set_shares=bad)


def test_samples_follow_the_shares(two_sets):
    """4,000 draws at a 0.5 share of a set that holds 1 sample in 9: its frequency is within 4
    binomial standard deviations of 0.5, and the other set's scenes are drawn alike within it."""
    n = 4000
    ds = SequenceDataset(two_sets, WINDOW, K, crop=8, seed=3, samples_per_epoch=n, set_shares={"nat": 0.5})
    assert ds.set_probs == pytest.approx({"photo": 0.5, "nat": 0.5})
    scenes = collections.Counter(ds[i]["scene"] for i in range(n))
    sigma = math.sqrt(0.25 / n)
    assert abs(scenes["nat:s0"] / n - 0.5) < 4 * sigma
    per_photo = 0.5 / 8
    for i in range(8):
        assert abs(scenes[f"photo:s{i}"] / n - per_photo) < 4 * math.sqrt(per_photo * (1 - per_photo) / n)
    # without shares the small set keeps its share of the samples
    plain = SequenceDataset(two_sets, WINDOW, K, crop=8, seed=3, samples_per_epoch=n)
    nat = sum(plain[i]["scene"] == "nat:s0" for i in range(n)) / n
    assert abs(nat - 1 / 9) < 4 * math.sqrt((1 / 9) * (8 / 9) / n)


def test_draws_are_a_function_of_seed_epoch_and_index(two_sets):
    a = SequenceDataset(two_sets, WINDOW, K, crop=8, seed=5, set_shares={"nat": 0.3})
    b = SequenceDataset(two_sets, WINDOW, K, crop=8, seed=5, set_shares={"nat": 0.3})
    assert len(a) == len(a.refs)  # an epoch keeps its length: every sample's count
    a.set_epoch(2), b.set_epoch(2)
    for i in (0, 7, 19):
        x, y = a[i], b[i]
        assert (x["scene"], x["first_centre"], x["y0"], x["x0"]) == (y["scene"], y["first_centre"], y["y0"], y["x0"])
        assert (x["spikes"] == y["spikes"]).all()


def test_one_root_or_validation_data_cannot_take_shares(two_sets):
    one = [make_scene("s0", 16, 20, WINDOW * 6)]
    with pytest.raises(ValueError, match="several --data roots"):
        SequenceDataset(one, WINDOW, K, crop=8, set_shares={"s0": 0.5})
    with pytest.raises(ValueError, match="validation set scores every sample"):
        SequenceDataset(two_sets, WINDOW, K, crop=8, random_crop=False, set_shares={"nat": 0.5})


def test_a_run_says_its_shares_and_keeps_them_on_resume(two_sets, tmp_path, capsys):
    run_training(tiny_experiment(max_steps=2, set_shares={"nat": 0.5}), two_sets, [], tmp_path,
                 device="cpu", progress=False)
    assert "samples drawn by set (train.set_shares): photo 50.0 %, nat 50.0 %" in capsys.readouterr().err
    with pytest.raises(ValueError, match="set_shares"):
        run_training(tiny_experiment(max_steps=4, set_shares={"nat": 0.25}), two_sets, [], tmp_path,
                     device="cpu", progress=False, resume=True)
    with pytest.raises(ValueError, match=r"names \['natural'\]"):
        run_training(tiny_experiment(max_steps=2, set_shares={"natural": 0.5}), two_sets, [], tmp_path / "b",
                     device="cpu", progress=False)


def test_compare_refuses_a_share_naming_no_set_before_any_run_trains(two_sets):
    """compare checks every config's samples before training: a set_shares typo is named there, not
    after the other configs' runs have trained."""
    import dataclasses
    from model.comparison import check_samples
    good = tiny_experiment()
    bad = dataclasses.replace(good, train=dataclasses.replace(good.train, set_shares={"natural": 0.5}))
    check_samples([("A", good)], two_sets)
    with pytest.raises(ValueError, match=r"--configs B: train.set_shares names \['natural'\]"):
        check_samples([("A", good), ("B", bad)], two_sets)
