"""The documented entry points (the `spikesim` script, and `torchrun` on it) work from a folder
holding a user's own `model.py`, `scenes.py`, `pipelines.py` and `spikesim.py`: a script's
sys.path starts at its own folder, not the working one, so these files cannot shadow the
project's packages (`python -m pipelines.cli` would import them: it is not a documented form)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spikesim import SpikeStream, write_dat

BIN = Path(sys.executable).parent
SHADOWS = ("model", "scenes", "pipelines", "spikesim")


@pytest.fixture
def users_folder(tmp_path):
    for name in SHADOWS:
        (tmp_path / f"{name}.py").write_text(f'raise ImportError("the user\'s own {name}.py was imported")\n')
    rng = np.random.default_rng(0)
    write_dat(tmp_path / "s.dat", SpikeStream.from_bool(rng.random((82, 16, 24)) < 0.1))
    return tmp_path


def _run(argv, cwd):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_the_spikesim_script_is_not_shadowed(users_folder):
    r = _run([str(BIN / "spikesim"), "reconstruct", "s.dat", "--height", "16", "--width", "24", "--method", "tfp",
              "-o", "rec", "--no-gif", "--no-mp4", "--quiet"], users_folder)
    assert r.returncode == 0, r.stderr
    assert "was imported" not in r.stderr and len(list((users_folder / "rec").rglob("*.png"))) == 2


def test_torchrun_on_the_script_is_not_shadowed(users_folder):
    torchrun = BIN / "torchrun"
    if not torchrun.exists():
        torchrun = shutil.which("torchrun")
    if torchrun is None:
        pytest.skip("torchrun is not installed")
    r = _run([str(torchrun), "--standalone", "--nproc_per_node", "1", str(BIN / "spikesim"), "train", "--help"],
             users_folder)
    assert r.returncode == 0, r.stderr
    assert "was imported" not in r.stderr and "--resume" in r.stdout


def test_the_shadowing_is_real(users_folder):
    """The guard against a test that cannot fail: `python -m` from that folder does import them."""
    r = _run([sys.executable, "-m", "pipelines.cli", "--version"], users_folder)
    assert r.returncode != 0 and "was imported" in r.stderr


def test_docs_give_only_forms_that_cannot_be_shadowed():
    root = Path(__file__).resolve().parents[1]
    for doc in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        text = doc.read_text()
        assert "-m pipelines.cli" not in text, f"{doc.name} documents `python -m pipelines.cli`"
