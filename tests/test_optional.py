"""Optional dependencies (extras): a feature whose package is missing says, in one line, which
extra installs it, and the command exits with status 2 instead of a traceback."""
from __future__ import annotations

import sys

import pytest

from cli_testing import one_line, run_cli
from spikesim._optional import EXTRAS, require
from spikesim.errors import UnavailableError


def hide(monkeypatch, *modules):
    """Make `import m` fail for each module as if it were not installed (None in sys.modules)."""
    for name in modules:
        monkeypatch.setitem(sys.modules, name, None)


def test_require_returns_the_module_when_present():
    matplotlib = pytest.importorskip("matplotlib")
    assert require("matplotlib", "plot", "anything") is matplotlib


@pytest.mark.parametrize("module, extra", [("matplotlib", "plot"), ("tensorboard", "train"),
                                           ("imageio_ffmpeg", "video"), ("ray", "cluster")])
def test_a_missing_module_names_its_extra_and_the_feature(monkeypatch, module, extra):
    hide(monkeypatch, module)
    with pytest.raises(UnavailableError) as info:
        require(module, extra, "the feature asked for")
    text = str(info.value)
    assert "\n" not in text and module in text and "the feature asked for" in text
    assert f"pip install 'spikesim[{extra}]'" in text


def test_every_extra_named_is_declared_in_pyproject():
    from pathlib import Path
    import tomllib
    declared = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    extras = declared["project"]["optional-dependencies"]
    assert set(EXTRAS) <= set(extras)
    for extra, modules in EXTRAS.items():
        for module in modules:
            # the distribution that provides each module is listed in its extra
            assert any(req.lower().replace("-", "_").startswith(module.lower()) for req in extras[extra]), (extra, module)


def test_require_of_an_undeclared_extra_or_module_is_a_bug():
    with pytest.raises(KeyError):
        require("json", "nonesuch", "x")
    with pytest.raises(KeyError):
        require("json", "plot", "x")


def test_tradeoff_without_matplotlib_is_one_line_naming_the_plot_extra(monkeypatch, tmp_path, capsys):
    """Checked before the study runs, so a missing plotting package costs no rendering."""
    hide(monkeypatch, "matplotlib", "matplotlib.pyplot")
    code, err = run_cli(["tradeoff", "--report-only", "--out", tmp_path / "t"], capsys)
    line = one_line(err)
    assert code == 2 and "spikesim[plot]" in line and "matplotlib" in line, line
    assert not (tmp_path / "t").exists()


def test_training_without_tensorboard_says_which_extra_and_goes_on(monkeypatch, tmp_path, capsys):
    from model.training import _Tensorboard
    hide(monkeypatch, "tensorboard", "torch.utils.tensorboard")
    board = _Tensorboard(tmp_path / "tb")
    assert board.writer is None
    err = capsys.readouterr().err
    assert "spikesim[train]" in err and "CSV" in err and len(err.strip().splitlines()) == 1


def test_reconstruct_without_ffmpeg_notes_the_video_extra_and_writes_the_rest(monkeypatch, tmp_path, capsys):
    import numpy as np
    from spikesim.stream import SpikeStream, write_dat
    rng = np.random.default_rng(0)
    dat = write_dat(tmp_path / "s.dat", SpikeStream.from_bool(rng.random((21, 6, 8)) < 0.3))
    hide(monkeypatch, "imageio_ffmpeg")
    code, err = run_cli(["reconstruct", dat, "--height", 6, "--width", 8, "--window", 7, "--out", tmp_path / "o",
                         "--quiet", "--device", "cpu", "--header-columns", 0], capsys)
    assert code == 0 and "spikesim[video]" in one_line(err)
    assert (tmp_path / "o" / "frames.gif").exists() and not (tmp_path / "o" / "frames.mp4").exists()


def test_the_set_up_script_installs_every_extra_the_tests_and_demo_use():
    """scripts/bootstrap.sh (behind the README's demo and test commands) installs all extras."""
    import re
    import tomllib
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    extras = set(tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    installed = re.findall(r'pip install -q -e "\.\[([\w,]+)\]"', (root / "scripts" / "bootstrap.sh").read_text())
    assert len(installed) == 1 and set(installed[0].split(",")) == extras, (installed, extras)


def test_every_command_loads_without_any_extra(monkeypatch, capsys):
    """A core install (`pip install .`) has the whole command line: no module imports an extra's
    package at load time."""
    from pipelines import cli
    hide(monkeypatch, "matplotlib", "matplotlib.pyplot", "tensorboard", "torch.utils.tensorboard",
         "imageio_ffmpeg", "ray")
    for name in [m for m in sys.modules if m.startswith("pipelines.") and m not in ("pipelines.cli",)]:
        monkeypatch.delitem(sys.modules, name)
    parser = cli.build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert set(cli._COMMAND_MODULE) <= set(commands), sorted(set(cli._COMMAND_MODULE) - set(commands))


def test_generate_ray_without_ray_is_one_line_naming_the_cluster_extra(monkeypatch, tmp_path, capsys):
    """--ray without Ray installed: the same one-line form as every other extra, nothing written."""
    hide(monkeypatch, "ray")
    code, err = run_cli(["generate", "llr", "--preset", "small", "--scenes", "fan", "--windows", 1, "--ray", "local",
                          "-o", tmp_path / "g", "--quiet"], capsys)
    line = one_line(err)
    assert code == 2 and "pip install 'spikesim[cluster]'" in line and "does not import here" in line, line
    assert "--ray" in line
