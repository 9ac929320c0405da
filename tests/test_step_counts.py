"""N requested steps are N steps written, from every frame source and at every keyframe spacing
(spikesim.keyframes is the one definition): the .dat, its sidecar (or meta.json) and `inspect`
all say N. Tiny frames (4 x 8) on the NumPy sensor keep the grid of steps 1..100 x
keyframe_every 1..8 fast; the command-line cases run CLI_STEPS, every remainder of it."""
from __future__ import annotations

import contextlib
import dataclasses
import io
import json
from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import main
from spikesim.camera import SpikeCamera
from spikesim.keyframes import keyframe_count, keyframe_steps, steps_covered
from spikesim.simulate import Simulator
from spikesim.stream import DatReader, read_sidecar

H, W = 4, 8
STEPS = range(1, 101)
SPACINGS = range(1, 9)
#: The step counts the command-line cases run (each a simulate and an inspect call): every count up to
#: 2 x 8 + 1, so every remainder modulo every spacing twice, and the ends and the case that wrote 49
#: steps for 50. The in-process cases and the definition keep the whole grid.
CLI_STEPS = (*range(1, 18), 25, 49, 50, 51, 99, 100)


def cli(*argv) -> str:
    """stdout of one in-process command (rc 0 asserted)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main([str(a) for a in argv])
    assert rc == 0, argv
    return out.getvalue()


def inspected_steps(dat: Path) -> int:
    text = cli("inspect", dat, "--height", H, "--width", W, "--json")
    return json.loads(text[text.index("{"):])["num_steps"]


def assert_steps(dat: Path, n: int, sidecar: dict) -> None:
    assert len(DatReader(dat, H, W, flip=True)) == n, dat
    assert sidecar["num_steps"] == n
    assert inspected_steps(dat) == n


def simulate_cli(tmp_path: Path, steps: int, k: int, *source) -> None:
    dat = tmp_path / "s.dat"
    cli("simulate", *source, "--steps", steps, "--keyframe-every", k, "--height", H, "--width", W,
        "--backend", "numpy", "--quiet", "-o", dat)
    assert_steps(dat, steps, read_sidecar(dat))


# ---- the definition -------------------------------------------------------------------------------
def test_keyframe_count_and_steps_covered_agree():
    for k in SPACINGS:
        for n in STEPS:
            m = keyframe_count(n, k)
            assert steps_covered(m, k) >= n > steps_covered(m - 1, k)  # the fewest frames that cover n
            assert list(keyframe_steps(5, n, k)) == [5 + j * k for j in range(m)]
    assert keyframe_count(50, 4) == 14  # the case that wrote 49 steps (a floored count: 13 keyframes)


def test_keep_last_holds_back_the_last_keyframe_only_between_keyframes():
    assert steps_covered(5, 4, keep_last=True) == 16 and steps_covered(5, 4) == 17
    assert steps_covered(5, 1, keep_last=True) == 5  # a frame per step: nothing to hold back
    with pytest.raises(ValueError, match="keyframe_every"):
        keyframe_count(10, 0)


# ---- every source ---------------------------------------------------------------------------------
@pytest.mark.parametrize("k", SPACINGS)
def test_the_moving_pattern_writes_the_steps_asked(k, tmp_path):
    for n in CLI_STEPS:
        simulate_cli(tmp_path, n, k)


@pytest.mark.parametrize("k", SPACINGS)
def test_an_npy_array_writes_the_steps_asked(k, tmp_path):
    rng = np.random.default_rng(k)
    npy = tmp_path / "y.npy"
    np.save(npy, rng.uniform(0, 0.5, (keyframe_count(100, k), H, W)).astype(np.float32))
    for n in CLI_STEPS:
        simulate_cli(tmp_path, n, k, "--frames", npy)


@pytest.mark.parametrize("k", SPACINGS)
def test_an_exr_folder_writes_the_steps_asked(k, tmp_path):
    """--steps counts steps, not files: k-spaced files cover (m - 1) k + 1 steps."""
    from spikesim.imageio import write_exr
    folder = tmp_path / "exr"
    folder.mkdir()
    rng = np.random.default_rng(k)
    for j in range(keyframe_count(100, k)):
        write_exr(folder / f"{j:04d}.exr", rng.uniform(0, 0.5, (H, W)).astype(np.float32))
    for n in CLI_STEPS:
        simulate_cli(tmp_path, n, k, "--frames", folder)


def test_an_exr_folder_without_steps_simulates_every_step_it_covers(tmp_path):
    from spikesim.imageio import write_exr
    folder = tmp_path / "exr"
    folder.mkdir()
    for j in range(5):
        write_exr(folder / f"{j}.exr", np.full((H, W), 0.2, np.float32))
    dat = tmp_path / "s.dat"
    cli("simulate", "--frames", folder, "--keyframe-every", 4, "--height", H, "--width", W, "--backend", "numpy",
        "--quiet", "-o", dat)
    assert_steps(dat, steps_covered(5, 4), read_sidecar(dat))


# A rendered scene loads Mitsuba and renders each keyframe (about a second a case here), so it is
# covered on a few cases, among them the one that wrote 49 steps for 50 (the pattern now writes 50).
@pytest.mark.parametrize("n,k", [(50, 4), (1, 1), (1, 8), (9, 8), (10, 3)])
def test_a_rendered_scene_writes_the_steps_asked(n, k, tmp_path):
    pytest.importorskip("mitsuba")
    simulate_cli(tmp_path, n, k, "--scene", "ball", "--spp", 1, "--device", "llvm")


@pytest.mark.parametrize("k", SPACINGS)
def test_a_generated_scene_writes_the_steps_asked(k, tmp_path):
    from spikesim.generation import SceneJob
    from spikesim.generation.job import run_job

    cam = SpikeCamera.realistic(height=H, width=W).to_dict()
    for n in CLI_STEPS:
        job = SceneJob(name=f"p{n}", source={"type": "pattern", "peak_y": 0.3}, camera=cam, render={},
                       num_steps=n, gt_steps=(0,), keyframe_every=k)
        run_job(job, tmp_path, backend="numpy")
        folder = tmp_path / job.name
        meta = json.loads((folder / "meta.json").read_text())
        assert_steps(folder / "spikes.dat", n, meta["simulator"])


# A generated scene from a rendered source: sampled like the rendered scene above, with the case
# that wrote 49 steps for 50 among them.
@pytest.mark.parametrize("n,k", [(50, 4), (1, 8), (9, 8), (10, 3)])
def test_a_generated_rendered_scene_writes_the_steps_asked(n, k, tmp_path):
    pytest.importorskip("mitsuba")
    from spikesim.generation import PRESETS, plan_llr
    from spikesim.generation.job import run_job

    preset = PRESETS["small"].replace(height=H, width=W, llr_windows=1, spp=1, gt_spp=1, keyframe_every=k)
    job = dataclasses.replace(plan_llr(preset, scenes=["ball"], lights=("low",))[0], num_steps=n, gt_steps=(0,),
                              windows=())
    run_job(job, tmp_path, backend="numpy", device="llvm")
    folder = tmp_path / job.name
    meta = json.loads((folder / "meta.json").read_text())
    assert_steps(folder / "spikes.dat", n, meta["simulator"])


class _Stripes:
    """A renderer as the trade study calls it: render_step(step, spp) and motion_px(step)."""

    def render_step(self, step: int, spp: int | None = None) -> np.ndarray:
        return np.full((H, W), 0.1 + 0.01 * (step % 7), np.float32)

    def motion_px(self, step: int) -> float:
        return 0.0


@pytest.mark.parametrize("k", SPACINGS)
def test_the_trade_study_simulates_the_steps_asked(k):
    from spikesim.quality import QualitySettings

    q = QualitySettings.of("t", spp=1, gt_spp=1, variant="mono", keyframe_policy="fixed" if k > 1 else "every",
                        keyframe_every=k)
    for n in STEPS:
        sim = Simulator(SpikeCamera.noiseless(height=H, width=W), backend="numpy")
        assert sum(p.num_steps for p in q.simulate(sim, _Stripes(), 3, n)) == n


@pytest.mark.parametrize("k", SPACINGS)
def test_simulator_run_gives_the_steps_its_keyframes_cover(k):
    frames = np.full((keyframe_count(100, k), H, W), 0.2, np.float32)
    for n in STEPS:
        m = keyframe_count(n, k)
        sim = Simulator(SpikeCamera.noiseless(height=H, width=W), backend="numpy", chunk_steps=16)
        assert sim.run(iter(frames[:m]), keyframe_every=k).num_steps == steps_covered(m, k)
