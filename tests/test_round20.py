"""Round twenty (issue 40): what a hostile round found on round nineteen's code, each checked here
on the behaviour it broke (docs/robustness.md, "Round twenty")."""
from __future__ import annotations

import json
import logging
import os
import shutil

import numpy as np
import pytest

from spikesim.dataset import write_manifest, write_scene
from spikesim.stream import SpikeStream, is_stream_sidecar, read_dat, sidecar_path, write_dat, write_sidecar


def _dataset(root, level: float, steps: int = 90, side: int = 16):
    """Two scenes s0, s1 of a random still image x `level`, noiseless spikes; rewritten in place
    with another level, the names, sizes and steps stay: only the content differs."""
    shutil.rmtree(root, ignore_errors=True)
    for i in range(2):
        img = (np.random.default_rng(i).uniform(0.2, 1.0, (side, side)) * level).astype(np.float32)
        acc = np.random.default_rng(10 + i).uniform(0, 1, (side, side)) + np.cumsum(np.repeat(img[None], steps, 0), 0)
        spikes = np.diff(np.floor(np.concatenate([acc[:1] - img[None], acc])), axis=0) > 0
        write_scene(root, f"s{i}", SpikeStream.from_bool(spikes), {g: img for g in range(10, steps, 7)}, meta={})
    write_manifest(root, {"kind": "mine"})
    return root


# ---- H1: compare's kept scores follow the test set's content ----------------------------------------
def test_scores_kept_for_a_test_set_rewritten_in_place_are_not_reported_for_the_new_content(tmp_path):
    """A test set rewritten in place (same names, sizes and steps, no job digest) kept its key, and
    `compare` reported the old content's scores for it, rc 0 (round twenty)."""
    from model.comparison import evaluate_runs
    from model.data import open_scenes
    root = tmp_path / "test"

    def tfp_psnr(level):
        _dataset(root, level)
        (tmp_path / "cmp").mkdir(exist_ok=True)
        rows = evaluate_runs({}, open_scenes(root), 21, baselines=["tfp"], out=tmp_path / "cmp")
        return [r.psnr_aligned for r in rows if r.scene == "s0"][0]
    bright = tfp_psnr(0.3)
    dark = tfp_psnr(0.02)
    _dataset(tmp_path / "fresh", 0.02)
    fresh = [r.psnr_aligned for r in evaluate_runs({}, open_scenes(tmp_path / "fresh"), 21, baselines=["tfp"])
             if r.scene == "s0"][0]
    assert dark == pytest.approx(fresh) and abs(dark - bright) > 1.0
    assert tfp_psnr(0.02) == pytest.approx(fresh)  # the same content again: its kept scores serve


# ---- H2 and M1: a kept run of other content; a refused resume leaves the record alone -----------------
@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    from model.config import ExperimentConfig, ModelConfig, TrainConfig
    from model.data import open_scenes
    from model.training import run_training
    tmp = tmp_path_factory.mktemp("r20")
    data = _dataset(tmp / "train", 0.3)
    exp = ExperimentConfig("tiny20", model=ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2),
                           train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=1, lr_milestones=(5,),
                                             samples_per_epoch=2, val_fraction=0.0, max_steps=2))
    run_training(exp, open_scenes(data), [], tmp / "run", device="cpu", progress=False)
    return tmp, data, exp


def test_compare_does_not_keep_a_run_trained_on_content_since_rewritten(trained):
    """`compare` kept finished runs after its training data were rewritten in place (same names and
    sizes), rc 0, where `train --resume` refuses; now both check the content."""
    from model.comparison import run_mismatch
    from model.data import open_scenes
    from model.training import data_content, data_identity
    tmp, data, exp = trained
    copy = tmp / "copy"
    shutil.copytree(data, copy)
    run = exp  # the very run: same config, steps and seed
    scenes = open_scenes(copy)
    assert run_mismatch(tmp / "run" / "last.pt", run, data_identity(scenes, []), None, data_content(scenes, [])) is None
    _dataset(copy, 0.02)
    scenes = open_scenes(copy)
    assert data_identity(scenes, []) == data_identity(open_scenes(data), [])  # what the old check saw
    got = run_mismatch(tmp / "run" / "last.pt", run, data_identity(scenes, []), None, data_content(scenes, []))
    assert got is not None and "other content" in got


def test_a_resume_refused_for_its_data_leaves_the_runs_config_record_alone(trained, tmp_path):
    """`train --resume --max-steps 10` on other data was refused, but config.json had already been
    rewritten to max_steps 10: the record of a run that never went on (round twenty)."""
    import dataclasses

    from model.data import open_scenes
    from model.training import run_training
    tmp, data, exp = trained
    run = tmp_path / "run"
    shutil.copytree(tmp / "run", run)
    before = (run / "config.json").read_bytes()
    other = _dataset(tmp_path / "other", 0.3, steps=111)
    longer = dataclasses.replace(exp, train=dataclasses.replace(exp.train, max_steps=10))
    with pytest.raises(ValueError, match="trained on other data"):
        run_training(longer, open_scenes(other), [], run, device="cpu", resume=True, progress=False)
    assert (run / "config.json").read_bytes() == before


# ---- H3: the Python stream writers --------------------------------------------------------------
def _stream():
    return SpikeStream.from_bool(np.ones((3, 4, 8), bool))


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_write_dat_never_replaces_a_fifo_or_a_device(tmp_path, kind):
    """write_dat replaced a character device (and a FIFO) with a regular file, where the CLI refuses."""
    target = tmp_path / "out.dat"
    if kind == "fifo":
        os.mkfifo(target)
    else:
        try:
            os.mknod(target, 0o666 | 0o020000, os.makedev(1, 3))  # a character device like /dev/null
        except PermissionError:
            pytest.skip("making a device needs root")
    with pytest.raises(ValueError, match="not a regular file"):
        write_dat(target, _stream())
    assert not target.is_file() and not target.is_symlink() and os.path.exists(target)
    assert [p.name for p in tmp_path.iterdir()] == ["out.dat"]  # no temporary file left


def test_a_users_json_of_the_sidecars_name_is_kept(tmp_path):
    """write_dat('d/camera') deleted the user's d/camera.json (the sidecar's name for a path without
    a suffix) and wrote nothing in its place; a stream's own sidecar is still removed."""
    mine = tmp_path / "camera.json"
    mine.write_text('{"my": "camera settings"}')
    write_dat(tmp_path / "camera", _stream())
    assert json.loads(mine.read_text()) == {"my": "camera settings"}
    assert not is_stream_sidecar(mine)
    old = tmp_path / "old.dat"
    write_dat(old, _stream())
    write_sidecar(old, {"height": 4, "width": 8, "flip": False, "num_steps": 3})
    assert is_stream_sidecar(sidecar_path(old))
    write_dat(old, SpikeStream.from_bool(np.ones((5, 4, 8), bool)))
    assert not sidecar_path(old).exists()  # it described the old stream
    assert read_dat(old, 4, 8).num_steps == 5


# ---- M2 and L1: the trade study's caches ---------------------------------------------------------------
def test_a_damaged_monte_carlo_probe_is_measured_again_and_nan_in_a_report(tmp_path, caplog):
    """A damaged mc_probe.json stopped the whole study (and --report-only) with rc 2, after every run;
    every other damaged cache is measured again with a warning."""
    from pipelines.tradeoff_study import _probe_of
    path = tmp_path / "mc_probe.json"
    path.write_text("garbage{")
    with caplog.at_level(logging.WARNING):
        assert _probe_of(path, "k") is None
    assert "damaged cache file" in caplog.text and str(path) in caplog.text
    path.write_text(json.dumps({"key": "k", "mc_ratio": "abc"}))
    assert _probe_of(path, "k") is None
    path.write_text(json.dumps({"key": "other", "mc_ratio": 1.5}))
    assert _probe_of(path, "k") is None
    path.write_text(json.dumps({"key": "k", "mc_ratio": 1.5}))
    assert _probe_of(path, "k") == {"key": "k", "mc_ratio": 1.5}


def test_a_fifo_at_a_cache_file_is_named_before_its_run_is_measured_again(tmp_path):
    """A FIFO at a run's .json was warned about as damage, the run simulated again, then refused with
    'choose another output'; now refused first, saying to remove it."""
    from pipelines.tradeoff_study import _is_cached
    row, npz = tmp_path / "float32.json", tmp_path / "float32.npz"
    os.mkfifo(row)
    with pytest.raises(ValueError, match=r"float32\.json: is a FIFO .*where this study keeps a cache file; remove it"):
        _is_cached(row, npz, "k")
    row.unlink()
    npz.mkdir()
    with pytest.raises(ValueError, match=r"float32\.npz: is a folder, where this study keeps a cache file"):
        _is_cached(row, npz, "k")


# ---- L2: the Python API's small checks ---------------------------------------------------------------
def test_a_blank_method_label_and_a_float_keyframe_step_are_refused():
    from model.methods import method_from_spec
    from spikesim import SpikeCamera, Simulator
    with pytest.raises(ValueError, match="the label before '=' is blank"):
        method_from_spec("=tfp")
    assert method_from_spec("mine=tfp").name == "mine"
    sim = Simulator(SpikeCamera.realistic(height=4, width=4), backend="numpy", seed=0)
    with pytest.raises(ValueError, match="keyframe_every must be a positive integer, got 2.0"):
        sim.run(np.full((3, 4, 4), 0.2, np.float32), keyframe_every=2.0)
    assert sim.run(np.full((3, 4, 4), 0.2, np.float32), keyframe_every=np.int64(1)).num_steps == 3


def test_compare_keeps_a_run_written_before_a_config_field_existed(trained, tmp_path):
    """A run whose stored config has no `train.set_shares` (written before the field) trained with its
    default: compare kept none of the 800-step runs of runs/study_norm once the field existed ("another
    network or recipe (its config)"). Read as `train --resume` reads it, it is the same run; a real
    difference in the new field is still named."""
    import dataclasses
    from model.checkpoint import atomic_torch_save, load_checkpoint
    from model.comparison import run_mismatch
    from model.data import open_scenes
    from model.training import data_content, data_identity
    tmp, data, exp = trained
    state = load_checkpoint(tmp / "run" / "last.pt")
    del state["experiment"]["train"]["set_shares"]  # as written before the field
    old = tmp_path / "last.pt"
    atomic_torch_save(state, old)
    scenes = open_scenes(data)
    ident, content = data_identity(scenes, []), data_content(scenes, [])
    assert run_mismatch(old, exp, ident, None, content) is None
    other = dataclasses.replace(exp, train=dataclasses.replace(exp.train, set_shares={"x": 1.0}))
    assert "train.set_shares" in run_mismatch(old, other, ident, None, content)
