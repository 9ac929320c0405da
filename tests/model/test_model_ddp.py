"""Multi-process training with torchrun (DDP on gloo, two CPU processes): both ranks end with the
same weights, and they equal one process with the same global batch, within float rounding."""
from __future__ import annotations

import csv
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from model.checkpoint import load_checkpoint

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent("""
    import os, sys
    sys.path[:0] = [{root!r}, {tests!r}]
    from modeltest_fakes import make_scene
    from test_model_training import tiny_experiment
    from pipelines.train import run_training
    scenes = [make_scene(f"s{{i}}", 16, 20, 7 * 6, brightness=0.3, velocity=0.2, seed=i) for i in range(3)]
    exp = tiny_experiment(max_steps=3, batch_size=4, samples_per_epoch=8)
    summary = run_training(exp, scenes[:2], [], sys.argv[1], device="cpu", progress=False)
    rank = os.environ.get("RANK", "0")
    with open(os.path.join(sys.argv[1], f"rank{{rank}}.txt"), "w") as f:  # not stdout: torchrun may drop it
        f.write(f"{{rank}} {{summary['processes']}} {{summary['weights_sha256']}}")
""")


def test_two_gloo_processes_equal_one_process(tmp_path: Path) -> None:
    script = tmp_path / "train_once.py"
    script.write_text(SCRIPT.format(root=str(ROOT), tests=str(ROOT / "tests" / "model")))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    single = subprocess.run([sys.executable, str(script), str(tmp_path / "one")], env=env,
                            capture_output=True, text=True, timeout=600)
    assert single.returncode == 0, single.stderr[-3000:]
    multi = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                            str(script), str(tmp_path / "two")], env=env, capture_output=True, text=True, timeout=600)
    assert multi.returncode == 0, multi.stderr[-3000:]
    ranks = sorted((tmp_path / "two" / f"rank{r}.txt").read_text().split() for r in (0, 1))
    assert [r[0] for r in ranks] == ["0", "1"] and all(r[1] == "2" for r in ranks)
    assert ranks[0][2] == ranks[1][2]  # the same weights on both ranks, bit for bit
    one = load_checkpoint(tmp_path / "one" / "last.pt")["model_state"]
    two = load_checkpoint(tmp_path / "two" / "last.pt")["model_state"]
    for k in one:  # gradients averaged over the two halves of each batch = the whole batch's gradient
        torch.testing.assert_close(two[k], one[k], atol=1e-5, rtol=1e-4, msg=k)
    losses = [[float(r["loss"]) for r in csv.DictReader((tmp_path / d / "train_log.csv").open())] for d in ("one", "two")]
    assert len(losses[0]) == 3 and losses[1] == pytest.approx(losses[0], rel=1e-5)
