"""Stage recipe of the GPU campaign (pipelines/gpu_campaign/stages.py `stage_recipe`, its own call
RECIPE_CALL = part `recipe`): the shipped network's recipe at GPU scale, i.e. the sixth stage's
datasets made on the GPU with their own commands and seeds, then `lrrep_span` fine-tuned from the
shipped `lrrep`, its weights handed back as recipe_weights.pt. The fast tests run the stage with
its commands replaced by stand-ins (no child process): the sets in order, each in a box that leaves
training its least, a failing multi-process set made again in one process, only finished sets
trained on, the skips and failures, the work folder's guard, and the plan against part `recipe`'s
deadline. The slow one runs the real call dry on the CPU at the tiny size (about 45 s on the
2-core VM: three small sets and four training steps)."""
from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipelines.gpu_campaign import PART_DEADLINE_S, PARTS, PROFILES, RECIPE_CALL, Options, StageRecord
from pipelines.gpu_campaign.outputs import out_problems, report_markdown
from pipelines.gpu_campaign.stages import RUN_MARKER, Campaign, CommandResult, StageFailed, stage_recipe

ROOT = Path(__file__).resolve().parents[1]


def _campaign(work: Path, calls: list, box_s: float = 490.0, *, fail=(), fail_once=(), slow=(),
              set_seconds: float = 5.0) -> Campaign:
    """A campaign in its recipe stage (gpu profile) whose commands are stand-ins: `generate` makes
    one complete scene per call and takes `set_seconds` of the (fake) clock, fails for the sets in
    `fail`, fails with several workers for those in `fail_once`, is cut by its box for those in
    `slow`; `train` writes best.pt and val_log.csv and reports its steps."""
    from pipelines.gpu_campaign.runner import _load_run_token

    o = Options(out=work.parent / "o", work=work, profile=PROFILES["gpu"], part="recipe", stages=("recipe",))
    c = Campaign(o)
    c.run_token = _load_run_token(o)
    c.current, c.box_end = StageRecord("recipe"), time.monotonic() + box_s
    (work / "logs").mkdir(parents=True, exist_ok=True)

    def command(argv, box_s=None):
        argv = [str(a) for a in argv]
        calls.append((argv, box_s))
        sub = argv[argv.index("pipelines.cli") + 1]
        out = Path(argv[argv.index("-o") + 1])
        if sub == "generate":
            name = out.name
            c.box_end -= set_seconds  # the clock runs as the set is made
            workers = argv[argv.index("--workers") + 1]
            if name in fail or (name in fail_once and workers != "1"):
                return CommandResult(1, False, set_seconds, "")
            (out / "rllr_0000").mkdir(parents=True, exist_ok=True)
            (out / "rllr_0000" / "meta.json").write_text("{}")
            if name in slow:
                return CommandResult(None, True, box_s or 0.0, "")
            return CommandResult(0, False, set_seconds, json.dumps({"generated": [{"name": "rllr_0000", "seconds": 1.0,
                                                                                   "bytes": 10}], "skipped": 0}))
        assert sub == "train"
        (out / "best.pt").write_text("weights")
        (out / "val_log.csv").write_text("time,epoch,step,psnr_aligned\n1,1,100,21.5\n2,2,200,21.75\n")
        return CommandResult(0, False, 100.0, json.dumps({"steps": 200, "train_seconds": 100.0, "samples_per_s": 32.0,
                                                          "best_val_psnr_aligned": 21.75, "precision": "fp32"}))

    c.command = command  # type: ignore[method-assign]
    return c


@pytest.fixture()
def stand_in(monkeypatch):
    """stage_recipe with the fingerprint of the stand-in checkpoint faked (it is not a torch file)."""
    import model.checkpoint as ckpt
    monkeypatch.setattr(ckpt, "load_checkpoint", lambda path, *a, **k: {"weights_sha256": "stand-in"})
    return stage_recipe


def _train_argv(calls):
    return next(argv for argv, _ in calls if argv[argv.index("pipelines.cli") + 1] == "train")


def _value_list(argv, flag):
    i = argv.index(flag) + 1
    out = []
    while i < len(argv) and not argv[i].startswith("--"):
        out.append(Path(argv[i]).name)
        i += 1
    return out


def test_the_recipe_makes_every_set_in_order_then_trains_on_them(tmp_path, stand_in):
    calls: list = []
    c = _campaign(tmp_path / "W", calls)
    fig = stand_in(c)
    p = PROFILES["gpu"]
    made = [Path(argv[argv.index("-o") + 1]).name for argv, _ in calls if "generate" in argv]
    assert made == [n for n, _, _ in p.recipe_sets]
    for argv, box in calls[:-1]:  # each set in a box that leaves training its least
        assert box <= 490.0 - p.recipe_train_least_s + 1e-6
        assert argv[argv.index("--device") + 1] == "cuda"
    train = _train_argv(calls)
    assert _value_list(train, "--data") == [n for n, r, _ in p.recipe_sets if r == "train"]
    assert _value_list(train, "--val-data") == [n for n, r, _ in p.recipe_sets if r == "val"]
    assert train[train.index("--seed") + 1] == str(p.recipe_seed) and "--init" in train
    assert all(a in train for a in p.recipe_train)
    assert fig["validations"] == [(100, 21.5), (200, 21.75)]
    assert fig["best_val_psnr_aligned"] == 21.75 and fig["steps"] == 200
    assert fig["train_sets"] == _value_list(train, "--data") and fig["data_scenes"] == 6
    assert (c.o.work / "recipe_run" / RUN_MARKER).is_file()  # the run is the campaign's: export takes it
    report = report_markdown({"stages": [{"name": "recipe", "status": "ok", "figures": fig}]})
    assert "| rllr_nat8tr | train | 1 |" in report and "100: 21.50, 200: 21.75" in report


def test_the_recipe_sets_are_the_sixth_stage_commands_with_their_seeds():
    # the commands of docs/model.md ("The sixth stage" and the fourth's data): same content, scales,
    # darkening, peak and seed per set; the GPU adds only --workers (the data does not depend on it)
    sets = {n: (r, a) for n, r, a in PROFILES["gpu"].recipe_sets}
    seeds = {n: a[a.index("--seed") + 1] for n, (_, a) in sets.items()}
    assert seeds == {"val_photo8": "401", "rllr_photo48": "400", "rllr_photo_bright48": "403",
                     "rllr_photo_still48": "404", "rllr_photo_bright_still48": "405",
                     "rllr_photo_vbright_still48": "406", "val_nat8": "301", "rllr_nat8tr": "300"}
    for n, (role, a) in sets.items():
        text = " ".join(a)
        assert "--preset paper --steps 369 --gt-stride 41" in text, n
        assert role == ("val" if n.startswith("val_") else "train")
        assert ("--still-share 1" in text) == ("still" in n), n
        assert ("--peak-y 2" in text) == (n in ("rllr_photo_bright48", "rllr_photo_bright_still48")), n
        assert ("--peak-y 3" in text) == (n == "rllr_photo_vbright_still48"), n
        assert ("--scales 0.5 " in text + " ") == n.startswith("val_"), n
    model_md = (ROOT / "docs" / "model.md").read_text()
    for seed in seeds.values():
        assert f"--seed {seed} -o data/" in model_md


def test_a_set_that_fails_with_several_processes_is_made_again_in_one(tmp_path, stand_in):
    calls: list = []
    c = _campaign(tmp_path / "W", calls, fail_once=("rllr_photo48",))
    fig = stand_in(c)
    tried = [argv for argv, _ in calls if "generate" in argv and argv[argv.index("-o") + 1].endswith("rllr_photo48")]
    assert [a[a.index("--workers") + 1] for a in tried] == ["8", "1"]
    rec = fig["sets"]["rllr_photo48"]
    assert rec["status"] == "ok" and "made again with --workers 1" in rec["retried"]
    assert "rllr_photo48" in fig["train_sets"]


def test_only_finished_sets_are_trained_on_and_the_rest_are_named(tmp_path, stand_in):
    calls: list = []
    c = _campaign(tmp_path / "W", calls, fail=("rllr_photo_bright48", "val_nat8"), slow=("rllr_photo_still48",))
    fig = stand_in(c)
    assert fig["sets"]["rllr_photo_bright48"]["status"] == "failed"
    assert fig["sets"]["rllr_photo_still48"]["status"] == "timeout"
    assert fig["sets"]["rllr_photo_still48"]["scenes"] == 1  # its complete scenes stay (generation resumes)
    train = _train_argv(calls)
    assert "rllr_photo_bright48" not in _value_list(train, "--data")
    assert "rllr_photo_still48" not in _value_list(train, "--data")
    assert _value_list(train, "--val-data") == ["val_photo8"]


def test_sets_that_would_leave_training_less_than_its_least_are_skipped(tmp_path, stand_in):
    calls: list = []
    p = PROFILES["gpu"]
    # each set takes 60 s of a box of training's least + 130 s: two sets, then the rest skipped
    c = _campaign(tmp_path / "W", calls, box_s=p.recipe_train_least_s + 130.0, set_seconds=60.0)
    fig = stand_in(c)
    status = {n: r["status"] for n, r in fig["sets"].items()}
    assert [status[n] for n, _, _ in p.recipe_sets[:3]] == ["ok", "ok", "skipped"]
    assert all(status[n] == "skipped" for n, _, _ in p.recipe_sets[2:])
    assert "before training's" in fig["sets"]["rllr_nat8tr"]["note"]
    assert _value_list(_train_argv(calls), "--data") == ["rllr_photo48"]


def test_no_finished_training_set_fails_the_stage_without_training(tmp_path, stand_in):
    calls: list = []
    train_sets = tuple(n for n, r, _ in PROFILES["gpu"].recipe_sets if r == "train")
    c = _campaign(tmp_path / "W", calls, fail=train_sets)
    with pytest.raises(StageFailed, match="no training set was made in full") as err:
        stand_in(c)
    assert not any("train" in argv for argv, _ in calls)
    assert err.value.args[1]["sets"]["rllr_nat8tr"]["status"] == "failed"


def test_a_users_run_folder_stops_the_stage_before_any_data_is_made(tmp_path, stand_in):
    calls: list = []
    work = tmp_path / "W"
    (work / "recipe_run").mkdir(parents=True)
    (work / "recipe_run" / "notes.txt").write_text("mine")
    c = _campaign(work, calls)
    with pytest.raises(StageFailed, match="is not an earlier campaign's training run"):
        stand_in(c)
    assert calls == [] and (work / "recipe_run" / "notes.txt").read_text() == "mine"


def test_the_recipe_call_fits_part_recipe_deadline():
    part, stages = RECIPE_CALL
    assert PARTS[part] == stages and PART_DEADLINE_S[part] == 540
    for profile in PROFILES.values():
        boxes = profile.boxes_of(part)
        # even when install takes its whole box, the recipe keeps its least and export its own
        assert PART_DEADLINE_S[part] - boxes["install"][1] - boxes["export"][0] >= boxes["recipe"][0]
        # and the recipe's least holds training's least plus at least one set's
        assert boxes["recipe"][0] >= profile.recipe_train_least_s + profile.recipe_set_least_s
        assert profile.recipe_train_least_s > profile.recipe_overhead_s
    p = PROFILES["gpu"]
    plan = p.part_plan_s["recipe"]
    assert sum(plan.values()) + 5 <= PART_DEADLINE_S[part]
    assert all(p.boxes_of(part)[s][0] <= t <= p.boxes_of(part)[s][1] for s, t in plan.items())


@pytest.mark.slow
def test_the_recipe_call_runs_dry_and_hands_back_loadable_weights(tmp_path):
    """RECIPE_CALL on the CPU at the tiny size: every stage ok, the recipe's weights come back and
    load as the shipped network's architecture, within what a lent machine returns."""
    from spikesim._drjit import has_llvm
    if not has_llvm():
        pytest.skip("the dry run renders and simulates with Dr.Jit's LLVM backend")
    out, work = tmp_path / "out", tmp_path / "work"
    env = {**os.environ, "PYTHON": sys.executable}
    env.pop("OUT", None)
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_campaign.sh"), "--dry-run", "--part", "recipe", "-o",
                           str(out), "--work", str(work), "--json", "--quiet"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout)
    by = {s["name"]: s for s in summary["stages"]}
    assert all(by[n]["status"] == "ok" for n in RECIPE_CALL[1]), {n: by[n]["note"] for n in RECIPE_CALL[1]}
    fig = by["recipe"]["figures"]
    assert fig["train_sets"] == ["rllr_photo2", "rllr_nat1"] and fig["val_sets"] == ["val_photo1"]
    assert fig["steps"] >= 1 and fig["validations"]
    assert out_problems(out) == []
    from model.checkpoint import load_checkpoint, model_from_checkpoint
    weights = out / "recipe_weights.pt"
    net, experiment = model_from_checkpoint(weights)
    assert experiment.model.output == "refine" and experiment.model.refine_span == 5
    assert load_checkpoint(weights)["weights_sha256"] == fig["checkpoint_weights_sha256"]
    assert {f["name"] for f in by["export"]["figures"]["files"]} == {"recipe_weights.pt"}
    assert shlex.split(by["recipe"]["commands"][-1])[3] == "train"


def test_the_recipe_crop_fits_the_smallest_scene_it_trains_on():
    # the first lent run (2026-11-28) trained at crop 64 and `train` refused it: the sets at pixel
    # scale 1/4 of 400 x 250 are 62 x 100 (spikesim train: "crop 64 is larger than scene ...")
    for profile in PROFILES.values():
        t = profile.recipe_train
        crop = int(t[t.index("--crop") + 1])
        for name, _, args in profile.recipe_sets:
            height = int(args[args.index("--height") + 1]) if "--height" in args else 250  # the paper preset
            i = args.index("--scales") + 1
            scales = []
            while i < len(args) and not args[i].startswith("--"):
                scales.append(float(args[i]))
                i += 1
            assert crop <= int(height * min(scales)), (profile.name, name, crop)
