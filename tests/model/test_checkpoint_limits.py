"""Checkpoints and configs that ask for too much or hold nonsense: a network of 10^6 blocks or
terabytes of weights is refused from its config alone, before anything is built; a config file
without its "model" section is refused; NaN weights are refused where every command loads a
checkpoint, and reconstruct never writes black frames from NaN; a refused pickle names the global
it imports, whatever its protocol."""
from __future__ import annotations

import dataclasses
import os
import pickle
import zipfile

import numpy as np
import pytest
import torch

from cli_testing import one_line, run_cli
from model.arch import build_model, check_model_size, count_parameters, parameter_count
from model.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint
from model.config import ExperimentConfig, ModelConfig, TrainConfig, load_config
from spikesim.stream import SpikeStream, write_dat

TINY = ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2)
pytestmark = pytest.mark.timeout(120)  # a network that is built after all fails the test, not the machine


def tiny_experiment(model: ModelConfig = TINY) -> ExperimentConfig:
    return ExperimentConfig("tinylimits", model=model,
                            train=TrainConfig(num_windows=2, crop=8, batch_size=1, epochs=1, lr_milestones=(5,),
                                              samples_per_epoch=1, val_fraction=0.0, max_steps=1))


def checkpoint_asking_for(path, **model_fields):
    """A real tiny checkpoint whose stored config is edited to ask for `model_fields` (the config
    is not covered by the weights' hash, as an edited or hostile file's would not be)."""
    torch.manual_seed(0)
    save_checkpoint(path, build_model(TINY), tiny_experiment())
    state = torch.load(path, weights_only=True)
    state["experiment"]["model"].update(model_fields)
    torch.save(state, path)
    return path


@pytest.fixture
def dat(tmp_path):
    frames = np.random.default_rng(0).random((7 * 2, 12, 16)) < 0.3
    return write_dat(tmp_path / "s.dat", SpikeStream.from_bool(frames))


def reconstruct_argv(dat, method, out):
    return ["reconstruct", dat, "--height", 12, "--width", 16, "--header-columns", 0, "--out", out,
            "--method", method, "--device", "cpu", "--quiet", "--no-mp4"]


# ---- sizes ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("field, value", [("num_blocks", 10 ** 6), ("num_features", 10 ** 6), ("window", 10 ** 6 + 1),
                                          ("pad_multiple", 4 * 10 ** 6), ("num_blocks", True)])
def test_a_config_asking_for_an_absurd_size_names_the_field(field, value):
    with pytest.raises(ValueError, match=f"model.{field} must be"):
        dataclasses.replace(TINY, **{field: value})


@pytest.mark.parametrize("fields, named", [({"num_blocks": 10 ** 6}, "num_blocks"),
                                           ({"num_features": 4096, "num_blocks": 1024}, "GiB of float32 weights")])
def test_a_checkpoint_asking_for_an_absurd_network_is_refused_before_building_it(tmp_path, dat, capsys, fields, named):
    """10^6 blocks ran until killed; 4096 features x 1024 blocks (3.7 TB of weights) was a traceback."""
    path = checkpoint_asking_for(tmp_path / "huge.pt", **fields)
    with pytest.raises(ValueError, match=named) as info:
        model_from_checkpoint(path)
    assert "huge.pt" in str(info.value)
    code, err = run_cli(reconstruct_argv(dat, path, tmp_path / "o"), capsys)
    line = one_line(err)
    assert code == 2 and "huge.pt" in line and named in line, line
    assert not (tmp_path / "o" / "png").exists()


@pytest.mark.parametrize("model", [TINY, dataclasses.replace(TINY, representation="tfp"),
                                   dataclasses.replace(TINY, aif=False, num_blocks=3),
                                   dataclasses.replace(TINY, num_blocks=0)], ids=["lrrep", "tfp", "no-aif", "no-blocks"])
def test_the_parameter_count_from_the_config_is_the_built_networks(model):
    assert parameter_count(model) == count_parameters(build_model(model))


def test_weights_that_exceed_the_memory_are_refused_naming_the_fields():
    n = check_model_size(TINY, memory=1 << 40)
    assert n == parameter_count(TINY)
    with pytest.raises(ValueError, match="model.num_features=8, model.num_blocks=1"):
        check_model_size(TINY, memory=4 * n - 1)


# ---- a config file without its model section -----------------------------------------------------
def test_a_config_file_without_a_model_section_is_refused(tmp_path, capsys):
    cfg = tmp_path / "nomodel.json"
    cfg.write_text('{"name": "nomodel", "train": {"epochs": 1}}')
    with pytest.raises(ValueError, match='nomodel.json: no "model" section'):
        load_config(cfg)
    code, err = run_cli(["train", "--config", cfg, "--data", tmp_path, "--out", tmp_path / "run", "--device", "cpu"],
                        capsys)
    line = one_line(err)
    assert code == 2 and "nomodel.json" in line and '"model"' in line, line
    assert not (tmp_path / "run").exists()
    cfg.write_text('{"name": "defaults", "model": {}}')  # the paper's network, asked for explicitly
    assert load_config(cfg).model == ModelConfig()


# ---- NaN weights and NaN frames ------------------------------------------------------------------
def nan_checkpoint(path):
    torch.manual_seed(0)
    model = build_model(TINY)
    with torch.no_grad():
        next(iter(model.parameters()))[0].fill_(float("nan"))
    save_checkpoint(path, model, tiny_experiment())  # its hash is of the NaN weights: only the values are wrong
    return path


def test_nan_weights_are_refused_where_checkpoints_load(tmp_path):
    path = nan_checkpoint(tmp_path / "nan.pt")
    for load in (load_checkpoint, model_from_checkpoint):
        with pytest.raises(ValueError, match=r"nan.pt: its weights hold NaN or infinite values \(\d+ of \d+ in '"):
            load(path)


def test_reconstruct_refuses_a_nan_checkpoint_and_writes_nothing(tmp_path, dat, capsys):
    """It wrote black PNGs and returned 0."""
    path = nan_checkpoint(tmp_path / "nan.pt")
    code, err = run_cli(reconstruct_argv(dat, path, tmp_path / "o"), capsys)
    line = one_line(err)
    assert code == 2 and "nan.pt" in line and "NaN" in line, line
    assert not list((tmp_path / "o").glob("png/*.png")) and not (tmp_path / "o" / "frames.gif").exists()


def test_reconstruct_refuses_non_finite_output_frames(tmp_path, dat, monkeypatch, capsys):
    """Whatever the method: finite weights can overflow, and a NaN frame encodes as black."""
    import pipelines.reconstruct as rec

    class Overflowing:
        name, window = "overflowing", 7

        def frames(self, source):
            for i in range(source.num_windows):
                yield i, np.full((12, 16), np.inf if i else 0.5, np.float32)

    monkeypatch.setattr(rec, "method_from_spec", lambda *a, **k: Overflowing())
    code, err = run_cli(reconstruct_argv(dat, "tfp", tmp_path / "o"), capsys)
    line = one_line(err)
    assert code == 2 and "overflowing" in line and "frame 1" in line and "infinite" in line, line
    assert not list((tmp_path / "o").glob("png/*.png")) and not (tmp_path / "o" / "reconstruct.json").exists()


# ---- a refused pickle names the global -----------------------------------------------------------
class Payload:
    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


class SystemPayload:
    def __reduce__(self):
        return (os.system, ("true",))


@pytest.mark.parametrize("protocol", [0, 2, 4, 5])
@pytest.mark.parametrize("container", ["bare", "zip"])
@pytest.mark.parametrize("payload", ["open", "system"])
def test_a_refused_pickle_names_the_global_it_imports(tmp_path, protocol, container, payload):
    """Protocol 4 and 5 pickles were refused as 'Unsupported operand 149' and blocked modules
    (posix) as 'not a torch checkpoint file', neither naming what the file would have run."""
    marker = tmp_path / "pwned"
    obj = Payload(str(marker)) if payload == "open" else SystemPayload()
    data = pickle.dumps(obj, protocol=protocol)
    path = tmp_path / "evil.pt"
    if container == "bare":
        path.write_bytes(data)
    else:
        torch.save({"a": 1}, tmp_path / "ok.pt")
        with zipfile.ZipFile(tmp_path / "ok.pt") as z, zipfile.ZipFile(path, "w") as out:
            for name in z.namelist():
                out.writestr(name, data if name.endswith("data.pkl") else z.read(name))
    with pytest.raises(ValueError) as info:
        load_checkpoint(path)
    message = str(info.value)
    assert not marker.exists()
    assert "evil.pt" in message and "not a torch checkpoint file" not in message, message
    assert ("open" if payload == "open" else "system") in message and "nothing in it was run" in message, message


def test_a_refused_protocol_5_pickle_is_one_line_on_the_command_line(tmp_path, dat, capsys):
    path = tmp_path / "evil.pt"
    path.write_bytes(pickle.dumps(SystemPayload(), protocol=5))
    code, err = run_cli(reconstruct_argv(dat, path, tmp_path / "o"), capsys)
    line = one_line(err)
    assert code == 2 and "evil.pt" in line and "global posix.system" in line, line


@pytest.mark.parametrize("section, field", [("train", "lr"), ("model", "num_blocks"), ("train", "crop")])
def test_a_checkpoint_config_with_a_400_digit_number_is_one_line(tmp_path, section, field):
    """An OverflowError traceback from math.isfinite before."""
    torch.manual_seed(0)
    save_checkpoint(tmp_path / "big.pt", build_model(TINY), tiny_experiment())
    state = torch.load(tmp_path / "big.pt", weights_only=True)
    state["experiment"][section][field] = 10 ** 400
    torch.save(state, tmp_path / "big.pt")
    with pytest.raises(ValueError, match=f"big.pt.*{section}.{field} is an integer of about 401 digits"):
        model_from_checkpoint(tmp_path / "big.pt")


def test_panel_refuses_non_finite_frames(tmp_path, monkeypatch, capsys):
    import model.methods as methods
    # 16 x 16: panel refuses a smaller stream before any method runs (round ten)
    frames = np.random.default_rng(0).random((7 * 2, 16, 16)) < 0.3
    dat = write_dat(tmp_path / "s16.dat", SpikeStream.from_bool(frames))

    class Overflowing:
        name, window = "overflowing", 7

        def frames(self, source):
            for i in range(source.num_windows):
                yield i, np.full((16, 16), np.nan, np.float32)

    monkeypatch.setattr(methods, "method_from_spec", lambda *a, **k: Overflowing())
    code, err = run_cli(["panel", dat, "-o", tmp_path / "p.png", "--height", 16, "--width", 16, "--header-columns", 0,
                         "--window", 7, "--methods", "tfp", "--device", "cpu"], capsys)
    line = one_line(err)
    assert code == 2 and "overflowing" in line and "NaN" in line, line
    assert not (tmp_path / "p.png").exists()
