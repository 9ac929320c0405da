"""Every GPU measurement and a training run, as one campaign that runs the first time on a lent GPU.

A lent machine (docs/gpu_campaign.md) comes rarely, for 15 minutes of device time a task (its
start and idle waits included) in calls of at most 10 minutes, without network and without
Dr.Jit, Mitsuba, OpenEXR, colour-science and trimesh. So the campaign is written and rehearsed
beforehand (`--dry-run`: every stage on the CPU at a tiny size, in the default test suite), and on
the day it:

1. installs the missing packages from the wheels carried with the working tree (scripts/gpu_wheels.sh);
2. runs each stage as a child process under its own time box, cut to what is left of the call's
   deadline after the least the later stages need, so that one stage that hangs or fails costs only
   itself: the later ones still run (a stage whose least no longer fits is skipped, the reason in
   its note), and each stage's record (status, seconds, figures, log) is written to the output
   folder as soon as it ends, so a call killed at its limit still returns everything before it;
3. hands back at most 8 files (outputs.py): summary.json, logs.txt, report.md and the trained
   weights.

Stages: install, gpu_tests, bench_sensor, bench_render, llr, rllr, train, evaluate, export, table1
(the Table-1 networks at equal training FLOP). The default part, `one`, runs them in one call of
9 minutes in order of value (install, the benches, the LLR, a one- or two-scene RLLR slice, a
short training, its weights), then gpu_tests, evaluate and table1 only where time is left;
table1 has a call of its own (options.TABLE1_CALL). For a longer lease, `--part 1` (up to the datasets) and `--part
2` (training, evaluation, weights) split them over two calls, the second finding the first's
datasets and records in the work folder when the machine is still the same and regenerating what
is missing when it is not; `--part all` runs them in stage order. Each stage is a `spikesim`
command, so what is measured is what users run.

This module is the run: it puts the stages (stages.py) in order and in their boxes and writes the
records (records.py) of an invocation (options.py) into the output folder (outputs.py). Nothing
in the package imports it but `__init__` and the command line (cmd.py).
"""
from __future__ import annotations

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
from spikesim.dataset import LOCK_FILE
from pipelines.gpu_campaign.options import DATA_STAGES, ROOT, STAGE_NAMES, Options
from pipelines.gpu_campaign.outputs import check_out, combined_logs, file_record, report_markdown
from pipelines.gpu_campaign.records import SCHEMA_VERSION, STATUSES, StageRecord
from pipelines.gpu_campaign.stages import (CAMPAIGN, STATE_FILE, STAGES, Campaign, SkipStage, StageFailed,
                                           check_command, check_work, check_work_owner, complete_scenes, new_state,
                                           read_state_doc)
#: The files a campaign writes in its output folder, besides the weights (weights*.pt).
OUT_FILES = ("summary.json", "logs.txt", "report.md")


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
    boxes = c.o.boxes
    least, most = boxes[name]
    if catch_up:
        most = min(most, c.p.catch_up_s.get(name, most))
    # the later stages' least boxes are kept for them, but for those that run only where time is left
    reserve = sum(boxes[s][0] for s in later if s not in c.o.optional)
    box = min(most, c.o.deadline_s - c.elapsed() - reserve)
    rec = StageRecord(name, log="logs.txt", started=_now(), part=c.o.part, time_box_s=round(box, 1))
    c.records[name] = rec
    outputs.atomic_write_text(c.log_path(name), f"stage {name}, started {rec.started}, time box {box:.0f} s\n")
    if box < least:
        kept = f" after the {reserve:.0f} s the later stages need" if reserve else ""
        rec.note = (f"not started: {max(box, 0):.0f} s left of the {c.o.deadline_s:.0f} s deadline{kept}, and it "
                    f"needs {least:.0f} s{' (it runs only where time is left)' if name in c.o.optional else ''}")
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
    try:
        doc = read_state_doc(o.work)  # a small regular file, bounded nesting
        if doc is None:
            return {}
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


def _load_run_token(o: Options) -> str | None:
    """The token state.json records for the training runs this campaign made in the work folder
    (kept with --fresh and across modes: it says whose run/ is, not what the stages measured)."""
    try:
        doc = read_state_doc(o.work)
    except ValueError:
        return None  # damaged: _load_state says so; a run folder can no longer be told ours
    token = doc.get("run_token") if doc is not None and doc.get("schema") == SCHEMA_VERSION else None
    return token if isinstance(token, str) and token else None


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
    return {"schema": SCHEMA_VERSION, "campaign": CAMPAIGN, "mode": c.p.name, "part": c.o.part,
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
    summary["files"] = [file_record(p) for p in sorted(out.iterdir())
                        if p.is_file() and p.name not in ("summary.json", LOCK_FILE)]  # the lock: this call's, removed at its end
    outputs.atomic_write_text(out / "summary.json", json.dumps(summary, indent=2, default=str) + "\n")
    outputs.atomic_write_text(outputs.writable(c.o.work, STATE_FILE), json.dumps(
        new_state(c.p.name, c.o.seed, c.run_token,
                  {s["name"]: s for s in summary["stages"] if s["name"] in c.records or s.get("started")}),
        indent=2, default=str))
    check_out(out)
    return summary


def run_campaign(options: Options, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Run the selected stages in order, each in its box; after each one, the outputs are
    rewritten whole, so what a killed call leaves in the output folder is complete up to there."""
    say = progress or (lambda text: None)
    out = options.out
    # before anything is written or removed: no link on the way to what the campaign writes under
    # --work, and no folder, FIFO or device where it keeps a file (state.json, a log)
    check_work(options.work)
    # nor a --work that holds the user's own state.json or logs, or lies in a dataset (round twelve:
    # they were replaced and deleted); nor an output folder in a dataset, which every command refuses
    check_work_owner(options.work)
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(out, flag="-o")
    from spikesim.generation.lock import output_lock
    # one call per --work at a time: two at once both finished, and one's stage record was lost
    # (round fourteen); the folder is made for the lock, and removed again if the call fails empty
    # and one call per -o: two calls with their own --work wrote one -o's summary, report and logs
    # (round fifteen)
    call = _call_line(options)
    with outputs.output_folder(options.work), output_lock(options.work, call, what="gpu-campaign call"), \
            outputs.output_folder(out), output_lock(out, call, what="gpu-campaign call"):
        return _run_locked(options, say)


def _call_line(options: Options) -> str:
    """The call as the --work lock records it for a second call's refusal."""
    return f"gpu-campaign --part {options.part} -o {options.out} --work {options.work}"


def _run_locked(options: Options, say: Callable[[str], None]) -> dict[str, Any]:
    out = options.out
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    if out.is_dir():
        ours = earlier_outputs(out)
        others = sorted(p.name for p in out.iterdir() if p not in ours and p.name != LOCK_FILE)  # LOCK_FILE: this call's
        if others:
            raise ValueError(f"--out {out} holds files this campaign did not write ({', '.join(others[:5])}"
                             f"{', ...' if len(others) > 5 else ''}): give an empty folder, or one an earlier "
                             "campaign filled (a lent machine returns at most 8 files)")
        for p in ours:  # an earlier call's results, weights above all, would mislead
            outputs.remove(out, p.name)
    options.work.mkdir(parents=True, exist_ok=True)
    c = Campaign(options)
    if not (options.work / STATE_FILE).exists():  # before the first log: a call killed in its first stage
        # leaves logs a later call can tell are the campaign's (check_work_owner)
        outputs.atomic_write_text(outputs.writable(options.work, STATE_FILE),
                                  json.dumps(new_state(options.profile.name, options.seed), indent=2))
    outputs.make_dirs(options.work, "logs")
    state = _load_state(options)
    c.run_token = _load_run_token(options)
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


__all__ = ["SCHEMA_VERSION", "OUT_FILES", "run_campaign", "summary_of", "write_outputs", "earlier_outputs"]
