"""The stages of a GPU campaign (pipelines/gpu_campaign/) and what runs them: each stage is a
function of the running `Campaign` that returns its figures, or raises StageFailed, TimeoutError
(both with the figures measured so far) or SkipStage. Every stage but export runs `spikesim`
commands (or pytest) as children through `Campaign.command`, which holds them to the stage's box,
so what is measured is what users run and a stage that hangs is stopped.

Under --work the campaign writes only through `spikesim.outputs` (`check_work` refuses, before
anything runs, a link on the way to anything it writes there, or a folder or FIFO where it keeps a
file; `check_work_owner` a state.json or logs/ that are not the campaign's, and a --work in a
dataset), and it removes a training run (run/, or table1/'s runs) only when its own record says it
trained it (`RUN_MARKER`).

It reads the invocation (options.py) and fills the stages' records (records.py); the run
(runner.py) imports it, never the other way round.
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import math
import os
import platform
import re
import secrets
import shlex
import signal
import stat
import subprocess
import sys
import tarfile
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from pipelines.gpu_campaign.options import ROOT, STAGE_NAMES, Options
from pipelines.gpu_campaign.outputs import write_weights
from pipelines.gpu_campaign.records import SCHEMA_VERSION, StageRecord
from spikesim import outputs

#: The packages a lent machine lacks (scripts/gpu_wheels.sh), by import name and distribution.
CARRIED = (("drjit", "drjit"), ("mitsuba", "mitsuba"), ("OpenEXR", "OpenEXR"), ("colour", "colour-science"),
           ("trimesh", "trimesh"))
WINDOW = 41
#: What the campaign makes in its work folder: the folders (the datasets and the training run are
#: written by `spikesim` children, which take the folder they are given as their root and guard
#: only what lies inside it) and the records.
WORK_FOLDERS = ("logs", "site", "llr", "rllr", "run", "evaluate", "export", "table1", "recipe_data", "recipe_run")
STATE_FILE = "state.json"
#: In a training run the campaign made: the token its state.json records (`Campaign.owns_run`).
RUN_MARKER = ".gpu_campaign_run"


# ---- the work folder ----------------------------------------------------------------------------
def _not_a(mode: int) -> str | None:
    """What a file of `mode` is, when it is not a plain file."""
    for test, what in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return what
    return None if stat.S_ISREG(mode) else "not a plain file"


def _work_files() -> list[tuple[str, ...]]:
    """Every file the campaign itself writes, truncates or removes under --work."""
    logs = [("logs", f"{n}{ext}") for n in (*STAGE_NAMES, "campaign") for ext in (".log", ".stdout")]
    return [(STATE_FILE,), *logs, ("run", RUN_MARKER), ("table1", RUN_MARKER), ("recipe_run", RUN_MARKER)]


def check_work(work: Path) -> None:
    """Refuse, before anything is written, a work folder where the campaign would follow a link or
    meet something of the wrong kind: a symlink at any of its folders (logs/, the datasets, run/,
    site/, ...) or files, or on the way to them, would carry its writes, truncations and deletes
    outside --work (the children it runs take the folder they are given as their root and follow
    it); a folder, FIFO or device where it keeps a file (state.json, a log) would fail or block
    after the stages ran. A ValueError names the first such path."""
    def refuse(path: Path, why: str) -> None:
        raise ValueError(f"--work {work}: {path}: {why}")

    for parts in [(f,) for f in WORK_FOLDERS] + _work_files():
        try:
            for i in range(len(parts)):  # the link itself named, even one that leads outside
                outputs.check_not_link(work.joinpath(*parts[:i + 1]))
            path = outputs.writable(work, *parts)  # and nothing that resolves outside
        except ValueError as exc:
            raise ValueError(f"--work {work}: {exc}") from None
        shown = work.joinpath(*parts)
        try:
            mode = os.lstat(shown).st_mode
        except FileNotFoundError:
            continue
        except NotADirectoryError:  # a file where a folder on the way should be: named by its own entry
            continue
        except OSError as exc:
            raise outputs.naming(exc, shown) from exc
        if len(parts) == 1 and parts[0] in WORK_FOLDERS:
            if not stat.S_ISDIR(mode):
                refuse(path, f"is {_not_a(mode) or 'a file'}, where the campaign keeps a folder (remove it, or choose another "
                             "--work)")
        elif (what := _not_a(mode)) is not None:
            refuse(shown, f"is {what}, where the campaign keeps a file{' (its records)' if parts == (STATE_FILE,) else ''}"
                          " (remove it, or choose another --work)")


#: What a campaign's state.json says it is (and summary.json: runner.summary_of).
CAMPAIGN = "spikesim gpu-campaign"
#: The keys of a state.json written before it named the campaign (round twelve).
_LEGACY_STATE_KEYS = {"schema", "mode", "seed", "run_token", "stages"}


def is_campaign_state(doc: Any) -> bool:
    """Whether `doc` (a state.json's JSON) is a campaign's state as the campaign writes it
    (`new_state`, runner.write_outputs): an object naming the campaign, with a schema number and
    its stages; or one written before it named the campaign (exactly its keys)."""
    if not isinstance(doc, dict) or isinstance(doc.get("schema"), bool) or not isinstance(doc.get("schema"), int):
        return False
    if doc.get("campaign") == CAMPAIGN:
        return True
    return {"schema", "mode", "seed", "stages"} <= set(doc) <= _LEGACY_STATE_KEYS


def new_state(mode: str, seed: Any, run_token: str | None = None, stages: dict | None = None) -> dict[str, Any]:
    """The JSON a campaign keeps in --work/state.json."""
    doc: dict[str, Any] = {"schema": SCHEMA_VERSION, "campaign": CAMPAIGN, "mode": mode, "seed": seed}
    if run_token is not None:
        doc["run_token"] = run_token
    doc["stages"] = stages if stages is not None else {}
    return doc


def check_work_owner(work: Path) -> None:
    """Refuse, before anything is written, a --work that is not the campaign's to write: one at or
    inside a dataset (verify would then report the campaign's state.json and logs/ as extra
    files), a state.json that is not a campaign's state (the user's own file would be replaced),
    and in logs/ anything but the campaign's own logs, or those without a campaign's state.json
    beside them (the campaign truncates, replaces and deletes them). An empty or new folder, or one
    an earlier campaign filled, is accepted. A ValueError names what is there."""
    from spikesim.dataset import check_outside_datasets

    check_outside_datasets(work, flag="--work")
    state = work / STATE_FILE
    ours = False
    if state.is_file() and not state.is_symlink():
        try:
            doc = read_state_doc(work)
        except ValueError as exc:
            raise ValueError(f"--work {work}: {state} is not a campaign's state ({str(exc).splitlines()[0][:160]}): "
                             "the campaign would replace it; move it, or choose another --work") from None
        if not is_campaign_state(doc):
            raise ValueError(f"--work {work}: {state} is not a campaign's state (no \"schema\" and \"campaign\": "
                             f"\"{CAMPAIGN}\"): the campaign would replace it; move it, or choose another --work")
        ours = True
    logs = work / "logs"
    if logs.is_dir() and not logs.is_symlink():
        names = {p[1] for p in _work_files() if p[0] == "logs"}
        held = sorted(p.name for p in logs.iterdir())
        # the campaign's own logs, and the temporary file of one a killed call left (outputs.new_temp_beside)
        temp = re.compile(r"\.(.+)\.[0-9a-f]{8}\.part")
        others = [n for n in held if (n not in names and not ((m := temp.fullmatch(n)) and m.group(1) in names))
                  or (logs / n).is_symlink() or not (logs / n).is_file()]
        if others or (held and not ours):
            shown = others or held
            why = ("files the campaign does not write" if others else
                   f"files, and no campaign's {STATE_FILE} says it wrote them")
            raise ValueError(f"--work {work}: {logs} holds {why} ({', '.join(shown[:5])}"
                             f"{', ...' if len(shown) > 5 else ''}): the campaign would replace or delete its logs "
                             "there; move them, or choose an empty --work (or one an earlier campaign filled)")


def read_state_doc(work: Path) -> dict[str, Any] | None:
    """The JSON object in `work`/state.json (a ValueError if it is damaged), None when there is none."""
    from spikesim.config_io import read_json_object

    path = outputs.writable(work, STATE_FILE)
    if not path.is_file() or path.is_symlink():
        return None
    return read_json_object(path, "campaign state")  # a small regular file, bounded nesting


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
        self.run_token: str | None = None
        """The token state.json records for the training runs this campaign made in --work/run
        (the run holds it in RUN_MARKER); None until it first trains there."""

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

    def work_path(self, *parts: str) -> Path:
        """`parts` under --work, reached without a link on the way (a ValueError naming one)."""
        return outputs.writable(self.o.work, *parts)

    def log_path(self, stage: str) -> Path:
        return self.work_path("logs", f"{stage}.log")

    def owns_run(self, folder: str = "run") -> bool:
        """Whether --work/`folder` (run/, or table1/'s runs) is what this campaign trained: its
        RUN_MARKER (a plain file, no link on the way) holds the token state.json records. A user's
        run, or one copied from elsewhere, has no such marker."""
        if not self.run_token:
            return False
        try:
            marker = self.work_path(folder, RUN_MARKER)
            if marker.is_symlink() or not marker.is_file() or marker.stat().st_size > 1024:
                return False
            return marker.read_text(errors="replace").strip() == self.run_token
        except (OSError, ValueError):
            return False

    def record_run_token(self) -> None:
        """Give this work folder's runs a token (kept if it has one) and write it into state.json
        now, before the run exists, so that even a call killed during training leaves a run the
        next call recognises as its own."""
        if not self.run_token:
            self.run_token = secrets.token_hex(16)
        try:
            doc = read_state_doc(self.o.work) or {}
        except ValueError:
            doc = {}
        if doc.get("schema") != SCHEMA_VERSION or not isinstance(doc.get("stages"), dict):
            doc = new_state(self.p.name, self.o.seed)
        doc["campaign"] = CAMPAIGN
        doc["run_token"] = self.run_token
        outputs.atomic_write_text(self.work_path(STATE_FILE), json.dumps(doc, indent=2, default=str))

    def check_run_folder(self, name: str, what: str) -> bool:
        """Whether --work/`name` holds this campaign's earlier runs (True) or nothing (False); a
        folder with anything else raises StageFailed, left as it was. A run folder is removed only
        when this campaign's record says it trained it (state.json's token in the folder's marker),
        and only once training starts (`take_run_folder`); an empty folder is simply used."""
        folder = self.work_path(name)  # a link there (or above) is refused, naming it
        existing = folder.is_dir() and any(folder.iterdir())
        ours = existing and self.owns_run(name)
        if existing and not ours:
            raise StageFailed(f"{folder} exists and is not an earlier campaign's {what} (state.json in {self.o.work} "
                              f"records no token that {folder / RUN_MARKER} holds): left as it was; move it, or "
                              "give another --work")
        return ours

    def take_run_folder(self, name: str, ours: bool) -> None:
        """Start --work/`name` afresh for this campaign's runs: its earlier runs removed (`ours`,
        from check_run_folder; never through a link), the token recorded in state.json before the
        runs exist, and written into the folder's marker."""
        if ours:
            outputs.remove(self.o.work, name)
        self.record_run_token()
        outputs.make_dirs(self.o.work, name)
        outputs.atomic_write_text(self.work_path(name, RUN_MARKER), self.run_token + "\n")

    def note_log(self, text: str, stage: str | None = None) -> None:
        """Append a line to a stage's log (default: the running stage's)."""
        name = stage or (self.current.name if self.current is not None else "campaign")
        outputs.append_text(self.log_path(name), text.rstrip("\n") + "\n")

    def command(self, argv: Sequence[str], box_s: float | None = None) -> CommandResult:
        """Run `argv` from the repository root, stderr (and then stdout) into the stage's log, at most
        `box_s` seconds (default: what is left of the stage's box): then SIGTERM to its process
        group, SIGKILL after the profile's grace."""
        assert self.current is not None
        box = self.left() if box_s is None else min(box_s, self.left())
        argv = [str(a) for a in argv]
        self.current.commands.append(shlex.join(argv))
        self.note_log(f"$ {shlex.join(argv)}   (time box {box:.0f} s)")
        out_parts = ("logs", f"{self.current.name}.stdout")
        out_path = self.work_path(*out_parts)
        t = time.monotonic()
        # read back through the descriptor the child wrote, never by name again
        with outputs.open_in_place(self.log_path(self.current.name), "ab") as err, \
                os.fdopen(outputs.in_place_fd(out_path, os.O_RDWR | os.O_CREAT), "rb+") as out:
            os.ftruncate(out.fileno(), 0)
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
            out.seek(0)
            stdout = out.read().decode(errors="replace")
        outputs.remove(self.o.work, *out_parts)
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


def check_command(result: CommandResult, what: str, figures: dict[str, Any] | None = None) -> None:
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


_PROBE = ("import json; from pipelines.gpu_campaign.stages import probe_environment; "
          "print(json.dumps(probe_environment()))")


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
        check_command(result, "the import probe")
        return _json_of(result.stdout)

    found = probe()
    figures: dict[str, Any] = {"installed": []}
    if any(found["versions"].get(dist) is None for _, dist in CARRIED):
        if not c.o.wheels.is_dir():
            raise StageFailed(f"{', '.join(d for _, d in CARRIED if found['versions'].get(d) is None)} do not import "
                              f"and there is no wheel folder {c.o.wheels} (run scripts/gpu_wheels.sh, carry .whl)", found)

        def run(argv: list[str]) -> None:
            check_command(c.command(argv, box_s=max(c.left() - 30, 10)), "pip install")
        figures["installed"] = install_wheels(c.o.wheels, outputs.make_dirs(c.o.work, "site"), c.python, run)
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
    check_command(result, "spikesim bench")
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


def complete_scenes(root: Path) -> list[str]:
    """Scene folders a reader takes (spikesim.dataset.open_dataset: meta.json, not hidden)."""
    if not root.is_dir():
        return []
    return sorted(d.name for d in root.iterdir() if d.is_dir() and not d.name.startswith(".")
                  and (d / "meta.json").exists())


def _generate_args(c: Campaign) -> tuple[str, ...]:
    return ("--device", c.p.drjit_device, "--seed", str(c.o.seed), "--json", "--quiet")


def stage_llr(c: Campaign) -> dict[str, Any]:
    """The LLR test set (the five scenes under both lights at the paper's size, `balanced`)."""
    out = c.work_path("llr")  # generate takes it as its root: no link on the way
    result = c.spikesim("generate", "llr", *c.p.llr, *_generate_args(c), "-o", str(out))
    # cut by its box: the scenes complete so far stay usable (evaluate reads them; generation resumes)
    check_command(result, "spikesim generate llr", {"root": str(out), "scenes": len(complete_scenes(out))})
    doc = _json_of(result.stdout)
    return {"root": str(out), "scenes": len(complete_scenes(out)), "seconds": doc["seconds"],
            **_generated(doc)}


def stage_rllr(c: Campaign) -> dict[str, Any]:
    """A slice of RLLR (the paper's random scenes at its size), grown in steps that fit the box:
    one scene first (its time sets the pace), then as many of the rest as the box allows
    (generation resumes, so the second run makes only the new scenes). The time for the paper's
    100 scenes is extrapolated from the seconds per scene."""
    out = c.work_path("rllr")
    target = c.o.rllr_target
    runs: list[dict[str, Any]] = []
    count = min(len(complete_scenes(out)) + 1, target)  # one new scene first: its time sets the pace
    while True:
        result = c.spikesim("generate", "rllr", *c.p.rllr, "--count", str(count), *_generate_args(c), "-o", str(out))
        done = complete_scenes(out)
        if result.timed_out or result.returncode != 0:  # what is complete stays usable (train reads it)
            check_command(result, f"spikesim generate rllr --count {count} ({len(done)} scene(s) complete)",
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


def _checkpoint(c: Campaign, folder: str = "run") -> Path | None:
    """The checkpoint of the training run this campaign made in --work/`folder` (run/: stage train's;
    recipe_run/: stage recipe's); none in a run it did not make."""
    run = c.o.work / folder
    if not c.owns_run(folder):
        return None
    for name in ("best.pt", "last.pt"):  # best.pt needs a validation scene; last.pt is always written
        if (run / name).is_file():
            return run / name
    return None


def _train_figures(c: Campaign, result: CommandResult, folder: str) -> dict[str, Any]:
    """What a `spikesim train` of this campaign printed and logged (its JSON, the steady rate), and
    the checkpoint it left in --work/`folder` with its weights' fingerprint."""
    figures: dict[str, Any] = {}
    if result.returncode == 0 or (result.timed_out and _checkpoint(c, folder)):
        try:
            doc = _json_of(result.stdout)
        except StageFailed:
            doc = {}
        keep = ("steps", "epoch", "precision", "samples_per_s", "data_wait_share", "train_seconds", "planned_steps",
                "best_val_psnr_aligned", "last_loss", "weights_sha256", "stopped_by")
        figures.update({k: doc[k] for k in keep if k in doc})
        if doc.get("steps") and doc.get("train_seconds"):
            figures["seconds_per_step"] = doc["train_seconds"] / doc["steps"]
        figures.update(_steady_rate(c.o.work / folder / "train_log.csv"))
    ckpt = _checkpoint(c, folder)
    figures["checkpoint"] = None if ckpt is None else str(ckpt)
    if ckpt is not None:  # the weights exported: best.pt's (validated several times a run), not the last step's
        from model.checkpoint import load_checkpoint
        figures["checkpoint_weights_sha256"] = load_checkpoint(ckpt)["weights_sha256"]
    return figures


def stage_train(c: Campaign) -> dict[str, Any]:
    """The profile's config on the RLLR slice, bf16, its step count planned from the measured step
    rate to fill what is left of the box (`--budget-minutes`), cosine schedule to that step."""
    run = c.work_path("run")
    ours = c.check_run_folder("run", "training run")
    data = c.o.work / "rllr"
    scenes = complete_scenes(data)
    if not scenes:
        kept = f"; {run} (this campaign's earlier run) left as it was" if ours else ""
        raise SkipStage(f"no RLLR scene in {data} (stage rllr made none){kept}")
    c.take_run_folder("run", ours)  # a rerun trains afresh
    minutes = max(c.left() - c.p.train_overhead_s, 6.0) * 0.85 / 60
    if c.p.train_max_minutes is not None:
        minutes = min(minutes, c.p.train_max_minutes)
    result = c.spikesim("train", *c.p.train, "--data", str(data), "--precision", "bf16", "--lr-schedule", "cosine",
                        "--budget-minutes", f"{minutes:.3f}", "--seed", str(c.o.seed), "--device", c.p.torch_device,
                        "--quiet", "-o", str(run))
    figures: dict[str, Any] = {"config": c.p.train_config, "data_scenes": len(scenes), "budget_minutes": minutes}
    figures.update(_train_figures(c, result, "run"))
    check_command(result, "spikesim train", figures)
    return figures


def _validations(run: Path) -> list[tuple[int, float]]:
    """(step, validation aligned PSNR in dB) of every validation a run logged (its val_log.csv)."""
    out: list[tuple[int, float]] = []
    try:
        with (run / "val_log.csv").open(newline="") as f:
            for row in csv.DictReader(f):
                v = float(row["psnr_aligned"])
                if math.isfinite(v):
                    out.append((int(float(row["step"])), round(v, 3)))
    except (OSError, KeyError, ValueError):
        pass
    return out


def stage_recipe(c: Campaign) -> dict[str, Any]:
    """The shipped network's recipe at GPU scale (RECIPE_CALL): the sixth stage's datasets made on
    the GPU with their own seeds and commands (the profile's `recipe_sets`, each set in a box that
    leaves training its least; one cut keeps its complete scenes, one that fails is left out and
    named), then `train` with the profile's recipe (`--init lrrep`, the larger batch and crop) on
    every training set made, best.pt chosen on the validation sets made, for what is left of the
    box. The weights come back through stage export (recipe_weights.pt), to be scored off the GPU
    on the held-out sets, as every network here is."""
    root = c.work_path("recipe_data")
    ours = c.check_run_folder("recipe_run", "training run")  # before any data is made: a user's run stops us
    outputs.make_dirs(c.o.work, "recipe_data")
    sets: dict[str, dict[str, Any]] = {}
    figures: dict[str, Any] = {"config": c.p.recipe_config, "sets": sets, "seed": c.p.recipe_seed,
                               "train_args": list(c.p.recipe_train)}
    for name, role, args in c.p.recipe_sets:
        box = c.left() - c.p.recipe_train_least_s
        rec: dict[str, Any] = {"role": role, "command": shlex.join(["spikesim", "generate", "rllr", *args])}
        sets[name] = rec
        if box < c.p.recipe_set_least_s:
            rec.update(status="skipped", scenes=len(complete_scenes(root / name)),
                       note=f"{max(box, 0):.0f} s left before training's {c.p.recipe_train_least_s:.0f} s")
            continue
        argv = ("generate", "rllr", *args, "--device", c.p.drjit_device, "--json", "--quiet",
                "-o", str(c.work_path("recipe_data", name)))
        result = c.spikesim(*argv, box_s=box)
        seconds = result.seconds
        if result.returncode != 0 and not result.timed_out and "--workers" in argv:
            # several processes on one GPU were never run before this stage: on a failure the set is
            # made again in one process (generation resumes: complete scenes are kept), and said so
            i = argv.index("--workers")
            if argv[i + 1] != "1" and c.left() - c.p.recipe_train_least_s >= c.p.recipe_set_least_s:
                rec["retried"] = f"failed with --workers {argv[i + 1]} (exit status {result.returncode}); made again with --workers 1"
                result = c.spikesim(*argv[:i + 1], "1", *argv[i + 2:], box_s=c.left() - c.p.recipe_train_least_s)
                seconds += result.seconds
        rec.update(seconds=round(seconds, 2), scenes=len(complete_scenes(root / name)),
                   status="ok" if result.returncode == 0 else "timeout" if result.timed_out else "failed")
        if result.returncode == 0:
            try:
                rec.update(_generated(_json_of(result.stdout)))
            except StageFailed:
                pass
    usable = {role: [str(root / n) for n, r, _ in c.p.recipe_sets if r == role and sets[n]["status"] == "ok"
                     and sets[n]["scenes"]] for role in ("train", "val")}
    # a set cut by its box keeps its complete scenes, but its manifest is that of a run in progress:
    # only finished sets are trained on (a reader checks a dataset against its record)
    figures["train_sets"], figures["val_sets"] = [Path(p).name for p in usable["train"]], [Path(p).name for p in usable["val"]]
    figures["data_seconds"] = round(sum(r.get("seconds", 0.0) for r in sets.values()), 2)
    if not usable["train"]:
        raise StageFailed("no training set was made in full (the sets' records say why; logs.txt has the commands)",
                          figures)
    c.take_run_folder("recipe_run", ours)
    run = c.work_path("recipe_run")
    minutes = max(c.left() - c.p.recipe_overhead_s, 6.0) * 0.85 / 60
    if c.p.recipe_max_minutes is not None:
        minutes = min(minutes, c.p.recipe_max_minutes)
    val = ["--val-data", *usable["val"]] if usable["val"] else []
    result = c.spikesim("train", *c.p.recipe_train, "--data", *usable["train"], *val, "--budget-minutes",
                        f"{minutes:.3f}", "--seed", str(c.p.recipe_seed), "--device", c.p.torch_device, "--quiet",
                        "-o", str(run))
    figures["budget_minutes"] = minutes
    figures["data_scenes"] = sum(sets[Path(p).name]["scenes"] for p in usable["train"])
    figures.update(_train_figures(c, result, "recipe_run"))
    figures["validations"] = _validations(run)
    check_command(result, "spikesim train (recipe)", figures)
    return figures


def stage_evaluate(c: Campaign) -> dict[str, Any]:
    """Every baseline, the shipped network where this version has one, and the network just
    trained, on the LLR of stage llr."""
    data = c.o.work / "llr"
    if not complete_scenes(data):
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
                        "--device", c.p.torch_device, "-o", str(c.work_path("evaluate")))
    check_command(result, "spikesim evaluate")
    doc = _json_of(result.stdout)
    return {"methods": doc["methods"], "groups": doc.get("groups", {}), "method_specs": methods,
            "checkpoint": None if ckpt is None else str(ckpt), "notes": notes}


# ---- table1: the Table-1 networks at equal training FLOP ------------------------------------------
#: Random samples per epoch of a table1 run: more than any run takes, so that a run is one epoch and
#: validates once, when it stops (an epoch of the slice's few samples would validate every step or two).
TABLE1_SAMPLES_PER_EPOCH = 1_000_000


def table1_costs(networks: Sequence[Sequence[str]], train_args: Sequence[str], frames: str) -> dict[str, Any]:
    """Per table1 network (label, config): its config as `spikesim train` reads it with
    `train_args` (the same parser and overrides), its parameters, GFLOP per frame at the size of the
    scenes in `frames` and GFLOP per training step (model/flops.py); a network whose config does not
    load or build gets its error instead. Run in a child (stage table1), never in the campaign."""
    from model.config import load_config
    from model.data import open_scenes
    from model.flops import network_cost
    from pipelines.cli import build_parser
    from pipelines.train import _apply_overrides

    scene = open_scenes(frames)[0]
    height, width = int(scene.height), int(scene.width)
    out: dict[str, Any] = {"frame": [height, width], "networks": {}}
    for label, config in networks:
        try:
            args = build_parser("train").parse_args(["train", "--config", config, "--data", frames, *train_args])
            exp = _apply_overrides(load_config(config), args)
            cost = network_cost(exp, height, width)
            out["networks"][label] = {
                "parameters": cost.parameters, "gflop_per_frame": cost.gflop_per_frame,
                "sampling_gflop_per_frame": cost.sampling_flop_per_frame / 1e9,
                "train_gflop_per_step": cost.train_flop_per_step / 1e9, "arch": exp.model.arch,
                "crop": exp.train.crop, "num_windows": exp.train.num_windows, "batch_size": exp.train.batch_size,
                "loss": exp.train.loss}
        except (Exception, SystemExit) as exc:  # argparse exits; any failure is this network's, not the others'
            out["networks"][label] = {"error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:400]}
    return out


_TABLE1_COSTS = ("import json, sys; from pipelines.gpu_campaign.stages import table1_costs; "
                 "print(json.dumps(table1_costs(**json.loads(sys.argv[1]))))")


def _log_size(c: Campaign) -> int:
    try:
        return c.log_path(c.current.name).stat().st_size
    except OSError:
        return 0


def _why(c: Campaign, since: int) -> str:
    """The last line of what the last command wrote to stderr (its log from byte `since`): the
    error line of a traceback, or the one-line refusal of a `spikesim` command."""
    try:
        with c.log_path(c.current.name).open("rb") as f:
            f.seek(since)
            text = f.read(4 << 20).decode(errors="replace")
    except OSError:
        return "its log could not be read"
    stderr = re.split(r"^\[(?:stdout\]|no stdout\])", text, maxsplit=1, flags=re.M)[0]
    lines = [ln.strip() for ln in stderr.splitlines()[1:] if ln.strip()]  # the first is the command
    errors = [ln for ln in lines if re.search(r"(Error|Exception|error:)", ln)]
    return ((errors or lines or ["no message (logs.txt has its output)"])[-1])[:400]


def _table1_scores(doc: dict[str, Any], label: str) -> dict[str, Any]:
    """A network's aligned PSNR, PSNR and SSIM on the LLR, low light, normal light and all, from
    `evaluate --json`."""
    out: dict[str, Any] = {}
    for key, table in (("low", doc.get("groups", {}).get("ALL_low", {})),
                       ("normal", doc.get("groups", {}).get("ALL_normal", {})), ("all", doc.get("methods", {}))):
        row = table.get(label)
        if row:
            out[key] = {m: row.get(m) for m in ("psnr_aligned", "psnr", "ssim", "frames")}
    return out


def stage_table1(c: Campaign) -> dict[str, Any]:
    """The Table-1 networks (the profile's: `full`, S2I, WGSE, RSIR, SSML at their published sizes
    on a GPU) trained at equal training FLOP on the RLLR slice, each scored on the LLR.

    The time left in the box, less the scoring's (`table1_eval_s`), is shared equally over the
    networks. The first network, the reference, trains for its share (`--budget-minutes`: 85 % of
    its share after `table1_overhead_s`, its step count planned from its measured step rate, as
    stage train does); its steps times its FLOP per step (model/flops.py `network_cost`) are the
    training FLOP of every network, so each other one trains `--max-steps` = that FLOP over its own
    FLOP per step, in a box of its share of what is then left. A network that cannot train (out of
    memory, a config that does not build) records why and the others go on (the next one becomes
    the reference if the reference failed); one cut by its box is scored at the steps it reached,
    marked `equal_flop: false`. Each run is `spikesim train` (bf16, cosine schedule to its last
    step, random samples so that it validates once, at its end); the scoring one `spikesim
    evaluate` of every trained network's last.pt (one per network if that fails)."""
    llr, rllr = c.o.work / "llr", c.o.work / "rllr"
    folder = c.work_path("table1")
    ours = c.check_run_folder("table1", "table1 runs")
    train_scenes, test_scenes = complete_scenes(rllr), complete_scenes(llr)
    kept = f"; {folder} (this campaign's earlier runs) left as it was" if ours else ""
    if not train_scenes:
        raise SkipStage(f"no RLLR scene in {rllr} (stage rllr made none){kept}")
    if not test_scenes:
        raise SkipStage(f"no LLR scene in {llr} (stage llr made none){kept}")
    c.take_run_folder("table1", ours)  # a rerun trains afresh

    nets: dict[str, dict[str, Any]] = {label: {"config": config} for label, config in c.p.table1}
    figures: dict[str, Any] = {"networks": nets, "data_scenes": len(train_scenes), "test_scenes": len(test_scenes),
                               "precision": "bf16", "reference": None, "train_gflop_each": None, "failed": []}
    result = c.command([c.python, "-c", _TABLE1_COSTS,
                        json.dumps({"networks": [list(n) for n in c.p.table1], "train_args": list(c.p.table1_train),
                                    "frames": str(llr)})], box_s=min(c.left(), 180.0))
    check_command(result, "the FLOP count (model/flops.py)", figures)
    costs = _json_of(result.stdout)
    figures["frame"] = costs["frame"]
    for label, cost in costs["networks"].items():
        nets[label].update(cost)

    flop: float | None = None  # GFLOP of training every network gets: the reference's
    todo = [(label, config) for label, config in c.p.table1 if "error" not in nets[label]]
    trained: dict[str, Path] = {}
    for i, (label, config) in enumerate(todo):
        rec = nets[label]
        share = (c.left() - c.p.table1_eval_s) / (len(todo) - i)  # time unused by earlier runs goes to later ones
        if share < 1.0:
            rec["error"] = (f"not started: {max(c.left(), 0):.0f} s left of the box, and the scoring keeps "
                            f"{c.p.table1_eval_s:.0f} s")
            continue
        if flop is None:  # the reference: its step count comes from its share of the time
            minutes = max(share - c.p.table1_overhead_s, 1.0) * 0.85 / 60
            if c.p.table1_max_minutes is not None:
                minutes = min(minutes, c.p.table1_max_minutes)
            length = ["--budget-minutes", f"{minutes:.4f}"]
            rec.update(role="reference", budget_minutes=minutes)
        else:
            steps = max(1, round(flop / rec["train_gflop_per_step"]))
            length = ["--max-steps", str(steps)]
            rec.update(role="equal FLOP", planned_steps=steps)
        run = c.work_path("table1", label)
        since = _log_size(c)
        result = c.spikesim("train", "--config", config, *c.p.table1_train, *length, "--data", str(rllr),
                            "--precision", "bf16", "--lr-schedule", "cosine", "--samples-per-epoch",
                            str(TABLE1_SAMPLES_PER_EPOCH), "--seed", str(c.o.seed), "--device", c.p.torch_device,
                            "--quiet", "-o", str(run), box_s=share)
        try:
            doc = _json_of(result.stdout)
        except StageFailed:
            doc = {}
        last = run / "last.pt"
        rec.update({k: doc[k] for k in ("steps", "train_seconds", "samples_per_s", "data_wait_share", "planned_steps",
                                        "stopped_by", "last_loss", "precision") if doc.get(k) is not None})
        rec.update(seconds=round(result.seconds, 1), returncode=result.returncode, timed_out=result.timed_out,
                   box_s=round(share, 1))
        if rec.get("steps") and rec.get("train_seconds"):
            rec["seconds_per_step"] = rec["train_seconds"] / rec["steps"]
        if not (result.returncode == 0 or result.timed_out) or not last.is_file() or not rec.get("steps"):
            rec["error"] = (f"train exited with status {result.returncode}: {_why(c, since)}" if not result.timed_out
                            else f"cut by its box ({share:.0f} s) before a checkpoint")
            continue
        rec["train_gflop"] = rec["steps"] * rec["train_gflop_per_step"]
        if flop is None:  # the reference's steps, however it ended, set every other network's
            flop = rec["train_gflop"]
            figures["reference"], figures["train_gflop_each"] = label, flop
            rec["equal_flop"] = True
        else:
            rec["equal_flop"] = rec["steps"] == rec["planned_steps"]
        if result.timed_out:
            rec["note"] = f"cut by its box ({share:.0f} s) at step {rec['steps']}" + (
                "" if rec["role"] == "reference" else f" of {rec['planned_steps']}: less training FLOP than the others")
        trained[label] = last
    figures["failed"] = [label for label in nets if "error" in nets[label]]
    if not trained:
        raise StageFailed("no network trained: " + "; ".join(f"{label}: {nets[label]['error']}"
                                                             for label in figures["failed"]), figures)

    t = time.monotonic()
    result = c.spikesim("evaluate", *c.p.evaluate, "--data", str(llr), "--methods",
                        *[f"{label}={path}" for label, path in trained.items()], "--json", "--quiet", "--device",
                        c.p.torch_device, "-o", str(c.work_path("table1", "evaluate")))
    if result.returncode == 0:
        doc = _json_of(result.stdout)
        for label in trained:
            nets[label]["scores"] = _table1_scores(doc, label)
    elif not result.timed_out and len(trained) > 1:  # one network's failure must not cost the others' scores
        figures["evaluate_note"] = "one evaluate of every network failed: each scored alone"
        for label, path in trained.items():
            since = _log_size(c)
            one = c.spikesim("evaluate", *c.p.evaluate, "--data", str(llr), "--methods", f"{label}={path}", "--json",
                             "--quiet", "--device", c.p.torch_device, "-o", str(c.work_path("table1", f"evaluate_{label}")))
            if one.returncode == 0:
                nets[label]["scores"] = _table1_scores(_json_of(one.stdout), label)
            else:
                nets[label]["error"] = ("cut by the box while scored" if one.timed_out else
                                        f"evaluate exited with status {one.returncode}: {_why(c, since)}")
    figures["evaluate_seconds"] = round(time.monotonic() - t, 1)
    figures["failed"] = [label for label in nets if "error" in nets[label]]
    if not any("scores" in n for n in nets.values()):
        check_command(result, "spikesim evaluate", figures)
        raise StageFailed("no network was scored on the LLR (logs.txt has evaluate's output)", figures)
    return figures


def stage_export(c: Campaign) -> dict[str, Any]:
    """The checkpoints this campaign trained as weights-only files: stage train's as weights*.pt,
    stage recipe's as recipe_weights*.pt (each run's best.pt where it validated, else last.pt)."""
    exported: list[dict[str, Any]] = []
    checkpoints = []
    ckpt = _checkpoint(c)
    if ckpt is not None:
        checkpoints.append(ckpt)
        provenance = {"campaign": c.p.name, "config": c.p.train_config, "data": "RLLR slice of stage rllr",
                      "seed": c.o.seed, "source": ckpt.name}
        exported += write_weights(ckpt, c.o.out, outputs.make_dirs(c.o.work, "export"), provenance=provenance)
    recipe = _checkpoint(c, "recipe_run")
    if recipe is not None:
        checkpoints.append(recipe)
        provenance = {"campaign": c.p.name, "config": c.p.recipe_config, "stage": "recipe",
                      "data": "the sixth stage's sets made on the GPU (stage recipe)",
                      "train_args": list(c.p.recipe_train), "seed": c.p.recipe_seed, "source": recipe.name}
        exported += write_weights(recipe, c.o.out, outputs.make_dirs(c.o.work, "export", "recipe"),
                                  provenance=provenance, stem="recipe_weights")
    if not checkpoints:
        raise SkipStage("no checkpoint to export (neither stage train nor stage recipe made one)")
    return {"checkpoint": str(checkpoints[0]), "checkpoints": [str(p) for p in checkpoints], "files": exported}


def stage_tradeoff(c: Campaign) -> dict[str, Any]:
    """The trade study at the paper's 400 x 250 on the GPU (the profile's `spikesim tradeoff`
    options): its runs are cached one by one, so a box that cuts it keeps what it measured and a
    later call goes on from there; then the report of what is cached (the CSV, handed back as
    tradeoff.csv). Its own call: TRADEOFF_CALL."""
    out = c.work_path("tradeoff")
    device = ("--device", c.p.drjit_device, "--backend", c.p.drjit_device, "--seed", str(c.o.seed))
    study = c.spikesim("tradeoff", *c.p.tradeoff, *device, "-o", str(out), "--quiet",
                       box_s=max(c.left() - c.p.tradeoff_report_s, 1.0))
    cut = study.timed_out or study.returncode != 0
    if cut:  # the report of what the box let it measure
        report = c.spikesim("tradeoff", *c.p.tradeoff, *device, "-o", str(out), "--quiet", "--report-only")
        if report.returncode != 0:
            check_command(study, "spikesim tradeoff")  # nothing cached: the study's own failure says why
            check_command(report, "spikesim tradeoff --report-only")
    csv_path = out / "tradeoff.csv"
    if not csv_path.is_file():
        raise StageFailed(f"spikesim tradeoff wrote no {csv_path}")
    text = csv_path.read_text()
    outputs.atomic_write_text(outputs.writable(c.o.out, "tradeoff.csv"), text)
    rows = list(csv.DictReader(io.StringIO(text)))
    measured = sorted({f"{r['scene']}_{r['light']}" for r in rows if r["knob"] != "gt"})
    loss: dict[str, dict[str, float]] = {}  # per cheap run, each scored axis's loss against the reference
    for r in rows:
        for axis in ("tfp", "net"):
            v = float(r.get(f"{axis}_gt_dpsnr") or "nan")
            if r["knob"] in ("spp", "seeds") and math.isfinite(v):
                loss.setdefault(f"{r['scene']}_{r['light']}:{r['run']}", {})[axis] = round(-v, 3)
    return {"csv": "tradeoff.csv", "rows": len(rows), "scene_lights": measured, "complete": not cut,
            "seconds": study.seconds, "loss_db": loss}


STAGES: dict[str, Callable[[Campaign], dict[str, Any]]] = {
    "install": stage_install, "gpu_tests": stage_gpu_tests, "bench_sensor": stage_bench_sensor,
    "bench_render": stage_bench_render, "llr": stage_llr, "rllr": stage_rllr, "train": stage_train,
    "evaluate": stage_evaluate, "recipe": stage_recipe, "export": stage_export, "tradeoff": stage_tradeoff,
    "table1": stage_table1,
}


__all__ = ["Campaign", "CommandResult", "StageFailed", "SkipStage", "STAGES", "CARRIED", "ROOT", "install_wheels",
           "probe_environment", "check_command", "complete_scenes", "check_work", "read_state_doc", "WORK_FOLDERS",
           "check_work_owner", "is_campaign_state", "new_state", "CAMPAIGN",
           "STATE_FILE", "RUN_MARKER", "table1_costs", "TABLE1_SAMPLES_PER_EPOCH"]
