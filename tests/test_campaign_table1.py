"""Stage table1 of the GPU campaign (pipelines/gpu_campaign/stages.py `stage_table1`): the Table-1
networks (`full`, S2I, WGSE, RSIR, SSML) trained at equal training FLOP on the RLLR slice and
scored on the LLR. The fast tests run the stage with its commands replaced by stand-ins (no child
process): the reference's budget from its share of the box, every other network's steps from the
reference's FLOP, a network that cannot train recorded while the others go on, the skips, the work
folder's guard and the report's table. The slow one runs the real call (TABLE1_CALL) dry, on the CPU
at the tiny size (about 60 s on the 2-core VM: five trainings and one evaluate)."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipelines.gpu_campaign import PROFILES, TABLE1_CALL, Options, StageRecord
from pipelines.gpu_campaign.outputs import out_problems, report_markdown
from pipelines.gpu_campaign.stages import RUN_MARKER, Campaign, CommandResult, SkipStage, StageFailed, stage_table1

ROOT = Path(__file__).resolve().parents[1]
#: GFLOP per training step of the stand-in networks (the gpu profile's labels)
COST = {"full": 100.0, "s2i": 200.0, "wgse": 50.0, "rsir": 25.0, "ssml": 100.0}
BOX_S = 400.0


def _scores(labels):
    row = {"psnr_aligned": 20.0, "psnr": 25.0, "ssim": 0.5, "frames": 21}
    return {"methods": {lb: row for lb in labels},
            "groups": {"ALL_low": {lb: {**row, "psnr_aligned": 18.0} for lb in labels},
                       "ALL_normal": {lb: {**row, "psnr_aligned": 22.0} for lb in labels}}}


def _work(tmp_path: Path) -> Path:
    work = tmp_path / "W"
    for folder, scene in (("rllr", "rllr_0000"), ("llr", "fan_low")):
        (work / folder / scene).mkdir(parents=True)
        (work / folder / scene / "meta.json").write_text("{}")
    return work


def _campaign(work: Path, calls: list, *, fail=(), broken=(), eval_fails=False, ref_steps=40) -> Campaign:
    """A campaign in its table1 stage (gpu profile) whose commands are stand-ins: the FLOP count
    gives COST, `train` writes last.pt and reports its steps (or fails as out of memory for the
    labels in `fail`), `evaluate` scores what it is given (or fails when given several)."""
    from pipelines.gpu_campaign.runner import _load_run_token

    o = Options(out=work.parent / "o", work=work, profile=PROFILES["gpu"], part="2", stages=("table1",))
    c = Campaign(o)
    c.run_token = _load_run_token(o)
    c.current, c.box_end = StageRecord("table1"), time.monotonic() + BOX_S
    (work / "logs").mkdir(exist_ok=True)

    def command(argv, box_s=None):
        argv = [str(a) for a in argv]
        calls.append((argv, box_s))
        c.note_log("$ " + " ".join(argv))
        if argv[1] == "-c":  # the FLOP count
            nets = {label: ({"error": "ValueError: unknown arch"} if label in broken else
                            {"parameters": 1000 + i, "gflop_per_frame": 10.0 * (i + 1), "train_gflop_per_step": COST[label]})
                    for i, (label, _) in enumerate(PROFILES["gpu"].table1)}
            return CommandResult(0, False, 0.1, json.dumps({"frame": [250, 400], "networks": nets}))
        sub = argv[argv.index("pipelines.cli") + 1]
        out = Path(argv[argv.index("-o") + 1])
        if sub == "train":
            if out.name in fail:
                c.note_log("Traceback (most recent call last):\n  File \"x\", line 1\n"
                           "torch.OutOfMemoryError: CUDA out of memory. Tried to allocate 2.00 GiB\n[no stdout]")
                return CommandResult(1, False, 0.5, "")
            out.mkdir(parents=True)
            (out / "last.pt").write_text("weights")
            steps = int(argv[argv.index("--max-steps") + 1]) if "--max-steps" in argv else ref_steps
            return CommandResult(0, False, 1.0, json.dumps({"steps": steps, "train_seconds": 2.0 * steps,
                                                            "samples_per_s": 4.0, "precision": "bf16"}))
        assert sub == "evaluate"
        labels = [m.split("=", 1)[0] for m in argv[argv.index("--methods") + 1:argv.index("--json")]]
        if eval_fails and len(labels) > 1:
            c.note_log("torch.OutOfMemoryError: CUDA out of memory\n[no stdout]")
            return CommandResult(1, False, 0.5, "")
        return CommandResult(0, False, 1.0, json.dumps(_scores(labels)))

    c.command = command
    return c


def _trains(calls):
    return {Path(a[a.index("-o") + 1]).name: (a, box) for a, box in calls if "train" in a and "-c" not in a}


def test_every_network_trains_the_references_flop_and_one_that_cannot_train_is_recorded(tmp_path):
    calls: list = []
    fig = stage_table1(_campaign(_work(tmp_path), calls, fail=("s2i",)))
    nets = fig["networks"]
    assert list(nets) == ["full", "s2i", "wgse", "rsir", "ssml"]
    # the reference (full) trains for its share of the box: (box - scoring) / 5 networks, less its overhead
    p = PROFILES["gpu"]
    share = (BOX_S - p.table1_eval_s) / 5
    argv, box = _trains(calls)["full"]
    assert box == pytest.approx(share, abs=2)
    minutes = float(argv[argv.index("--budget-minutes") + 1])
    assert minutes == pytest.approx((share - p.table1_overhead_s) * 0.85 / 60, abs=0.01)
    assert nets["full"]["role"] == "reference" and fig["reference"] == "full"
    assert fig["train_gflop_each"] == 40 * COST["full"] == nets["full"]["train_gflop"]
    # the others: the same training FLOP, each in steps of its own cost
    assert {lb: nets[lb]["planned_steps"] for lb in ("wgse", "rsir", "ssml")} == {"wgse": 80, "rsir": 160, "ssml": 40}
    for lb in ("wgse", "rsir", "ssml"):
        argv, _ = _trains(calls)[lb]
        assert argv[argv.index("--max-steps") + 1] == str(nets[lb]["planned_steps"])
        assert nets[lb]["train_gflop"] == fig["train_gflop_each"] and nets[lb]["equal_flop"] is True
    for argv, _ in _trains(calls).values():  # as stage train: bf16, cosine to the last step; one epoch
        assert {"--precision", "bf16", "--lr-schedule", "cosine", "--samples-per-epoch", "--num-workers"} <= set(argv)
    # s2i ran out of memory: recorded with the error line; the others went on and were scored together
    assert fig["failed"] == ["s2i"] and "scores" not in nets["s2i"]
    assert "status 1" in nets["s2i"]["error"] and "CUDA out of memory" in nets["s2i"]["error"]
    evaluates = [a for a, _ in calls if "evaluate" in a]
    assert len(evaluates) == 1 and not any(m.startswith("s2i=") for m in evaluates[0])
    for lb in ("full", "wgse", "rsir", "ssml"):
        assert nets[lb]["scores"]["low"]["psnr_aligned"] == 18.0 and nets[lb]["scores"]["normal"]["psnr_aligned"] == 22.0
        assert nets[lb]["parameters"] > 0 and nets[lb]["gflop_per_frame"] > 0 and nets[lb]["seconds"] > 0
    assert fig["frame"] == [250, 400]


def test_when_the_reference_cannot_train_the_next_network_is_the_reference(tmp_path):
    calls: list = []
    fig = stage_table1(_campaign(_work(tmp_path), calls, fail=("full",)))
    nets = fig["networks"]
    assert fig["reference"] == "s2i" and nets["s2i"]["role"] == "reference" and "--budget-minutes" in _trains(calls)["s2i"][0]
    assert fig["train_gflop_each"] == 40 * COST["s2i"]
    assert nets["wgse"]["planned_steps"] == 160 and nets["rsir"]["planned_steps"] == 320
    assert fig["failed"] == ["full"] and "CUDA out of memory" in nets["full"]["error"]


def test_a_network_whose_config_does_not_build_is_recorded_and_never_trained(tmp_path):
    calls: list = []
    fig = stage_table1(_campaign(_work(tmp_path), calls, broken=("wgse",)))
    assert fig["failed"] == ["wgse"] and "unknown arch" in fig["networks"]["wgse"]["error"]
    assert "wgse" not in _trains(calls) and len(_trains(calls)) == 4


def test_when_every_network_fails_the_stage_fails_with_each_reason(tmp_path):
    calls: list = []
    with pytest.raises(StageFailed, match="no network trained: full: train exited with status 1") as info:
        stage_table1(_campaign(_work(tmp_path), calls, fail=tuple(COST)))
    assert set(info.value.args[1]["failed"]) == set(COST)  # the figures so far are kept in the record


def test_when_one_evaluate_of_every_network_fails_each_is_scored_alone(tmp_path):
    calls: list = []
    fig = stage_table1(_campaign(_work(tmp_path), calls, eval_fails=True))
    evaluates = [a for a, _ in calls if "evaluate" in a]
    assert len(evaluates) == 1 + 5 and "each scored alone" in fig["evaluate_note"]
    assert all("scores" in n for n in fig["networks"].values()) and fig["failed"] == []


@pytest.mark.parametrize("missing,reason", [("llr", "no LLR scene"), ("rllr", "no RLLR scene")])
def test_table1_is_skipped_without_its_data(missing, reason, tmp_path):
    work = _work(tmp_path)
    for scene in (work / missing).iterdir():
        (scene / "meta.json").unlink()
    calls: list = []
    with pytest.raises(SkipStage, match=reason):
        stage_table1(_campaign(work, calls))
    assert calls == []


def test_only_the_campaigns_own_table1_runs_are_ever_removed(tmp_path):
    work, calls = _work(tmp_path), []
    stage_table1(_campaign(work, calls))  # made, with the token state.json records
    token = json.loads((work / "state.json").read_text())["run_token"]
    assert (work / "table1" / RUN_MARKER).read_text().strip() == token
    (work / "table1" / "notes.txt").write_text("an earlier call's")
    stage_table1(_campaign(work, calls))  # its own: trained afresh
    assert not (work / "table1" / "notes.txt").exists() and (work / "table1" / "full" / "last.pt").is_file()
    (work / "table1" / RUN_MARKER).write_text("0" * 32)  # someone else's
    (work / "table1" / "notes.txt").write_text("mine")
    n = len(calls)
    with pytest.raises(StageFailed, match="is not an earlier campaign's table1 runs"):
        stage_table1(_campaign(work, calls))
    assert len(calls) == n and (work / "table1" / "notes.txt").read_text() == "mine"


def test_the_report_has_a_row_per_network(tmp_path):
    calls: list = []
    fig = stage_table1(_campaign(_work(tmp_path), calls, fail=("s2i",)))
    text = report_markdown({"mode": "gpu", "stages": [{"name": "table1", "status": "ok", "seconds": 300.0,
                                                       "figures": json.loads(json.dumps(fig)), "note": None}]})
    assert "## Table 1 networks at equal training FLOP (stage table1)" in text
    assert "| full | full | 1,000 | 10 | 40 | 4 | 1.0 | 18.00 dB | 22.00 dB |  |" in text
    row = next(ln for ln in text.splitlines() if ln.startswith("| s2i |"))
    assert "not measured" in row and "CUDA out of memory" in row
    assert "GFLOP per 400 x 250 frame" in text and "the steps of full" in text
    empty = report_markdown({"stages": [{"name": "table1", "status": "skipped", "note": "no LLR scene", "figures": {}}]})
    assert "not measured (no LLR scene)" in empty


@pytest.mark.slow
def test_the_table1_call_runs_dry_end_to_end(tmp_path):
    """TABLE1_CALL as a lent GPU runs it, on the CPU at the tiny size: install, the LLR and the
    RLLR slice, then the five networks trained at equal FLOP and scored (about 60 s here)."""
    from sensor_testing import HAS_LLVM

    if not HAS_LLVM:
        pytest.skip("the dry run renders and simulates with Dr.Jit's LLVM backend")
    part, stages = TABLE1_CALL
    out = tmp_path / "out"
    env = {**os.environ, "PYTHON": sys.executable}
    env.pop("OUT", None)
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_campaign.sh"), "--dry-run", "--part", part, "--stages",
                           *stages, "-o", str(out), "--work", str(tmp_path / "work"), "--json", "--quiet"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    by = {s["name"]: s for s in json.loads(proc.stdout)["stages"]}
    assert all(by[s]["status"] == "ok" for s in stages), {s: by[s]["note"] for s in stages}
    fig = by["table1"]["figures"]
    nets = fig["networks"]
    assert [(lb, n["config"]) for lb, n in nets.items()] == list(PROFILES["dry-run"].table1)
    assert fig["failed"] == [] and fig["reference"] == "full" and fig["frame"] == [16, 24]
    for lb, n in nets.items():
        assert n["parameters"] > 0 and n["gflop_per_frame"] > 0 and n["steps"] >= 1 and n["seconds"] > 0, lb
        # equal training FLOP, to the rounding of a whole step
        assert abs(n["train_gflop"] - fig["train_gflop_each"]) <= n["train_gflop_per_step"] / 2 + 1e-9, lb
        for light in ("low", "normal"):
            assert math.isfinite(n["scores"][light]["psnr_aligned"]), (lb, light)
    report = (out / "report.md").read_text()
    assert all(f"| {lb} | {n['config']} |" in report for lb, n in nets.items())
    assert out_problems(out) == []
