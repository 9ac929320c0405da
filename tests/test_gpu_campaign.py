"""The GPU campaign (pipelines/gpu_campaign/) rehearsed on the CPU: a lent GPU comes rarely and
for minutes, so everything it will run has to have run here first. `--dry-run` runs every stage
(the same `spikesim` commands, tiny sizes, Dr.Jit LLVM and torch on the CPU) into the same files
with the same schema; these tests check that schema, the limits on what a lent machine returns,
and that a stage that fails or hangs is recorded while the stages after it still run."""
from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

from pipelines.gpu_campaign import (DEFAULT_PART, OPTIONAL, PART_DEADLINE_S, PARTS, PROFILES, RECIPE_CALL, STAGE_NAMES, STATUSES,
                                    TABLE1_CALL, TRADEOFF_CALL, Options)
from pipelines.gpu_campaign.outputs import (MAX_FILES, combined_logs, join_weight_parts, out_problems,
                                            write_weights)
from pipelines.gpu_campaign.stages import install_wheels
from sensor_testing import HAS_LLVM

ROOT = Path(__file__).resolve().parents[1]
needs_llvm = pytest.mark.skipif(not HAS_LLVM, reason="the dry run renders and simulates with Dr.Jit's LLVM backend")
STAGE_KEYS = {"name", "status", "seconds", "figures", "log", "note", "commands", "returncode", "time_box_s",
              "started", "part"}
#: The stages the dry runs below run: all but table1, whose five trainings take about 45 s of their
#: own (tests/test_campaign_table1.py runs it, slow, and checks its logic on stand-in commands, fast),
#: and recipe, which has a call of its own (RECIPE_CALL; tests/test_campaign_recipe.py, likewise).
RUN = tuple(s for s in STAGE_NAMES if s not in ("table1", "recipe"))


def _campaign(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHON": sys.executable}
    env.pop("OUT", None)
    return subprocess.run(["bash", str(ROOT / "scripts" / "gpu_campaign.sh"), *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def dry_runs(tmp_path_factory):
    """The dry run as a lent GPU runs it: two calls sharing a work folder, part 1 then part 2
    (about 100 s in all on the 2-core VM; part 2 without table1, see RUN). Returns {part: (output
    folder, summary)} and the work folder."""
    if not HAS_LLVM:
        pytest.skip("the dry run renders and simulates with Dr.Jit's LLVM backend")
    base = tmp_path_factory.mktemp("campaign")
    work, runs = base / "work", {}
    for part in ("1", "2"):
        out = base / f"out{part}"
        stages = [s for s in PARTS[part] if s in RUN]
        proc = _campaign("--dry-run", "--part", part, "-o", str(out), "--work", str(work), "--json", "--quiet",
                         "--stages", *stages)
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs[part] = (out, json.loads(proc.stdout))
    return runs, work


@pytest.fixture(scope="module")
def dry_run(dry_runs):
    """The second call's output folder, the work folder and the summary of every stage."""
    runs, work = dry_runs
    out, summary = runs["2"]
    return out, work, summary


def _files(out: Path) -> list[Path]:
    return sorted(p for p in out.rglob("*") if p.is_file())


@needs_llvm
def test_the_dry_run_runs_every_stage_and_writes_the_summary_schema(dry_run):
    out, _, summary = dry_run
    assert json.loads((out / "summary.json").read_text()) == summary
    assert summary["schema"] == 1 and summary["mode"] == "dry-run" and summary["part"] == "2"
    assert [s["name"] for s in summary["stages"]] == list(STAGE_NAMES)
    for s in summary["stages"]:
        assert set(s) == STAGE_KEYS, s["name"]
        if s["name"] not in RUN:
            assert s["status"] == "skipped" and s["note"].startswith("not run: not selected"), s
            continue
        assert s["status"] == "ok", (s["name"], s["note"])
        assert s["seconds"] > 0 and s["log"] == "logs.txt" and s["commands"] or s["name"] == "export"
        assert isinstance(s["figures"], dict) and s["figures"], s["name"]
    assert summary["counts"] == {"ok": len(RUN), "failed": 0, "skipped": len(STAGE_NAMES) - len(RUN), "timeout": 0}
    fig = {s["name"]: s["figures"] for s in summary["stages"]}
    assert fig["install"]["versions"]["mitsuba"] and fig["install"]["drjit_llvm"] is True
    assert {r["stage"] for r in fig["bench_sensor"]["results"]} == {"sensor"}
    assert any("2 streams per launch" in r["what"] for r in fig["bench_sensor"]["results"])
    assert {r["stage"] for r in fig["bench_render"]["results"]} == {"render", "pipeline"}
    assert fig["llr"]["scenes"] == 2 and fig["rllr"]["scenes"] == 2 and fig["rllr"]["extrapolated_100_minutes"] > 0
    assert fig["train"]["steps"] >= 1 and fig["train"]["precision"] == "bf16"
    assert {"TFP", "TFI", "TFP-123", "black", "mean", "tiny"} <= set(fig["evaluate"]["methods"])
    assert [f["name"] for f in fig["export"]["files"]] == ["weights.pt"]
    # the trade study (part 1, only where time is left: the dry run has it): its CSV handed back
    assert fig["tradeoff"]["complete"] and fig["tradeoff"]["rows"] > 5 and fig["tradeoff"]["csv"] == "tradeoff.csv"
    assert set(fig["tradeoff"]["loss_db"]) >= {"fan_low:spp=1", "fan_low:spp=4"}  # TFP-41 at this size


@needs_llvm
def test_the_second_call_keeps_the_first_calls_datasets_and_records(dry_runs):
    runs, _ = dry_runs
    first = {s["name"]: s for s in runs["1"][1]["stages"]}
    second = {s["name"]: s for s in runs["2"][1]["stages"]}
    assert all(first[n]["status"] == "ok" and first[n]["part"] == "1" for n in PARTS["1"])
    assert all(first[n]["status"] == "skipped" and "not run" in first[n]["note"] for n in ("train", "evaluate", "export"))
    assert not any(p.name.startswith("weights") for p in runs["1"][0].iterdir())
    csv_text = (runs["1"][0] / "tradeoff.csv").read_text()
    assert csv_text.startswith("scene,light,run,knob,") and "fan,low,spp=1,spp," in csv_text
    assert "## Trade study at 400 x 250 (stage tradeoff)" in (runs["1"][0] / "report.md").read_text()
    for n in ("gpu_tests", "bench_sensor", "bench_render", "llr", "rllr"):  # measured once, by the first call
        assert second[n] == first[n], n
    assert all(second[n]["part"] == "2" for n in ("install", "train", "evaluate", "export"))


@needs_llvm
def test_the_dry_run_returns_what_a_lent_machine_gives_back(dry_run):
    out, _, summary = dry_run
    files = _files(out)
    assert len(files) <= MAX_FILES and all(len(f.relative_to(out).parts) <= 3 for f in files)
    assert out_problems(out) == []
    assert {f.name for f in files} == {"summary.json", "logs.txt", "report.md", "weights.pt"}
    assert {f["name"] for f in summary["files"]} == {"logs.txt", "report.md", "weights.pt"}
    logs = (out / "logs.txt").read_text()
    assert all(f"===== {name} (ok" in logs for name in RUN)
    report = (out / "report.md").read_text()
    assert "| tiny, bf16 |" in report and "**All scenes**" in report
    assert "## Table 1 networks at equal training FLOP (stage table1)" in report  # not measured: not selected


@needs_llvm
def test_the_exported_weights_load_and_match_the_trained_network(dry_run):
    from model.checkpoint import model_from_checkpoint, state_fingerprint

    out, _, summary = dry_run
    model, experiment = model_from_checkpoint(out / "weights.pt")
    train = next(s for s in summary["stages"] if s["name"] == "train")["figures"]
    assert experiment.name == "tiny" and state_fingerprint(model.state_dict()) == train["checkpoint_weights_sha256"]


@needs_llvm
def test_weights_too_large_for_one_file_come_back_as_bf16_and_fp32_parts(dry_run, tmp_path):
    from model.checkpoint import load_checkpoint, model_from_checkpoint

    _, work, _ = dry_run
    ckpt = work / "run" / "best.pt"
    full = load_checkpoint(ckpt)
    limit = 600_000  # the tiny network is 0.77 MB in fp32
    records = write_weights(ckpt, tmp_path / "out", tmp_path / "scratch", max_bytes=limit)
    names = [r["name"] for r in records]
    assert names[0] == "weights_bf16.pt" and all(n.startswith("weights_fp32.part") for n in names[1:])
    assert len(names) >= 3 and all(r["bytes"] <= limit for r in records)
    model, _ = model_from_checkpoint(tmp_path / "out" / "weights_bf16.pt")  # loads as it is
    assert model is not None
    fingerprint = join_weight_parts([tmp_path / "out" / n for n in names[1:]], tmp_path / "joined.pt")
    assert fingerprint == full["weights_sha256"]
    joined = load_checkpoint(tmp_path / "joined.pt")
    assert all((joined["model_state"][k] == v).all() for k, v in full["model_state"].items())
    with pytest.raises(ValueError, match="expected 1 to"):
        join_weight_parts([tmp_path / "out" / names[1]], tmp_path / "half.pt")


@needs_llvm
def test_a_failing_and_a_hanging_stage_are_recorded_and_later_stages_still_run(tmp_path):
    out, work = tmp_path / "out", tmp_path / "work"
    proc = _campaign("--dry-run", "--part", "1", "-o", str(out), "--work", str(work), "--json", "--quiet",
                     "--stages", "install", "gpu_tests", "bench_sensor",
                     "--inject", "install=fail", "--inject", "gpu_tests=timeout", timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    by = {s["name"]: s for s in summary["stages"]}
    assert by["install"]["status"] == "failed" and "status 3" in by["install"]["note"]
    assert by["gpu_tests"]["status"] == "timeout" and by["gpu_tests"]["seconds"] < 30
    assert by["bench_sensor"]["status"] == "ok" and by["bench_sensor"]["figures"]["results"]
    assert all(by[n]["status"] == "skipped" and "not run" in by[n]["note"]
               for n in STAGE_NAMES if n not in ("install", "gpu_tests", "bench_sensor"))
    assert set(s["status"] for s in summary["stages"]) <= set(STATUSES)
    logs = (out / "logs.txt").read_text()
    assert "injected failure" in logs and "killed at the end of its time box" in logs
    assert out_problems(out) == []


def test_the_parts_cover_every_stage_once_in_order():
    # every stage but recipe, which has a call of its own (RECIPE_CALL = part `recipe`), and `all`
    assert sorted(set(PARTS["1"]) | set(PARTS["2"]) | {"recipe"}) == sorted(STAGE_NAMES)
    assert PARTS["recipe"] == RECIPE_CALL[1] and RECIPE_CALL[0] == "recipe" and "recipe" in PARTS["all"]
    for name in ("1", "2", "all"):  # the two-call parts and `all`: in stage order
        assert list(PARTS[name]) == sorted(PARTS[name], key=STAGE_NAMES.index)
    # the one-call part: every stage but recipe once, in order of value, the ones run only where time is left last
    one = PARTS["one"]
    assert sorted(one) == sorted(set(STAGE_NAMES) - {"recipe"})
    assert one[:7] == ("install", "bench_sensor", "bench_render", "llr", "rllr", "train", "export")
    assert one[7:] == OPTIONAL["one"] == ("gpu_tests", "evaluate", "tradeoff", "table1")
    # the trade study's full-size points: only where time is left, in part one, part 1 and `all`;
    # its own call (TRADEOFF_CALL) gives it part one's time
    for name in ("one", "1", "all"):
        assert "tradeoff" in PARTS[name] and "tradeoff" in OPTIONAL[name]
    part, stages = TRADEOFF_CALL
    assert part == "one" and stages == ("install", "tradeoff")
    for profile in PROFILES.values():  # its call leaves it its least even when install takes its whole box
        boxes = profile.boxes_of(part)
        assert PART_DEADLINE_S[part] - boxes["install"][1] >= boxes["tradeoff"][0] > profile.tradeoff_report_s
    # table1 comes last wherever it runs, and only where time is left: nothing earlier keeps time for it
    for name in ("one", "2", "all"):
        assert PARTS[name][-1] == "table1" and "table1" in OPTIONAL[name]
    part, stages = TABLE1_CALL  # its own call: part one's datasets, then table1
    assert part == "one" and set(stages) <= set(PARTS[part]) and stages[-1] == "table1"


# ---- the one-call part (part `one`): its plan, its default, its skips -------------------------------
def test_the_default_part_is_the_one_call_part_with_its_deadline(tmp_path, monkeypatch):
    from pipelines.cli import build_parser
    from pipelines.gpu_campaign.cmd import options_from_args

    assert DEFAULT_PART == "one" and PART_DEADLINE_S["one"] == 540
    args = build_parser().parse_args(["gpu-campaign", "-o", str(tmp_path / "o"), "--work", str(tmp_path / "w")])
    o = options_from_args(args)
    assert o.part == "one" and o.deadline_s == 540 and o.profile.name == "gpu" and o.rllr_target == 2
    assert Options(out=tmp_path / "o", work=tmp_path / "w", profile=PROFILES["gpu"]).part == "one"
    for part in ("1", "2", "all"):  # the two-call parts keep their 9.25 minutes
        args = build_parser().parse_args(["gpu-campaign", "-o", str(tmp_path / "o"), "--part", part])
        assert options_from_args(args).deadline_s == 555
    args = build_parser().parse_args(["gpu-campaign", "-o", str(tmp_path / "o"), "--deadline-minutes", "8"])
    assert options_from_args(args).deadline_s == 480  # given, it wins over the part's


def test_the_one_call_parts_boxes_and_time_line_fit_its_deadline():
    """Part one on the GPU: the least boxes of the valued stages fit its 540 s, so does the
    planned time line (each stage within its box), and even when every stage before training uses
    its whole box, training and export keep their least."""
    p, deadline = PROFILES["gpu"], PART_DEADLINE_S["one"]
    assert deadline <= 540  # 9 minutes of the call's 10
    boxes, plan = p.boxes_of("one"), p.part_plan_s["one"]
    valued = [s for s in PARTS["one"] if s not in OPTIONAL["one"]]
    assert sum(boxes[s][0] for s in valued) <= deadline
    assert list(plan) == valued and sum(plan.values()) <= deadline
    for s in valued:
        least, most = boxes[s]
        assert least <= plan[s] <= most, s
    before_train = valued[:valued.index("train")]
    assert sum(boxes[s][1] for s in before_train) + boxes["train"][0] + boxes["export"][0] <= deadline
    assert 60 <= boxes["rllr"][0] <= boxes["rllr"][1] <= 90 and p.part_rllr_count["one"] in (1, 2)
    # training's box is what is left but export's least: the plan gives it exactly that
    assert plan["train"] <= deadline - sum(plan[s] for s in before_train) - boxes["export"][0]
    # the two-call parts keep the profile's own boxes
    assert p.boxes_of("1") == p.boxes == p.boxes_of("2")


@pytest.mark.parametrize("profile", ["gpu", "dry-run"])
def test_the_table1_calls_time_line_fits_part_ones_deadline(profile):
    """table1 runs only where time is left in a part (on part one's plan, 5 s are); its own call
    (TABLE1_CALL: part one's datasets, then table1) gives it the rest of the 540 s. Its plan fits
    the boxes and the deadline, and even when the datasets use their whole boxes table1 keeps its least."""
    p, (part, stages) = PROFILES[profile], TABLE1_CALL
    deadline, boxes, plan = PART_DEADLINE_S[part], p.boxes_of(part), p.table1_call_plan_s
    assert list(plan) == list(stages) and sum(plan.values()) + 5 <= deadline  # 5 s: the writes between stages
    for s in stages:
        least, most = boxes[s]
        assert least <= plan[s] <= most, s
    before = [s for s in stages if s != "table1"]
    on_plan_box = min(boxes["table1"][1], deadline - sum(plan[s] for s in before))
    assert plan["table1"] <= on_plan_box
    assert deadline - sum(boxes[s][1] for s in before) >= boxes["table1"][0]
    if profile == "gpu":
        # on part one's own plan, table1 finds the 5 s after the weights: below its least, so skipped
        one = p.part_plan_s["one"]
        assert deadline - sum(one.values()) < boxes["table1"][0]
        # the box shared out: a cost count, then per network its overhead and a share of steps, then the scoring
        steps_s = plan["table1"] - 15 - p.table1_eval_s - len(p.table1) * p.table1_overhead_s
        assert steps_s / len(p.table1) >= 10  # a few seconds of steps each beyond train's calibration


def test_a_stage_is_skipped_with_its_reason_when_time_left_is_below_its_least(tmp_path, monkeypatch):
    """The runner on a clock that the stages advance (no child process): part one with the GPU
    profile's boxes. On plan, every valued stage runs and the ones run only where time is left are
    skipped; when the benches overran (their grace, a slow start), the stages whose least no longer
    fits are skipped, each with its reason in summary.json and report.md, and the later ones that
    still fit run."""
    from pipelines.gpu_campaign import runner, stages

    p = PROFILES["gpu"]
    plan = p.part_plan_s["one"]

    def run(took: dict[str, float], name: str, overran: dict[str, float] | None = None, only: tuple[str, ...] = ()):
        clock = [0.0]

        def fake(stage):
            def work(c):  # a stage takes its seconds, or is cut at the end of its box, unless it overran it
                clock[0] += (overran or {}).get(stage) or min(took.get(stage, 1.0), max(c.left() - 1.0, 0.0))
                return {"took": took.get(stage, 1.0)}
            return work

        monkeypatch.setattr(stages.Campaign, "elapsed", lambda self: clock[0])
        for stage in STAGE_NAMES:
            monkeypatch.setitem(runner.STAGES, stage, fake(stage))
        o = Options(out=tmp_path / name / "out", work=tmp_path / name / "work", profile=p, stages=only)
        summary = runner.run_campaign(o)
        return {s["name"]: s for s in summary["stages"]}, o

    by, o = run(plan, "on_plan")
    assert all(by[s]["status"] == "ok" for s in plan), {s: by[s]["note"] for s in plan}
    # training got what was left but export's least
    assert by["train"]["time_box_s"] == pytest.approx(540 - sum(plan[s] for s in plan if s not in ("train", "export"))
                                                      - p.boxes_of("one")["export"][0], abs=0.5)
    for s in OPTIONAL["one"]:
        assert by[s]["status"] == "skipped" and "runs only where time is left" in by[s]["note"], by[s]
        assert by[s]["seconds"] == 0 and not by[s]["commands"]

    # the benches ran far past their boxes (the clock jumps: a child slow to die, a machine stalled):
    # the LLR's and the RLLR's least no longer fit before training's and export's
    by, o = run(plan, "late", overran={"bench_sensor": 200.0, "bench_render": 150.0})
    assert by["bench_render"]["status"] == "ok"
    for s in ("llr", "rllr"):
        assert by[s]["status"] == "skipped" and by[s]["note"].startswith("not started:"), by[s]
        assert f"needs {p.boxes_of('one')[s][0]:.0f} s" in by[s]["note"] and "540 s deadline" in by[s]["note"]
    assert by["train"]["status"] == "ok" and by["export"]["status"] == "ok"
    summary = json.loads((o.out / "summary.json").read_text())
    assert {s["name"]: s["status"] for s in summary["stages"]}["llr"] == "skipped"
    report = (o.out / "report.md").read_text()
    assert f"| llr | skipped | 0.0 | {by['llr']['note']} |" in report

    # table1's own call: the datasets at their plan, then table1 gets the rest of the 540 s
    call = p.table1_call_plan_s
    by, o = run(call, "table1_call", only=TABLE1_CALL[1])
    assert all(by[s]["status"] == "ok" for s in call), {s: by[s]["note"] for s in call}
    assert by["table1"]["time_box_s"] == pytest.approx(540 - sum(call[s] for s in call if s != "table1"), abs=0.5)
    assert by["table1"]["time_box_s"] >= call["table1"]


@pytest.mark.slow
@needs_llvm
def test_the_one_call_dry_run_runs_every_stage_in_order_of_value(tmp_path):
    """What a lent GPU now runs, rehearsed: the default part in one call (about 100 s on the 2-core
    VM; table1, which comes last, aside: see RUN). With the dry run's time to spare, gpu_tests and
    evaluate run too, after the weights. Slow: the default suite's `dry_runs` fixture already runs
    every one of these stages, in the two calls a lent GPU used before."""
    out = tmp_path / "out"
    selected = [s for s in PARTS["one"] if s in RUN]
    proc = _campaign("--dry-run", "-o", str(out), "--work", str(tmp_path / "work"), "--json", "--quiet",
                     "--stages", *selected)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout)
    assert summary["part"] == "one" and summary["deadline_s"] == 540 and summary["selected"] == selected
    by = {s["name"]: s for s in summary["stages"]}
    assert all(by[n]["status"] == "ok" and by[n]["part"] == "one" for n in RUN), \
        {n: (by[n]["status"], by[n]["note"]) for n in RUN}
    started = [by[n]["started"] for n in selected]
    assert started == sorted(started)  # ISO times to the second: run in the part's order
    assert by["rllr"]["figures"]["scenes"] == 2 and by["train"]["figures"]["precision"] == "bf16"
    assert "tiny" in by["evaluate"]["figures"]["methods"]
    assert by["tradeoff"]["figures"]["complete"] and by["tradeoff"]["figures"]["scene_lights"] == ["fan_low"]
    assert {f.name for f in _files(out)} == {"summary.json", "logs.txt", "report.md", "weights.pt", "tradeoff.csv"}
    assert out_problems(out) == []


@needs_llvm
def test_the_dry_run_skips_a_stage_that_time_no_longer_fits(tmp_path):
    """The real command, dry-run profile, part one (the default) with a 6 s deadline: install (an
    injected hang, cut at 1 s) runs, then gpu_tests and evaluate, which run only where time is left,
    find less than their least (5 s) and are skipped cleanly, their reason in summary.json and report.md."""
    out = tmp_path / "out"
    proc = _campaign("--dry-run", "-o", str(out), "--work", str(tmp_path / "work"), "--json", "--quiet",
                     "--deadline-minutes", "0.1", "--stages", "install", "gpu_tests", "evaluate",
                     "--inject", "install=timeout", timeout=60)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["part"] == "one" and summary["deadline_s"] == pytest.approx(6)
    by = {s["name"]: s for s in summary["stages"]}
    assert by["install"]["status"] == "timeout"
    report = (out / "report.md").read_text()
    for s in ("gpu_tests", "evaluate"):
        assert by[s]["status"] == "skipped" and by[s]["seconds"] == 0 and not by[s]["commands"], by[s]
        assert by[s]["note"].startswith("not started:") and "needs 5 s" in by[s]["note"], by[s]["note"]
        assert f"| {s} | skipped | 0.0 | {by[s]['note']} |" in report
    assert out_problems(out) == []


def test_the_output_check_names_every_file_that_would_not_come_back(tmp_path):
    for i in range(MAX_FILES):
        (tmp_path / f"f{i}.txt").write_text("x")
    assert out_problems(tmp_path) == []
    deep = tmp_path / "a" / "b" / "c"
    deep.mkdir(parents=True)
    (deep / "deep.txt").write_text("x")
    (tmp_path / "bad name.txt").write_text("x")
    problems = " ".join(out_problems(tmp_path))
    assert "10 files, more than 8" in problems and "3 folders deep" in problems and "'bad name.txt'" in problems


def test_logs_too_long_keep_their_head_and_tail_and_short_ones_whole():
    long = "START\n" + "x" * 50_000 + "\nEND\n"
    text = combined_logs([("short", "all of it"), ("long", long)], limit=10_000)
    assert len(text) < 12_000 and "all of it" in text and "START" in text and "END" in text
    assert "characters left out" in text


def _wheel(folder: Path) -> Path:
    """A minimal pure wheel: one module and its dist-info."""
    path = folder / "fakepkg-1.0-py3-none-any.whl"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("fakepkg.py", "VALUE = 42\n")
        z.writestr("fakepkg-1.0.dist-info/METADATA", "Metadata-Version: 2.1\nName: fakepkg\nVersion: 1.0\n")
        z.writestr("fakepkg-1.0.dist-info/WHEEL", "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\n"
                                                  "Tag: py3-none-any\n")
        z.writestr("fakepkg-1.0.dist-info/RECORD", "")
    return path


def test_the_carried_wheels_install_into_a_folder_and_damage_is_named(tmp_path):
    import hashlib

    wheels = tmp_path / "whl"
    wheels.mkdir()
    _wheel(wheels)
    with tarfile.open(wheels / "fakemitsuba.tar.xz", "w:xz") as tar:  # as scripts/gpu_wheels.sh repacks mitsuba
        data = b"VALUE = 7\n"
        info = tarfile.TarInfo("./fakemitsuba/__init__.py")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
    sums = "".join(f"{hashlib.sha256(p.read_bytes()).hexdigest()}  {p.name}\n" for p in sorted(wheels.iterdir()))
    (wheels / "SHA256SUMS").write_text(sums)
    site = tmp_path / "site"
    assert install_wheels(wheels, site) == ["fakemitsuba.tar.xz", "fakepkg-1.0-py3-none-any.whl"]
    check = subprocess.run([sys.executable, "-c", "import fakepkg, fakemitsuba; print(fakepkg.VALUE + fakemitsuba.VALUE)"],
                           env={**os.environ, "PYTHONPATH": str(site)}, capture_output=True, text=True)
    assert check.stdout.strip() == "49", check.stderr
    with (wheels / "fakemitsuba.tar.xz").open("ab") as f:
        f.write(b"!")
    with pytest.raises(ValueError, match="fakemitsuba.tar.xz: sha256 differs"):
        install_wheels(wheels, site)
    (wheels / "SHA256SUMS").unlink()
    with pytest.raises(ValueError, match="run scripts/gpu_wheels.sh"):
        install_wheels(wheels, site)


@pytest.mark.parametrize("args,message", [
    (["--dry-run", "-o", "X", "--inject", "nosuch=fail"], "expected STAGE=fail or STAGE=timeout"),
    (["--dry-run", "-o", "X", "--part", "1", "--stages", "train"], "not stages of part 1"),
    (["--dry-run"], "needs -o/--out"),
    (["--dry-run", "-o", "FULL"], "did not write (notes.txt)"),
])
def test_bad_input_is_one_line(args, message, tmp_path, monkeypatch, capsys):
    from pipelines.cli import main

    monkeypatch.delenv("OUT", raising=False)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "notes.txt").write_text("mine")
    args = [{"X": str(tmp_path / "o"), "FULL": str(tmp_path / "full")}.get(a, a) for a in args]
    assert main(["gpu-campaign", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # the error is one line (argparse's refusals follow its usage text)
    assert err[-1].startswith("spikesim gpu-campaign: error:") and message in err[-1], err
    assert len(err) == 1 or err[0].startswith("usage:")


def test_exported_weights_are_never_written_through_a_link(dry_run, tmp_path):
    """gpu-campaign writes through the project's output guard too: a link planted where the
    weights go is refused, naming it, and the file it points to is untouched."""
    _, work, _ = dry_run
    outside = tmp_path / "outside.txt"
    outside.write_text("keep")
    out = tmp_path / "out"
    out.mkdir()
    (out / "weights.pt").symlink_to(outside)
    with pytest.raises(ValueError, match="weights.pt: is a symlink"):
        write_weights(work / "run" / "best.pt", out, tmp_path / "scratch")
    assert outside.read_text() == "keep" and (out / "weights.pt").is_symlink()


def test_the_campaign_deletes_only_what_its_own_record_lists(dry_run, tmp_path, capsys):
    """A -o holding the user's own report.md or weights lost them; a --work holding the user's run/
    lost it (rm -rf). Now: only files an earlier campaign's summary.json lists, with their recorded
    sha256, are replaced; anything else is refused, untouched."""
    import shutil

    from pipelines.cli import main
    from pipelines.gpu_campaign import earlier_outputs

    out, _, summary = dry_run
    earlier = tmp_path / "earlier"
    shutil.copytree(out, earlier)
    assert sorted(p.name for p in earlier_outputs(earlier)) == sorted(p.name for p in earlier.iterdir())
    (earlier / "report.md").write_text("the user's own notes")  # no longer the file the record lists
    assert "report.md" not in {p.name for p in earlier_outputs(earlier)}
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "report.md").write_text("mine")
    (mine / "weights.pt").write_bytes(b"mine")
    assert main(["gpu-campaign", "--dry-run", "-o", str(mine), "--work", str(tmp_path / "w")]) == 2
    assert "did not write (report.md, weights.pt)" in capsys.readouterr().err
    assert (mine / "report.md").read_text() == "mine" and (mine / "weights.pt").read_bytes() == b"mine"


def test_a_users_run_folder_in_work_is_never_removed(tmp_path):
    work = tmp_path / "w"
    (work / "run").mkdir(parents=True)
    (work / "run" / "precious.txt").write_text("keep")
    proc = _campaign("--dry-run", "--part", "2", "--stages", "train", "-o", str(tmp_path / "o"), "--work", str(work),
                     "--json", "--quiet")
    assert proc.returncode == 0, proc.stderr[-2000:]
    stage = next(s for s in json.loads(proc.stdout)["stages"] if s["name"] == "train")
    assert stage["status"] == "failed" and "not an earlier campaign's training run" in stage["note"]
    assert (work / "run" / "precious.txt").read_text() == "keep"


def test_relative_paths_are_resolved_before_the_stages_run(tmp_path, monkeypatch):
    import argparse

    from pipelines.gpu_campaign.cmd import options_from_args

    monkeypatch.chdir(tmp_path)
    args = argparse.Namespace(out=Path("o"), work=Path("scratch"), dry_run=True, part="all", stages=None,
                              deadline_minutes=9.0, wheels=Path("wh"), seed=0, rllr_count=None, inject=None, fresh=False)
    o = options_from_args(args)
    assert o.out == tmp_path / "o" and o.work == tmp_path / "scratch" and o.wheels == tmp_path / "wh"


def test_the_trained_run_carries_the_token_its_state_records(dry_run):
    """The run the campaign trains is marked as its own (the token state.json records), so a later
    call may replace it; a run without that mark is never removed (tests/test_gpu_campaign_work_folder.py)."""
    from pipelines.gpu_campaign.stages import RUN_MARKER

    _, work, _ = dry_run
    token = json.loads((work / "state.json").read_text())["run_token"]
    assert token and (work / "run" / RUN_MARKER).read_text().strip() == token
    assert (work / "run" / "best.pt").is_file() or (work / "run" / "last.pt").is_file()
