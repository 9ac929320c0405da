"""Every GPU measurement and a training run, as one campaign that runs the first time on a lent GPU.

A lent machine (docs/gpu_campaign.md) comes rarely, for at most 30 minutes of device time in calls
of at most 10 minutes, without network and without Dr.Jit, Mitsuba, OpenEXR, colour-science and
trimesh. So the campaign is written and rehearsed beforehand (`--dry-run`: every stage on the CPU at
a tiny size, in the default test suite), and on the day it:

1. installs the missing packages from the wheels carried with the working tree (scripts/gpu_wheels.sh);
2. runs each stage as a child process under its own time box, cut to what is left of the call's
   deadline after the time the later stages need, so that one stage that hangs or fails costs only
   itself: the later ones still run, and each stage's record (status, seconds, figures, log) is
   written to the output folder as soon as it ends, so a call killed at its limit still returns
   everything before it;
3. hands back at most 8 files (pipelines/gpu_campaign_outputs.py): summary.json, logs.txt,
   report.md and the trained weights.

Stages, in order: install, gpu_tests, bench_sensor, bench_render, llr, rllr, train, evaluate,
export. Two device calls split them (`--part 1`: up to the datasets; `--part 2`: training,
evaluation, weights); the second finds the first's datasets and records in the work folder when
the machine is still the same, and regenerates what is missing when it is not. Each stage is a
`spikesim` command, so what is measured is what users run.
"""
from __future__ import annotations

import dataclasses
import datetime
import functools
import hashlib
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from spikesim import outputs
from pipelines.gpu_campaign_outputs import check_out, combined_logs, file_record, report_markdown
from pipelines.gpu_campaign_stages import ROOT, STAGES, Campaign, SkipStage, StageFailed, check_command, complete_scenes

SCHEMA_VERSION = 1
STATUSES = ("ok", "failed", "skipped", "timeout")
STAGE_NAMES = ("install", "gpu_tests", "bench_sensor", "bench_render", "llr", "rllr", "train", "evaluate", "export")
PARTS = {
    "1": ("install", "gpu_tests", "bench_sensor", "bench_render", "llr", "rllr"),
    "2": ("install", "llr", "rllr", "train", "evaluate", "export"),
    "all": STAGE_NAMES,
}
#: Stages whose data a later call reuses instead of measuring again (resumable datasets).
DATA_STAGES = ("llr", "rllr")
INJECTIONS = ("fail", "timeout")
#: The files a campaign writes in its output folder, besides the weights (weights*.pt).
OUT_FILES = ("summary.json", "logs.txt", "report.md")


# ---- what a campaign runs at which size ---------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Profile:
    """The sizes, devices and time boxes of one kind of campaign: `gpu` (the paper's sizes on
    CUDA) or `dry-run` (the same commands on the CPU at a tiny size, to rehearse them)."""

    name: str
    drjit_device: str
    """Where `generate` and `bench` render and simulate: cuda or llvm."""
    torch_device: str
    """Where `train` and `evaluate` run: cuda or cpu."""
    needs_gpu: bool
    """Whether the install stage fails when torch or Dr.Jit sees no CUDA device."""
    bench_sensor: tuple[str, ...]
    bench_render: tuple[str, ...]
    llr: tuple[str, ...]
    rllr: tuple[str, ...]
    rllr_count: int
    """RLLR scenes to make (the paper has 100; the time for 100 is extrapolated)."""
    train: tuple[str, ...]
    evaluate: tuple[str, ...]
    train_config: str
    train_overhead_s: float
    """Seconds of a training stage's box that are not training steps: start-up, validation, saving."""
    train_max_minutes: float | None
    llr_windows: int
    """Windows per LLR sequence: `tfp:N` takes N = windows x 41 steps (a network sees as much)."""
    boxes: dict[str, tuple[float, float]]
    """Per stage (least seconds worth starting it with, most seconds it may take)."""
    catch_up_s: dict[str, float]
    """Most seconds a later call spends remaking a dataset the machine lost between calls."""
    grace_s: float
    """Seconds between SIGTERM and SIGKILL when a stage's box ends (train writes last.pt)."""

    def __post_init__(self) -> None:
        if self.drjit_device not in ("cuda", "llvm") or self.torch_device not in ("cuda", "cpu"):
            raise ValueError(f"profile {self.name}: devices {self.drjit_device}/{self.torch_device}")
        if set(self.boxes) != set(STAGE_NAMES):
            raise ValueError(f"profile {self.name}: time boxes for {sorted(self.boxes)}, expected {STAGE_NAMES}")
        for stage, (least, most) in self.boxes.items():
            if not 0 < least <= most:
                raise ValueError(f"profile {self.name}: stage {stage}: box ({least}, {most}) must have 0 < least <= most")
        if self.rllr_count < 1 or self.llr_windows < 1 or self.grace_s < 0 or self.train_overhead_s < 0:
            raise ValueError(f"profile {self.name}: counts must be positive, times non-negative")


_TINY = ("--height", "16", "--width", "24", "--workers", "1", "--quality", "balanced")
PROFILES: dict[str, Profile] = {
    "gpu": Profile(
        "gpu", "cuda", "cuda", True,
        bench_sensor=("--stages", "sensor", "--backends", "cuda", "--streams", "8", "--steps", "2048",
                      "--numpy-steps", "128"),
        bench_render=("--stages", "render", "pipeline", "--backends", "cuda", "--repeats", "2"),
        llr=("--preset", "paper", "--quality", "balanced"),
        rllr=("--preset", "paper", "--quality", "balanced"),
        rllr_count=10,
        # 8 loader processes of the 16 cores: a sample is 21 windows of spikes and 21 ground-truth
        # EXR files, read and cropped on the CPU
        train=("--config", "full", "--num-workers", "8"),
        evaluate=(),
        train_config="full", train_overhead_s=75.0, train_max_minutes=None, llr_windows=21,
        # the measurements first, each capped so that at worst they leave the LLR two minutes; the
        # RLLR slice and training take what is left of their call
        boxes={"install": (30, 90), "gpu_tests": (30, 120), "bench_sensor": (30, 90), "bench_render": (30, 90),
               "llr": (60, 240), "rllr": (60, 600), "train": (150, 3600), "evaluate": (90, 180),
               "export": (15, 60)},
        # a bare machine in part 2 (the first call's datasets lost): the LLR (under 2 min is the
        # goal) and 1-3 RLLR scenes, which leaves training about 3 minutes
        catch_up_s={"llr": 150, "rllr": 90}, grace_s=20.0),
    "dry-run": Profile(
        "dry-run", "llvm", "cpu", False,
        bench_sensor=("--stages", "sensor", "--backends", "llvm", "--streams", "2", "--height", "16", "--width", "24",
                      "--steps", "64", "--numpy-steps", "8", "--repeats", "1"),
        bench_render=("--stages", "render", "pipeline", "--backends", "llvm", "--height", "16", "--width", "24",
                      "--spp", "1", "--repeats", "1", "--pipeline-steps", "17"),
        llr=("--preset", "small", "--scenes", "fan", "--windows", "3", *_TINY),
        rllr=("--preset", "small", *_TINY),
        rllr_count=2,
        # one torch thread: on a shared CPU, OpenMP's barriers between two threads that wait for
        # cores made steps of 0.2 s take 4-17 s (measured on the development VM)
        train=("--config", "tiny", "--crop", "16", "--max-steps", "20", "--threads", "1"),
        evaluate=("--threads", "1"),
        train_config="tiny", train_overhead_s=10.0, train_max_minutes=0.1, llr_windows=3,
        boxes={"install": (5, 60), "gpu_tests": (5, 120), "bench_sensor": (5, 120), "bench_render": (5, 120),
               "llr": (5, 180), "rllr": (5, 180), "train": (10, 180), "evaluate": (5, 120), "export": (2, 60)},
        catch_up_s={"llr": 180, "rllr": 180}, grace_s=5.0),
}


@dataclasses.dataclass(frozen=True)
class Options:
    """One invocation of the campaign."""

    out: Path
    work: Path
    profile: Profile
    part: str = "all"
    stages: tuple[str, ...] = ()
    """Only these of the part's stages (empty: all of them)."""
    deadline_s: float = 555.0
    """Seconds this invocation may take in all (a device call is killed at 600)."""
    wheels: Path = ROOT / ".whl"
    seed: int = 0
    rllr_count: int | None = None
    inject: dict[str, str] = dataclasses.field(default_factory=dict)
    """Stage -> "fail" or "timeout": that stage's work is replaced by a failure (to test the campaign)."""
    fresh: bool = False
    """Forget the records of earlier calls (by default a call keeps them: part 2 adds to part 1)."""

    def __post_init__(self) -> None:
        if self.part not in PARTS:
            raise ValueError(f"--part {self.part!r}: expected one of {', '.join(PARTS)}")
        unknown = [s for s in self.stages if s not in PARTS[self.part]]
        if unknown:
            raise ValueError(f"--stages {' '.join(unknown)}: not stages of part {self.part} "
                             f"({', '.join(PARTS[self.part])})")
        for stage, what in self.inject.items():
            if stage not in STAGE_NAMES or what not in INJECTIONS:
                raise ValueError(f"--inject {stage}={what}: expected STAGE=fail or STAGE=timeout, STAGE one of "
                                 f"{', '.join(STAGE_NAMES)}")
        if not (math.isfinite(self.deadline_s) and self.deadline_s > 0):
            raise ValueError(f"the deadline must be a positive number of seconds, got {self.deadline_s}")
        if self.rllr_count is not None and self.rllr_count < 1:
            raise ValueError(f"--rllr-count must be >= 1, got {self.rllr_count}")
        out, work = self.out.resolve(), self.work.resolve()
        if out == work or work in out.parents or out in work.parents:
            raise ValueError(f"--out {self.out} and --work {self.work} must be separate folders (the output holds "
                             "only what comes back)")

    @property
    def selected(self) -> tuple[str, ...]:
        return tuple(s for s in PARTS[self.part] if not self.stages or s in self.stages)


# ---- one stage's record --------------------------------------------------------------------------
@dataclasses.dataclass
class StageRecord:
    """What summary.json says of a stage."""

    name: str
    status: str = "skipped"
    seconds: float = 0.0
    figures: dict[str, Any] = dataclasses.field(default_factory=dict)
    log: str | None = None
    note: str | None = None
    commands: list[str] = dataclasses.field(default_factory=list)
    returncode: int | None = None
    time_box_s: float | None = None
    started: str | None = None
    part: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "StageRecord":
        return cls(**{f.name: data[f.name] for f in dataclasses.fields(cls) if f.name in data})


# ---- the campaign --------------------------------------------------------------------------------
def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _injected(c: Campaign, what: str) -> dict[str, Any]:
    """A stand-in for a stage's work that fails, or that outlives a one-second box."""
    code = ("import sys; print('injected failure (--inject)'); sys.exit(3)" if what == "fail"
            else "import time; time.sleep(600)")
    check_command(c.command([c.python, "-c", code], box_s=1.0 if what == "timeout" else None), f"injected {what}")
    return {}


def _run_stage(c: Campaign, name: str, later: Sequence[str], catch_up: bool) -> StageRecord:
    """Run one stage in its box and return its record, whatever happens inside."""
    least, most = c.p.boxes[name]
    if catch_up:
        most = min(most, c.p.catch_up_s.get(name, most))
    reserve = sum(c.p.boxes[s][0] for s in later)
    box = min(most, c.o.deadline_s - c.elapsed() - reserve)
    rec = StageRecord(name, log="logs.txt", started=_now(), part=c.o.part, time_box_s=round(box, 1))
    c.records[name] = rec
    outputs.atomic_write_text(c.log_path(name), f"stage {name}, started {rec.started}, time box {box:.0f} s\n")
    if box < least:
        rec.note = (f"not started: {max(box, 0):.0f} s left of the deadline after the {reserve:.0f} s the later "
                    f"stages need, and it needs {least:.0f} s")
        return rec
    c.current, c.box_end = rec, time.monotonic() + box
    t = time.monotonic()
    try:
        rec.figures = _injected(c, c.o.inject[name]) if name in c.o.inject else STAGES[name](c)
        rec.status = "ok"
    except SkipStage as exc:
        rec.status, rec.note = "skipped", str(exc)
    except (TimeoutError, StageFailed) as exc:
        rec.status = "timeout" if isinstance(exc, TimeoutError) else "failed"
        rec.note = str(exc.args[0]) if exc.args else rec.status
        if len(exc.args) > 1 and isinstance(exc.args[1], dict):
            rec.figures = exc.args[1]
    except Exception as exc:  # a bug in a stage must not stop the stages after it
        import traceback
        rec.status, rec.note = "failed", f"{type(exc).__name__}: {' '.join(str(exc).split())}"
        c.note_log(traceback.format_exc())
    finally:
        rec.seconds = round(time.monotonic() - t, 3)
        c.current, c.box_end = None, math.inf
    c.note_log(f"[stage {name}: {rec.status}, {rec.seconds:.1f} s{': ' + rec.note if rec.note else ''}]", name)
    return rec


def earlier_outputs(out: Path) -> list[Path]:
    """The files in `out` an earlier campaign wrote, by its own record: a `summary.json` of this
    campaign's schema, and each file it lists with the size and sha256 it recorded. Anything else
    (the user's own report.md, weights or .part file) is not this campaign's to delete."""
    from spikesim.config_io import read_json_object

    summary = out / "summary.json"
    if not summary.is_file() or summary.is_symlink():
        return []
    try:
        doc = read_json_object(summary, "campaign summary")
    except ValueError:
        return []
    if doc.get("campaign") != "spikesim gpu-campaign" or not isinstance(doc.get("files"), list):
        return []
    ours = [summary]
    for f in doc["files"]:
        p = out / str(f.get("name", "")) if isinstance(f, dict) else None
        if p is None or p.parent != out or not p.is_file() or p.is_symlink():
            continue
        if p.stat().st_size == f.get("bytes") and file_record(p)["sha256"] == f.get("sha256"):
            ours.append(p)
    return ours


def _load_state(o: Options) -> dict[str, StageRecord]:
    path = o.work / "state.json"
    if o.fresh or not path.is_file():
        return {}
    from spikesim.config_io import read_json_object
    try:
        doc = read_json_object(path, "campaign state")  # a small regular file, bounded nesting
        if doc.get("schema") != SCHEMA_VERSION or doc.get("mode") != o.profile.name or doc.get("seed") != o.seed:
            return {}  # another kind of campaign ran here: its records do not describe this one
        stages = doc.get("stages", {})
        if not isinstance(stages, dict):
            raise TypeError("stages is not an object")
        return {n: StageRecord.from_dict(r) for n, r in stages.items() if n in STAGE_NAMES}
    except (ValueError, TypeError, AttributeError, KeyError) as exc:  # damaged: start the campaign afresh
        print(f"[gpu-campaign] {path} is damaged ({str(exc).splitlines()[0][:160]}); its stages run again",
              file=sys.stderr)
        return {}


def _machine() -> dict[str, Any]:
    from spikesim.machine import cpu_model
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()}


@functools.lru_cache(maxsize=1)
def _code_identity() -> dict[str, Any]:
    """Which code ran: the git commit where there is a repository, and a digest of the packages'
    Python files (a device copy of the tree has no .git)."""
    h = hashlib.sha256()
    for folder in ("spikesim", "model", "pipelines", "scenes"):
        for p in sorted((ROOT / folder).rglob("*.py")):
            h.update(str(p.relative_to(ROOT)).encode())
            h.update(p.read_bytes())
    commit = None
    try:
        r = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=10)
        commit = r.stdout.strip() or None if r.returncode == 0 else None
    except (OSError, subprocess.TimeoutExpired):
        pass
    return {"git_commit": commit, "python_files_sha256": h.hexdigest()}


def summary_of(c: Campaign, state: dict[str, StageRecord], started: str, finished: str | None) -> dict[str, Any]:
    """summary.json: every stage of the campaign in order, from this call, an earlier call kept in
    the work folder, or 'skipped' with a note that it has not run."""
    stages = []
    for name in STAGE_NAMES:
        rec = c.records.get(name) or state.get(name)
        if rec is None:
            rec = StageRecord(name, note="not run: not selected in this call (--part/--stages) nor in an earlier one "
                                         "kept in the work folder")
        stages.append(rec.to_dict())
    install = next(s for s in stages if s["name"] == "install")["figures"]
    versions = install.get("versions", {})
    machine = {**_machine(), "gpu": install.get("gpu"), "torch": versions.get("torch"),
               "drjit": versions.get("drjit"), "mitsuba": versions.get("mitsuba"),
               "drjit_cuda": install.get("drjit_cuda"), "drjit_llvm": install.get("drjit_llvm")}
    counts = {s: sum(1 for r in stages if r["status"] == s) for s in STATUSES}
    return {"schema": SCHEMA_VERSION, "campaign": "spikesim gpu-campaign", "mode": c.p.name, "part": c.o.part,
            "selected": list(c.o.selected), "seed": c.o.seed, "started": started, "finished": finished,
            "seconds": round(c.elapsed(), 3), "deadline_s": c.o.deadline_s, "machine": machine,
            "code": dict(_code_identity()), "counts": counts, "stages": stages, "files": []}


def write_outputs(c: Campaign, summary: dict[str, Any]) -> dict[str, Any]:
    """summary.json, logs.txt and report.md in the output folder (beside the weights of stage
    export), then the check that all of it comes back."""
    out = c.o.out
    out.mkdir(parents=True, exist_ok=True)
    sections = []
    for s in summary["stages"]:
        path = c.log_path(s["name"])
        if path.is_file():
            sections.append((f"{s['name']} ({s['status']}, {s['seconds']:.1f} s)", path.read_text(errors="replace")))
    outputs.atomic_write_text(out / "logs.txt", combined_logs(sections))
    outputs.atomic_write_text(out / "report.md", report_markdown(summary))
    summary["files"] = [file_record(p) for p in sorted(out.iterdir()) if p.is_file() and p.name != "summary.json"]
    outputs.atomic_write_text(out / "summary.json", json.dumps(summary, indent=2, default=str) + "\n")
    outputs.atomic_write_text(c.o.work / "state.json", json.dumps(
        {"schema": SCHEMA_VERSION, "mode": c.p.name, "seed": c.o.seed,
         "stages": {s["name"]: s for s in summary["stages"] if s["name"] in c.records or s.get("started")}},
        indent=2, default=str))
    check_out(out)
    return summary


def run_campaign(options: Options, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run the selected stages in order, each in its box; after each one, the outputs are
    rewritten whole, so what a killed call leaves in the output folder is complete up to there."""
    say = progress or (lambda text: None)
    out = options.out
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    if out.is_dir():
        ours = earlier_outputs(out)
        others = sorted(p.name for p in out.iterdir() if p not in ours)
        if others:
            raise ValueError(f"--out {out} holds files this campaign did not write ({', '.join(others[:5])}"
                             f"{', ...' if len(others) > 5 else ''}): give an empty folder, or one an earlier "
                             "campaign filled (a lent machine returns at most 8 files)")
        for p in ours:  # an earlier call's results, weights above all, would mislead
            outputs.remove(out, p.name)
    options.work.mkdir(parents=True, exist_ok=True)
    c = Campaign(options)
    c.logs.mkdir(parents=True, exist_ok=True)
    state = _load_state(options)
    started = _now()
    selected = options.selected
    for i, name in enumerate(selected):
        earlier = state.get(name)
        if (options.part != "all" and name in DATA_STAGES and earlier is not None and earlier.part != options.part
                and earlier.status in ("ok", "timeout") and complete_scenes(options.work / name)):
            say(f"[campaign] {name}: kept from part {earlier.part} ({earlier.status}, {earlier.seconds:.0f} s)")
            continue
        catch_up = options.part == "2" and name in DATA_STAGES
        say(f"[campaign] {name} ...")
        rec = _run_stage(c, name, selected[i + 1:], catch_up)
        say(f"[campaign] {name}: {rec.status}, {rec.seconds:.1f} s{' (' + rec.note + ')' if rec.note else ''}")
        write_outputs(c, summary_of(c, state, started, None))
    return write_outputs(c, summary_of(c, state, started, _now()))


__all__ = ["Options", "Profile", "PROFILES", "PARTS", "STAGE_NAMES", "STATUSES", "StageRecord", "run_campaign",
           "summary_of", "SCHEMA_VERSION"]
