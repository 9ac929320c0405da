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
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from pipelines.gpu_campaign_outputs import (check_out, combined_logs, file_record, report_markdown,
                                            write_weights)

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
#: The packages a lent machine lacks (scripts/gpu_wheels.sh), by import name and distribution.
CARRIED = (("drjit", "drjit"), ("mitsuba", "mitsuba"), ("OpenEXR", "OpenEXR"), ("colour", "colour-science"),
           ("trimesh", "trimesh"))
ROOT = Path(__file__).resolve().parents[1]
WINDOW = 41


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


class StageFailed(Exception):
    """A stage failed: args are (why, figures measured before it failed); the record keeps both.
    TimeoutError takes the same args for a stage whose box ended."""


class SkipStage(Exception):
    """The stage cannot run here (its input is missing); the reason is the record's note."""


@dataclasses.dataclass
class CommandResult:
    returncode: int | None
    timed_out: bool
    seconds: float
    stdout: str


# ---- running commands under a time box -------------------------------------------------------------
class Campaign:
    """The state of one invocation: where things go, the child environment, the clock."""

    def __init__(self, options: Options) -> None:
        self.o = options
        self.p = options.profile
        self.t0 = time.monotonic()
        self.logs = options.work / "logs"
        self.site = options.work / "site"
        self.python = sys.executable
        self.records: dict[str, StageRecord] = {}
        self.current: StageRecord | None = None
        self.box_end = math.inf

    # the clock
    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def left(self) -> float:
        """Seconds left of the current stage's box."""
        return self.box_end - time.monotonic()

    # the children's environment: the carried packages, then this checkout, before anything installed
    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        paths = [str(self.site)] if self.site.is_dir() else []
        paths.append(str(ROOT))
        if env.get("PYTHONPATH"):
            paths.append(env["PYTHONPATH"])
        env["PYTHONPATH"] = os.pathsep.join(paths)
        env["PYTHONUNBUFFERED"] = "1"
        return env

    def log_path(self, stage: str) -> Path:
        return self.logs / f"{stage}.log"

    def note_log(self, text: str, stage: str | None = None) -> None:
        """Append a line to a stage's log (default: the running stage's)."""
        name = stage or (self.current.name if self.current is not None else "campaign")
        with self.log_path(name).open("a") as f:
            f.write(text.rstrip("\n") + "\n")

    def command(self, argv: Sequence[str], box_s: float | None = None) -> CommandResult:
        """Run `argv` from the repository root, stderr (and then stdout) into the stage's log, at most
        `box_s` seconds (default: what is left of the stage's box): then SIGTERM to its process
        group, SIGKILL after the profile's grace."""
        assert self.current is not None
        box = self.left() if box_s is None else min(box_s, self.left())
        argv = [str(a) for a in argv]
        self.current.commands.append(shlex.join(argv))
        self.note_log(f"$ {shlex.join(argv)}   (time box {box:.0f} s)")
        out_path = self.logs / f"{self.current.name}.stdout"
        t = time.monotonic()
        with self.log_path(self.current.name).open("ab") as err, out_path.open("wb") as out:
            proc = subprocess.Popen(argv, cwd=ROOT, env=self.env(), stdin=subprocess.DEVNULL, stdout=out,
                                    stderr=err, start_new_session=True)
            timed_out = False
            try:
                rc: int | None = proc.wait(timeout=max(box, 0.1))
            except subprocess.TimeoutExpired:
                timed_out = True
                _signal_group(proc.pid, signal.SIGTERM)
                try:
                    rc = proc.wait(timeout=self.p.grace_s)
                except subprocess.TimeoutExpired:
                    _signal_group(proc.pid, signal.SIGKILL)
                    rc = proc.wait()
            finally:
                if proc.poll() is None:  # interrupted ourselves: take the child with us
                    _signal_group(proc.pid, signal.SIGKILL)
                    proc.wait()
        stdout = out_path.read_text(errors="replace")
        out_path.unlink()
        seconds = time.monotonic() - t
        self.note_log(f"[stdout]\n{stdout}" if stdout.strip() else "[no stdout]")
        self.note_log(f"[exit status {rc}{', killed at the end of its time box' if timed_out else ''}, {seconds:.1f} s]")
        self.current.returncode = rc
        return CommandResult(rc, timed_out, seconds, stdout)

    def spikesim(self, *args: str, box_s: float | None = None) -> CommandResult:
        return self.command([self.python, "-m", "pipelines.cli", *args], box_s)


def _signal_group(pid: int, sig: int) -> None:
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _json_of(stdout: str) -> Any:
    """The JSON document a command printed (its last top-level one, if anything precedes it)."""
    text = stdout.strip()
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        pass
    starts = [m.start() for m in re.finditer(r"^[\[{]", text, re.M)]
    for s in reversed(starts):
        try:
            return json.loads(text[s:])
        except json.JSONDecodeError:
            continue
    raise StageFailed("no JSON in the command's output")


def _check(result: CommandResult, what: str, figures: dict[str, Any] | None = None) -> None:
    """Raise TimeoutError or StageFailed (with the figures so far) unless the command succeeded."""
    if result.timed_out:
        raise TimeoutError(f"{what} did not end within its time box ({result.seconds:.0f} s)", figures or {})
    if result.returncode != 0:
        raise StageFailed(f"{what} exited with status {result.returncode} (logs.txt has its output)", figures or {})


# ---- the stages ---------------------------------------------------------------------------------
def probe_environment() -> dict[str, Any]:
    """What a stage run in this interpreter finds: each carried package's version (None where it
    does not import, the error beside), torch and its GPU, Mitsuba's variants, Dr.Jit's backends.
    Run in a child with the campaign's PYTHONPATH (stage install), never in the campaign itself."""
    import importlib

    out: dict[str, Any] = {"python": platform.python_version(), "versions": {}, "errors": {}}
    for mod, dist in CARRIED:
        try:
            out["versions"][dist] = str(getattr(importlib.import_module(mod), "__version__", "?"))
        except Exception as exc:  # any failure to import is what this reports
            out["versions"][dist] = None
            out["errors"][dist] = f"{type(exc).__name__}: {exc}"
    try:
        import numpy
        import torch
        out["versions"]["torch"], out["versions"]["numpy"] = torch.__version__, numpy.__version__
        out["torch_cuda"] = torch.cuda.is_available()
        if out["torch_cuda"]:
            out["gpu"], out["bf16"] = torch.cuda.get_device_name(0), torch.cuda.is_bf16_supported()
    except Exception as exc:
        out["errors"]["torch"] = f"{type(exc).__name__}: {exc}"
    try:
        import mitsuba
        out["mitsuba_variants"] = list(mitsuba.variants())
    except Exception:
        pass
    try:
        from spikesim._drjit import has_cuda, has_llvm
        out["drjit_cuda"], out["drjit_llvm"] = has_cuda(), has_llvm()
    except Exception as exc:
        out["errors"]["spikesim._drjit"] = f"{type(exc).__name__}: {exc}"
    return out


_PROBE = "import json; from pipelines.gpu_campaign import probe_environment; print(json.dumps(probe_environment()))"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def install_wheels(wheels: Path, site: Path, python: str = sys.executable,
                   run: Callable[[list[str]], None] | None = None) -> list[str]:
    """Install the carried wheels into `site` (a folder the campaign puts on PYTHONPATH): check
    every file against the folder's SHA256SUMS, `pip install --no-index --no-deps --target` the
    .whl files, unpack the .tar.xz ones (mitsuba, repacked to fit the carry limit) over them.
    Returns the files installed. A missing, unlisted or damaged file is a ValueError naming it."""
    sums_path = wheels / "SHA256SUMS"
    if not sums_path.is_file():
        raise ValueError(f"{sums_path} is missing: run scripts/gpu_wheels.sh beforehand and carry {wheels.name}")
    sums = {}
    for line in sums_path.read_text().splitlines():
        if line.strip():
            digest, name = line.split(None, 1)
            sums[name.strip().lstrip("*")] = digest
    files = sorted(p for p in wheels.iterdir() if p.name != "SHA256SUMS")
    unlisted = [p.name for p in files if p.name not in sums]
    missing = [n for n in sums if not (wheels / n).is_file()]
    if unlisted or missing:
        raise ValueError(f"{wheels}: {'unlisted files ' + ', '.join(unlisted) if unlisted else ''}"
                         f"{'; ' if unlisted and missing else ''}{'missing ' + ', '.join(missing) if missing else ''}"
                         " (rerun scripts/gpu_wheels.sh)")
    for p in files:
        if _sha256(p) != sums[p.name]:
            raise ValueError(f"{p}: sha256 differs from SHA256SUMS: damaged in transfer (rerun scripts/gpu_wheels.sh)")
    site.mkdir(parents=True, exist_ok=True)
    whls = [str(p) for p in files if p.name.endswith(".whl")]
    if whls:
        argv = [python, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--no-compile", "--no-cache-dir",
                "--disable-pip-version-check", "--upgrade", "--target", str(site), *whls]
        if run is not None:
            run(argv)
        else:
            subprocess.run(argv, check=True)
    for p in files:
        if p.name.endswith(".tar.xz"):
            with tarfile.open(p, "r:xz") as tar:
                tar.extractall(site, filter="data")  # no links or paths out of `site`
    return [p.name for p in files]


def stage_install(c: Campaign) -> dict[str, Any]:
    """Make the carried packages importable (installing them when they are not), then report the
    versions, the GPU and the Dr.Jit backends the later stages will find."""
    def probe() -> dict[str, Any]:
        result = c.command([c.python, "-c", _PROBE], box_s=120)
        _check(result, "the import probe")
        return _json_of(result.stdout)

    found = probe()
    figures: dict[str, Any] = {"installed": []}
    if any(found["versions"].get(dist) is None for _, dist in CARRIED):
        if not c.o.wheels.is_dir():
            raise StageFailed(f"{', '.join(d for _, d in CARRIED if found['versions'].get(d) is None)} do not import "
                              f"and there is no wheel folder {c.o.wheels} (run scripts/gpu_wheels.sh, carry .whl)", found)

        def run(argv: list[str]) -> None:
            _check(c.command(argv, box_s=max(c.left() - 30, 10)), "pip install")
        figures["installed"] = install_wheels(c.o.wheels, c.site, c.python, run)
        figures["site"] = str(c.site)
        found = probe()
    figures.update(found)
    missing = [d for _, d in CARRIED if found["versions"].get(d) is None]
    missing += [m for m in ("torch", "spikesim._drjit") if m in found["errors"]]
    if missing:
        raise StageFailed(f"not importable: {', '.join(missing)} (figures.errors says why)", figures)
    if c.p.needs_gpu and not (found.get("torch_cuda") and found.get("drjit_cuda")):
        raise StageFailed(f"no CUDA device: torch sees {'one' if found.get('torch_cuda') else 'none'}, Dr.Jit "
                          f"{'one' if found.get('drjit_cuda') else 'none'}", figures)
    return figures


def _gpu_test_files() -> list[str]:
    """The test files that hold `gpu`-marked tests: pytest collects only those, so that a module
    needing a package the GPU machine lacks (an extra) cannot stop the run at collection."""
    found = [p for p in sorted((ROOT / "tests").rglob("test_*.py")) if "mark.gpu" in p.read_text(errors="replace")]
    return [str(p.relative_to(ROOT)) for p in found]


_PYTEST_COUNTS = re.compile(r"(\d+) (passed|failed|skipped|deselected|errors?|xfailed|xpassed|warnings?)")


def stage_gpu_tests(c: Campaign) -> dict[str, Any]:
    files = _gpu_test_files()
    if not files:
        raise StageFailed("no test file holds a gpu-marked test")
    result = c.command([c.python, "-m", "pytest", "-m", "gpu", "-p", "no:cacheprovider", "-q", "-rfEs",
                        "--continue-on-collection-errors", *files])
    lines = [ln for ln in result.stdout.splitlines() if _PYTEST_COUNTS.search(ln)]
    figures: dict[str, Any] = {"files": files}
    if lines:
        for n, what in _PYTEST_COUNTS.findall(lines[-1]):
            figures[{"error": "errors", "warning": "warnings"}.get(what, what)] = int(n)
    figures["failed_tests"] = re.findall(r"^(?:FAILED|ERROR) (\S+)", result.stdout, re.M)
    if result.timed_out:
        raise TimeoutError(f"pytest did not end within its time box; figures: {figures}")
    if result.returncode not in (0, 5):  # 5: nothing collected (no gpu-marked test left)
        raise StageFailed(f"{figures.get('failed', 0)} failed, {figures.get('errors', 0)} errors: "
                          f"{', '.join(figures['failed_tests'][:5])}")
    return figures


def _bench(c: Campaign, args: Sequence[str]) -> dict[str, Any]:
    result = c.spikesim("bench", *args, "--json")
    _check(result, "spikesim bench")
    doc = _json_of(result.stdout)
    keep = ("stage", "what", "device", "pixel_steps_per_s", "vs_reference", "vs_real_time", "render_share",
            "seconds_per_render")
    return {"machine": doc["machine"], "height": doc["height"], "width": doc["width"],
            "results": [{k: r[k] for k in keep if k in r} for r in doc["results"]]}


def stage_bench_sensor(c: Campaign) -> dict[str, Any]:
    return _bench(c, c.p.bench_sensor)


def stage_bench_render(c: Campaign) -> dict[str, Any]:
    return _bench(c, c.p.bench_render)


def _generated(doc: dict[str, Any]) -> dict[str, Any]:
    gen = doc.get("generated", [])
    secs = [g["seconds"] for g in gen]
    return {"scenes_generated": len(gen), "scenes_skipped": doc.get("skipped", 0),
            "per_scene_seconds": {g["name"]: round(g["seconds"], 3) for g in gen},
            "bytes": sum(g.get("bytes", 0) for g in gen),
            "scene_seconds_min": min(secs) if secs else None, "scene_seconds_max": max(secs) if secs else None,
            "scene_seconds_mean": sum(secs) / len(secs) if secs else None}


def _complete_scenes(root: Path) -> list[str]:
    """Scene folders a reader takes (spikesim.dataset.open_dataset: meta.json, not hidden)."""
    if not root.is_dir():
        return []
    return sorted(d.name for d in root.iterdir() if d.is_dir() and not d.name.startswith(".")
                  and (d / "meta.json").exists())


def _generate_args(c: Campaign) -> tuple[str, ...]:
    return ("--device", c.p.drjit_device, "--seed", str(c.o.seed), "--json", "--quiet")


def stage_llr(c: Campaign) -> dict[str, Any]:
    """The LLR test set (the five scenes under both lights at the paper's size, `balanced`)."""
    out = c.o.work / "llr"
    result = c.spikesim("generate", "llr", *c.p.llr, *_generate_args(c), "-o", str(out))
    _check(result, "spikesim generate llr")
    doc = _json_of(result.stdout)
    return {"root": str(out), "scenes": len(_complete_scenes(out)), "seconds": doc["seconds"],
            **_generated(doc)}


def stage_rllr(c: Campaign) -> dict[str, Any]:
    """A slice of RLLR (the paper's random scenes at its size), grown in steps that fit the box:
    one scene first (its time sets the pace), then as many of the rest as the box allows
    (generation resumes, so the second run makes only the new scenes). The time for the paper's
    100 scenes is extrapolated from the seconds per scene."""
    out = c.o.work / "rllr"
    target = c.o.rllr_count or c.p.rllr_count
    runs: list[dict[str, Any]] = []
    count = min(len(_complete_scenes(out)) + 1, target)  # one new scene first: its time sets the pace
    while True:
        result = c.spikesim("generate", "rllr", *c.p.rllr, "--count", str(count), *_generate_args(c), "-o", str(out))
        done = _complete_scenes(out)
        if result.timed_out or result.returncode != 0:  # what is complete stays usable (train reads it)
            _check(result, f"spikesim generate rllr --count {count} ({len(done)} scene(s) complete)",
                   _rllr_figures(out, runs, target, done))
        runs.append(_json_of(result.stdout))
        figures = _rllr_figures(out, runs, target, done)
        if count >= target:
            return figures
        pace = figures["scene_seconds_max"] or 1.0
        fit = int(max(c.left() - 30.0, 0.0) / (1.25 * pace))  # 25 % and 30 s to spare: scenes vary
        if fit < 1:
            figures["stopped_early"] = f"{len(done)} of {target}: the box had no room for another scene"
            return figures
        count = min(target, len(done) + fit)


def _rllr_figures(out: Path, runs: list[dict[str, Any]], target: int, done: list[str]) -> dict[str, Any]:
    merged = {"generated": [g for r in runs for g in r.get("generated", [])], "skipped": 0}
    fig = {"root": str(out), "target": target, "scenes": len(done), "runs": len(runs),
           "seconds": sum(r.get("seconds", 0.0) for r in runs), **_generated(merged)}
    mean = fig["scene_seconds_mean"]
    fig["extrapolated_100_minutes"] = None if mean is None else 100 * mean / 60
    return fig


def _steady_rate(log: Path) -> dict[str, Any]:
    """Median samples/s and seconds per step of the logged steps after the first (whose
    allocations, kernel selection and compilation make it several times slower): the rate a
    longer run keeps, which the summary's mean over all steps understates in a short one."""
    import csv
    import statistics

    try:
        with log.open(newline="") as f:
            rows = list(csv.DictReader(f))[1:]
        rates = [float(r["samples_per_s"]) for r in rows if float(r["samples_per_s"]) > 0]
        times = [b - a for a, b in zip((float(r["time"]) for r in rows), (float(r["time"]) for r in rows[1:]))]
    except (OSError, KeyError, ValueError):
        return {}
    out: dict[str, Any] = {}
    if rates:
        out["samples_per_s_steady"] = statistics.median(rates)
    if times:
        out["seconds_per_step_steady"] = statistics.median(times)
    return out


def _checkpoint(c: Campaign) -> Path | None:
    run = c.o.work / "run"
    for name in ("best.pt", "last.pt"):  # best.pt needs a validation scene; last.pt is always written
        if (run / name).is_file():
            return run / name
    return None


def stage_train(c: Campaign) -> dict[str, Any]:
    """The profile's config on the RLLR slice, bf16, its step count planned from the measured step
    rate to fill what is left of the box (`--budget-minutes`), cosine schedule to that step."""
    data = c.o.work / "rllr"
    scenes = _complete_scenes(data)
    if not scenes:
        raise SkipStage(f"no RLLR scene in {data} (stage rllr made none)")
    run = c.o.work / "run"
    if run.exists():  # a rerun trains afresh; the folder is this campaign's scratch
        shutil.rmtree(run)
    minutes = max(c.left() - c.p.train_overhead_s, 6.0) * 0.85 / 60
    if c.p.train_max_minutes is not None:
        minutes = min(minutes, c.p.train_max_minutes)
    result = c.spikesim("train", *c.p.train, "--data", str(data), "--precision", "bf16", "--lr-schedule", "cosine",
                        "--budget-minutes", f"{minutes:.3f}", "--seed", str(c.o.seed), "--device", c.p.torch_device,
                        "--quiet", "-o", str(run))
    figures: dict[str, Any] = {"config": c.p.train_config, "data_scenes": len(scenes), "budget_minutes": minutes}
    if result.returncode == 0 or (result.timed_out and _checkpoint(c)):
        try:
            doc = _json_of(result.stdout)
        except StageFailed:
            doc = {}
        keep = ("steps", "epoch", "precision", "samples_per_s", "data_wait_share", "train_seconds", "planned_steps",
                "best_val_psnr_aligned", "last_loss", "weights_sha256", "stopped_by")
        figures.update({k: doc[k] for k in keep if k in doc})
        if doc.get("steps") and doc.get("train_seconds"):
            figures["seconds_per_step"] = doc["train_seconds"] / doc["steps"]
        figures.update(_steady_rate(run / "train_log.csv"))
    ckpt = _checkpoint(c)
    figures["checkpoint"] = None if ckpt is None else str(ckpt)
    _check(result, "spikesim train", figures)
    return figures


def stage_evaluate(c: Campaign) -> dict[str, Any]:
    """Every baseline, the shipped network where this version has one, and the network just
    trained, on the LLR of stage llr."""
    data = c.o.work / "llr"
    if not _complete_scenes(data):
        raise SkipStage(f"no LLR scene in {data} (stage llr made none)")
    methods = ["tfp", "tfi", f"tfp:{c.p.llr_windows * WINDOW}", "black", "mean"]
    notes = []
    try:
        from model.pretrained import PRETRAINED
        shipped = "lrrep" in PRETRAINED
    except ImportError as exc:
        shipped, notes = False, [f"model.pretrained did not import ({exc})"]
    if shipped:
        methods.append("lrrep")
    else:
        notes.append("lrrep left out: this version ships no trained weights (model.pretrained.PRETRAINED has no 'lrrep')")
    ckpt = _checkpoint(c)
    if ckpt is not None:
        methods.append(f"{c.p.train_config}={ckpt}")
    else:
        notes.append("no network trained by this campaign (stage train made no checkpoint): baselines only")
    result = c.spikesim("evaluate", *c.p.evaluate, "--data", str(data), "--methods", *methods, "--json", "--quiet",
                        "--device", c.p.torch_device, "-o", str(c.o.work / "evaluate"))
    _check(result, "spikesim evaluate")
    doc = _json_of(result.stdout)
    return {"methods": doc["methods"], "groups": doc.get("groups", {}), "method_specs": methods,
            "checkpoint": None if ckpt is None else str(ckpt), "notes": notes}


def stage_export(c: Campaign) -> dict[str, Any]:
    ckpt = _checkpoint(c)
    if ckpt is None:
        raise SkipStage("no checkpoint to export (stage train made none)")
    provenance = {"campaign": c.p.name, "config": c.p.train_config, "data": "RLLR slice of stage rllr",
                  "seed": c.o.seed, "source": ckpt.name}
    files = write_weights(ckpt, c.o.out, c.o.work / "export", provenance=provenance)
    return {"checkpoint": str(ckpt), "files": files}


STAGES: dict[str, Callable[[Campaign], dict[str, Any]]] = {
    "install": stage_install, "gpu_tests": stage_gpu_tests, "bench_sensor": stage_bench_sensor,
    "bench_render": stage_bench_render, "llr": stage_llr, "rllr": stage_rllr, "train": stage_train,
    "evaluate": stage_evaluate, "export": stage_export,
}


# ---- the campaign --------------------------------------------------------------------------------
def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _injected(c: Campaign, what: str) -> dict[str, Any]:
    """A stand-in for a stage's work that fails, or that outlives a one-second box."""
    code = ("import sys; print('injected failure (--inject)'); sys.exit(3)" if what == "fail"
            else "import time; time.sleep(600)")
    _check(c.command([c.python, "-c", code], box_s=1.0 if what == "timeout" else None), f"injected {what}")
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
    c.log_path(name).write_text(f"stage {name}, started {rec.started}, time box {box:.0f} s\n")
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


def _load_state(o: Options) -> dict[str, StageRecord]:
    path = o.work / "state.json"
    if o.fresh or not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError:
        return {}
    if doc.get("schema") != SCHEMA_VERSION or doc.get("mode") != o.profile.name or doc.get("seed") != o.seed:
        return {}  # another kind of campaign ran here: its records do not describe this one
    return {n: StageRecord.from_dict(r) for n, r in doc.get("stages", {}).items() if n in STAGE_NAMES}


def _machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu)
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()}


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
    _atomic_write(out / "logs.txt", combined_logs(sections))
    _atomic_write(out / "report.md", report_markdown(summary))
    summary["files"] = [file_record(p) for p in sorted(out.iterdir()) if p.is_file() and p.name != "summary.json"]
    _atomic_write(out / "summary.json", json.dumps(summary, indent=2, default=str) + "\n")
    _atomic_write(c.o.work / "state.json", json.dumps(
        {"schema": SCHEMA_VERSION, "mode": c.p.name, "seed": c.o.seed,
         "stages": {s["name"]: s for s in summary["stages"] if s["name"] in c.records or s.get("started")}},
        indent=2, default=str))
    check_out(out)
    return summary


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_text(text)
    os.replace(tmp, path)


def run_campaign(options: Options, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run the selected stages in order, each in its box; after each one, the outputs are
    rewritten whole, so what a killed call leaves in the output folder is complete up to there."""
    say = progress or (lambda text: None)
    out = options.out
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    if out.is_dir():
        ours = [p for p in out.iterdir() if p.name in OUT_FILES or re.fullmatch(r"weights[\w.]*\.pt", p.name)
                or re.fullmatch(r"\..+\.part", p.name)]  # a killed call's temporary files too
        others = sorted(p.name for p in out.iterdir() if p not in ours)
        if others:
            raise ValueError(f"--out {out} holds other files ({', '.join(others[:5])}{', ...' if len(others) > 5 else ''}): "
                             "give an empty folder (a lent machine returns at most 8 files)")
        for p in ours:  # an earlier call's results, weights above all, would mislead
            p.unlink()
    options.work.mkdir(parents=True, exist_ok=True)
    c = Campaign(options)
    c.logs.mkdir(parents=True, exist_ok=True)
    state = _load_state(options)
    started = _now()
    selected = options.selected
    for i, name in enumerate(selected):
        earlier = state.get(name)
        if (options.part != "all" and name in DATA_STAGES and earlier is not None and earlier.part != options.part
                and earlier.status in ("ok", "timeout") and _complete_scenes(options.work / name)):
            say(f"[campaign] {name}: kept from part {earlier.part} ({earlier.status}, {earlier.seconds:.0f} s)")
            continue
        catch_up = options.part == "2" and name in DATA_STAGES
        say(f"[campaign] {name} ...")
        rec = _run_stage(c, name, selected[i + 1:], catch_up)
        say(f"[campaign] {name}: {rec.status}, {rec.seconds:.1f} s{' (' + rec.note + ')' if rec.note else ''}")
        write_outputs(c, summary_of(c, state, started, None))
    return write_outputs(c, summary_of(c, state, started, _now()))


__all__ = ["Options", "Profile", "PROFILES", "PARTS", "STAGE_NAMES", "STATUSES", "StageRecord", "run_campaign",
           "install_wheels", "probe_environment", "summary_of", "SCHEMA_VERSION"]
