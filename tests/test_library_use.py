"""A Python script runs a generation and a trade study with the objects the CLI uses, and the
library never imports the command line (`pipelines`)."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run_script(code: str, tmp_path: Path) -> str:
    """stdout of `code` run as a user's script in a fresh interpreter (cwd: tmp_path)."""
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=240, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_a_script_generates_a_dataset_without_the_command_line(tmp_path):
    out = run_script("""
        import sys
        from spikesim.dataset import open_dataset
        from spikesim.generation import PRESETS, generate, plan_rllr
        preset = PRESETS["small"].replace(height=8, width=12, rllr_steps=20, rllr_gt_stride=10)
        jobs = plan_rllr(preset, seed=3, count=2, source="pattern")
        report = generate(jobs, "data", workers=1, show_progress=False)
        scenes = open_dataset("data")
        print(len(report["generated"]), [s.num_steps for s in scenes], scenes[0].height, scenes[0].width)
        print(sorted(m for m in sys.modules if m.split(".")[0] == "pipelines"))
    """, tmp_path)
    assert out.splitlines() == ["2 [20, 20] 8 12", "[]"]


def test_a_script_plans_a_trade_study_and_reads_its_report_without_the_command_line(tmp_path):
    out = run_script("""
        import sys
        from pathlib import Path
        from pipelines.tradeoff_study import StudyConfig, collect_rows, plan_runs
        cfg = StudyConfig(scenes=("ball",), lights=("low",), knobs=("spp",), spp_values=(1, 4))
        print([r.name for r in plan_runs(cfg)])
        print(collect_rows(cfg, Path("nothing_yet")))
        print(sorted(m for m in sys.modules if m.split(".")[0] == "pipelines"))
    """, tmp_path)
    # the study joins the simulator and the model, so it sits in pipelines/, but no command module
    # (pipelines.tradeoff, its parser) is loaded
    assert out.splitlines() == [str(["reference", "floor: sensor seed", "floor: sensor+render seed", "spp=1", "spp=4"]),
                                "[]", str(["pipelines", "pipelines.tradeoff_study"])]


def test_the_generate_command_and_a_script_plan_the_same_jobs():
    """The CLI builds its jobs with spikesim.generation: no second planner in pipelines."""
    import pipelines.generate as cli
    import spikesim.generation as lib

    assert cli.plan_llr is lib.plan_llr and cli.generate is lib.generate and cli.PRESETS is lib.PRESETS
    preset = dataclasses.replace(lib.PRESETS["small"], height=8, width=12)
    assert [j.digest for j in lib.plan_llr(preset, scenes=["ball"])] == [j.digest for j in cli.plan_llr(preset, scenes=["ball"])]


def test_the_library_does_not_import_the_command_line():
    sources = [p for p in (ROOT / "spikesim").rglob("*.py")
               if "import pipelines" in p.read_text() or "from pipelines" in p.read_text()]
    assert sources == []


def test_a_script_trains_and_evaluates_a_model_without_the_command_line(tmp_path):
    """The training loop, its resume and the evaluation are the model package's: a notebook runs
    a (tiny) budgeted run, continues it, and scores it, and `pipelines` is never imported."""
    out = run_script("""
        import dataclasses, sys
        from model.config import ExperimentConfig, ModelConfig, TrainConfig
        from model.methods import ModelMethod, method_from_spec
        from model.training import run_training
        from spikesim.dataset import open_dataset
        from spikesim.generation import PRESETS, generate, plan_rllr
        preset = PRESETS["small"].replace(height=16, width=16, rllr_steps=30, rllr_gt_stride=1)
        generate(plan_rllr(preset, seed=3, count=2, source="pattern"), "data", workers=1, show_progress=False)
        scenes = open_dataset("data")
        exp = ExperimentConfig("nb", model=ModelConfig(window=7, num_features=8, num_blocks=1, deform_groups=2),
                               train=TrainConfig(num_windows=3, crop=8, batch_size=2, max_steps=2, epochs=100,
                                                 lr_schedule="cosine", val_every=100))
        first = run_training(exp, scenes[:1], [], "run", device="cpu", progress=False)
        more = dataclasses.replace(exp, train=dataclasses.replace(exp.train, max_steps=3))
        second = run_training(more, scenes[:1], [], "run", device="cpu", resume=True, progress=False)
        model = ModelMethod("nb", __import__("pathlib").Path("run/last.pt"))
        print(first["steps"], second["steps"], model.span, method_from_spec("tfp:21", window=7).name)
        print(sorted(m for m in sys.modules if m.split(".")[0] == "pipelines"))
    """, tmp_path)
    assert out.splitlines() == ["2 3 21 TFP-21", "[]"]


def test_a_frame_of_another_size_names_how_to_make_a_camera_of_that_size():
    import numpy as np

    from spikesim import SpikeCamera
    from spikesim.simulate import Simulator
    with pytest.raises(ValueError, match=r"expected \(250, 400\).*SpikeCamera.realistic\(height=\.\.\., width=\.\.\.\)"):
        Simulator(SpikeCamera.realistic(), backend="numpy").run(np.zeros((2, 64, 100), np.float32))
    small = Simulator(SpikeCamera.realistic(height=64, width=100), backend="numpy").run(np.zeros((2, 64, 100), np.float32))
    assert small.num_steps == 2


def test_api_arguments_of_the_wrong_kind_are_named():
    """Round six: max_frames=-1 ran as 'no limit', SceneRenderer(camera="realistic") was an
    AttributeError deep inside, ground_truth(spp=0) took the default and spp=-1 was Dr.Jit's error."""
    import numpy as np
    import pytest

    from spikesim.camera import SpikeCamera
    from spikesim.render import SceneRenderer
    from spikesim.simulate import Simulator
    sim = Simulator(SpikeCamera.realistic(height=8, width=12), backend="numpy")
    with pytest.raises(ValueError, match="max_frames must be an integer >= 0"):
        sim.run([np.zeros((8, 12), np.float32)] * 3, max_frames=-1)
    with pytest.raises(TypeError, match=r"SpikeCamera.preset\('realistic'\)"):
        SceneRenderer("tests/data/plain_scene/scene.xml", camera="realistic")
    r = SceneRenderer("tests/data/plain_scene/scene.xml", variant="mono", spp=1, resolution=(5, 8))
    for bad in (0, -1, 1.5, "4", True):
        with pytest.raises(ValueError, match="must be a positive integer"):
            r.ground_truth(0, spp=bad)
        with pytest.raises(ValueError, match="must be a positive integer"):
            r.render_step(0, spp=bad)
