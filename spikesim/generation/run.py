"""Resumable generation: run the jobs that are not done, then write the manifest.

A job is run by one process from start to end and its folder appears only when complete, with the
checksums of its files, so generation is resumable: a complete folder whose recorded job equals
the planned one (its parameters and the content of its inputs, spikesim.generation.inputs) and
whose files match its own checksums is skipped; a damaged one, or one whose inputs have changed
since, is rebuilt, with a line saying why; one from other parameters needs `overwrite_stale`. One run at a time writes an output folder (a lock
inside it), and nothing is written, deleted or read outside it. Jobs run in a local process pool
by default (spikesim.generation.pool), or as Ray tasks writing to a shared path;
spikesim.generation.job runs one job.
"""
from __future__ import annotations

import json
import logging
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from spikesim._drjit import resolve_device
from spikesim.config_io import parse_text
from spikesim.dataset import (MANIFEST, META, SATURATION_WARN_FRACTION, SATURATION_Y, check_scene,
                              drop_from_manifest, holds_only_scene_files, inside_root, manifest_disagreement,
                              read_manifest, remove_inside, scene_folders, scene_saturation, write_manifest)
from spikesim.generation.inputs import changes, job_inputs, legacy_changes
from spikesim.generation.lock import output_lock
from spikesim.generation.pace import Pace
from spikesim.generation.plan import SceneJob, power_label
from spikesim.signals import Terminated, sigterm_raises  # noqa: F401 (Terminated: re-exported for callers)

log = logging.getLogger("spikesim.generate")


# ---- resumable generation --------------------------------------------------------------------------
def scene_state(job: SceneJob, root: Path, full: bool = False,
                recorded: dict[str, Any] | None = None) -> tuple[str, list[str]]:
    """What the output holds for `job`, and why if it is to be rebuilt or refused:

    'todo'    no folder yet
    'done'    complete, the same job (the same parameters and inputs), every file matching the
              checksums recorded when it was written (sizes only unless `full`: then every sha256)
    'changed' complete, the same parameters, but a file it was made from (XML, mesh, texture,
              motion or light file, a generator's or the code's version) has other content now:
              rebuilt by a plain rerun; the reasons name what changed
    'stale'   complete, from other parameters (rebuilt only with --overwrite); the reasons name them
    'damaged' a file missing, truncated, altered (with `full`), meta.json or the record lost, or
              its checksum record differing from `recorded`, its entries in the manifest
    'foreign' something the generator did not write (never deleted)
    """
    folder = inside_root(root, job.name)  # a symlink leading out of the root is refused here
    given = root / job.name
    if not given.exists() and not given.is_symlink():
        return "todo", []
    if given.is_symlink() or not folder.is_dir() or not holds_only_scene_files(folder):
        return "foreign", []
    try:
        meta = parse_text((folder / META).read_text(), str(folder / META))
        digest = meta.get("job_digest")
    except (OSError, ValueError, AttributeError):
        meta, digest = {}, None  # missing or unreadable: the checksum record says which
    if digest is not None and digest != job.digest:
        state, reasons = _compare_with_record(job, meta, digest)
        if state != "done":
            return state, reasons
    problems = check_scene(root, job.name, checksums=full)
    if not problems and digest is None:
        problems = [f"{job.name}/{META}: records no job"]
    if not problems and recorded is not None:
        problems = manifest_disagreement(root, job.name, recorded)
    return ("damaged", problems) if problems else ("done", [])


def _compare_with_record(job: SceneJob, meta: dict[str, Any], digest: str) -> tuple[str, list[str]]:
    """Why a finished scene's recorded digest differs from the planned job's: 'stale' (other
    parameters, named), 'changed' (the same parameters, other inputs, named), or 'done' for a
    scene written before inputs were part of the identity whose recorded file hashes still match
    (spikesim.generation.inputs.legacy_changes)."""
    recorded = meta.get("job")
    if not isinstance(recorded, dict):
        return "stale", ["its meta.json records no job"]
    if "inputs" not in recorded:  # written before the inputs were part of the identity
        if digest != job.legacy_digest:
            return "stale", parameter_changes(recorded, job.parameters())
        source = meta.get("source") if isinstance(meta.get("source"), dict) else {}
        found = legacy_changes(job.source, source.get("sha256"), job_inputs(job.source, job.quality))
        if found is None:
            return "changed", ["its record does not say which files it was made from"]
        return ("changed", found) if found else ("done", [])
    params = {k: v for k, v in recorded.items() if k != "inputs"}
    if params != job.parameters() and _as_rendered(params) != job.parameters():
        return "stale", parameter_changes(params, job.parameters()) or ["its recorded job differs"]
    found = changes(recorded["inputs"] if isinstance(recorded["inputs"], dict) else {}, job.inputs)
    return ("changed", found) if found else ("stale", ["its recorded digest does not match its recorded job"])


def _as_rendered(params: dict[str, Any]) -> dict[str, Any]:
    """A recorded job with the render knobs of its quality in place of the planned ones: what a
    job records since it records the values its renderer was given. A scene generated with a
    quality before then is the same scene (the job applied the quality's knobs itself)."""
    quality = params.get("quality")
    if not isinstance(quality, str) or not isinstance(params.get("render"), dict):
        return params
    from spikesim.quality import QualitySettings
    try:
        knobs = QualitySettings.from_name(quality).render_kwargs()
    except ValueError:
        return params
    render = {**params["render"], **{k: v for k, v in knobs.items() if k in params["render"]}}
    return {**params, "render": render, "keyframe_every": knobs["keyframe_every"]}


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(d, dict):
        out: dict[str, Any] = {}
        for k, v in d.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: d}


def parameter_changes(recorded: dict[str, Any], planned: dict[str, Any], limit: int = 4) -> list[str]:
    """The parameters that differ, as "render.spp 2 -> 4" (at most `limit`, then a count)."""
    old, new = _flat(recorded), _flat(planned)
    keys = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]
    out = [f"{k} {json.dumps(old.get(k))} -> {json.dumps(new.get(k))}" for k in keys[:limit]]
    return out + ([f"{len(keys) - limit} more"] if len(keys) > limit else [])


def job_status(job: SceneJob, root: Path, full: bool = False) -> str:
    """'todo', 'done', 'changed', 'stale', 'damaged' or 'foreign' (see `scene_state`)."""
    return scene_state(job, Path(root), full)[0]


def _takes_name(job: SceneJob) -> bool:
    """Whether the job's folder name is the user's to choose: `generate scene --name` (a user
    scene); LLR and RLLR name their folders themselves (round seven: an RLLR conflict said --name)."""
    from scenes import SCENES
    return job.source.get("type") == "scene" and job.source.get("scene") not in SCENES


def _jobs_to_run(jobs: list[SceneJob], root: Path, overwrite_stale: bool, full: bool,
                 listed: dict[str, dict[str, Any]]) -> tuple[list[SceneJob], dict[str, str]]:
    """The jobs whose scene is missing, damaged or made from inputs that changed since (and, with
    `overwrite_stale`, from other parameters), and why each existing one is rebuilt; their old
    folders are removed, but only once every folder has been looked at, so a refusal (a folder it
    did not write, other parameters) leaves everything as it was. `listed`: the manifest's scenes,
    each checked against its entries there; a rebuilt scene is first dropped from the manifest."""
    states = {job.name: scene_state(job, root, full, listed.get(job.name)) for job in jobs}
    for name, (state, reasons) in states.items():
        if state == "foreign":
            raise FileExistsError(f"{root / name} exists but is not a scene folder this generator wrote "
                                  "(it holds other files or is a link); move it away or choose another output folder")
        if state == "stale" and not overwrite_stale:
            planned = next(job for job in jobs if job.name == name)
            recorded = _recorded_scene(root / name)
            if recorded is not None and recorded != _scene_identity(planned.to_dict()):
                raise FileExistsError(f"{root / name} holds another scene, {_scene_label(recorded)}, under the name "
                                      f"this run gives {_scene_label(_scene_identity(planned.to_dict()))}; write "
                                      "this run into another output folder (-o"
                                      f"{', or give it another --name' if _takes_name(planned) else ''}), or use "
                                      "--overwrite to replace it")
            raise FileExistsError(f"{root / name} was generated with other parameters ({'; '.join(reasons)}); "
                                  "use --overwrite to rebuild it, or another output folder")
    rebuilt = {}
    for name, (state, reasons) in states.items():
        if state == "damaged":
            rebuilt[name] = f"damaged ({'; '.join(reasons[:3])})"
        elif state == "changed":
            rebuilt[name] = ", ".join(reasons)
        elif state == "stale":
            rebuilt[name] = f"other parameters ({'; '.join(reasons)}), --overwrite"
        if name in rebuilt:
            log.warning("%s: %s, rebuilding", name, rebuilt[name])
    drop_from_manifest(root, [name for name, (state, _) in states.items() if state != "done"])
    for name in rebuilt:
        remove_inside(root, name)
    return [job for job in jobs if states[job.name][0] != "done"], rebuilt


def _scene_identity(job: dict[str, Any]) -> tuple[dict[str, Any], float] | None:
    """What makes a job another scene rather than the same scene with other settings: its source
    and its light power factor (None when the record lacks them)."""
    source, factor = job.get("source"), job.get("light_power_factor", 1.0)
    if not isinstance(source, dict) or not isinstance(factor, (int, float)):
        return None
    return source, float(factor)


def _recorded_scene(folder: Path) -> tuple[dict[str, Any], float] | None:
    """The scene a folder's meta.json records (`_scene_identity`), or None when unreadable."""
    try:
        job = parse_text((folder / META).read_text(), str(folder / META))["job"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return _scene_identity(job) if isinstance(job, dict) else None


def _scene_label(scene: tuple[dict[str, Any], float]) -> str:
    """A scene in a few words: its XML (or kind), light, files and power factor."""
    source, factor = scene
    power = f"power x{power_label(factor)}"
    if not source.get("scene"):  # a pattern or random scene: its few parameters
        return f"{json.dumps(source, sort_keys=True)} ({power})"
    extras = [f"{k} {source[k]}" for k in ("light", "motion", "lights") if source.get(k)]
    return f"{source['scene']} ({', '.join([*extras, power])})"


def _passing_scenes(root: Path, planned: list[str], full: bool, listed: dict[str, dict[str, Any]]) -> list[str]:
    """The scenes the manifest may list: every planned one (each must pass), and any other scene
    folder the manifest already lists (`listed`) that passes its own check and agrees with its
    entries there. A folder neither planned nor listed, such as a copy of a scene, is left out
    (with a warning): nothing vouches for it but its own record."""
    for name in planned:
        if problems := check_scene(root, name):
            raise RuntimeError(f"{name} failed its check right after it was generated: {'; '.join(problems[:3])}")
    others = []
    for name in scene_folders(root):
        if name in planned:
            continue
        if name not in listed:
            log.warning("%s is a scene folder that this run did not plan and %s does not list%s: left out of the "
                        "manifest (run the command that made it to add it)", name, MANIFEST, _copy_hint(root, name))
        elif problems := (check_scene(root, name, checksums=full) or manifest_disagreement(root, name, listed[name])):
            log.warning("%s is not planned here and fails its check (%s): left out of the manifest",
                        name, "; ".join(problems[:3]))
        else:
            others.append(name)
    return planned + others


def _copy_hint(root: Path, name: str) -> str:
    """" (a copy of X?)" when the folder's meta.json names another scene."""
    try:
        recorded = parse_text(inside_root(root, name, META).read_text(), META).get("name")
    except (OSError, ValueError, AttributeError):
        return ""
    return f" (its {META} names {recorded}: a copy?)" if isinstance(recorded, str) and recorded != name else ""


def _make_root(root: Path) -> list[Path]:
    """Create the output root and its missing parents; returns the folders created, deepest
    first, so that a run that fails can remove them again if it left them empty."""
    created = []
    p = root.absolute()
    while not p.exists() and not p.is_symlink() and p != p.parent:
        created.append(p)
        p = p.parent
    root.mkdir(parents=True, exist_ok=True)
    return created


def _remove_if_empty(folders: list[Path]) -> None:
    for folder in folders:  # deepest first
        try:
            folder.rmdir()
        except OSError:
            return  # not empty (finished scenes are kept), or not ours to remove


def _remove_debris(root: Path, jobs: list[SceneJob]) -> None:
    """The work and part folders of `jobs` (their workers have ended): what a stopped worker
    could not clean up itself."""
    for job in jobs:
        for name in (f".{job.name}.work", f".{job.name}.part"):
            try:
                remove_inside(root, name)
            except (OSError, ValueError) as exc:
                log.warning("could not remove %s: %s", root / name, exc)


def generate(jobs: list[SceneJob], root: str | Path, workers: int | None = None, ray_address: str | None = None,
             info: dict[str, Any] | None = None, overwrite_stale: bool = False, show_progress: bool = True,
             check: bool = False, command: str | None = None, device: str = "auto",
             estimate_time: bool | None = None, estimate_scenes: int | None = None) -> dict[str, Any]:
    """Run the jobs that are not done yet, then write the manifest from the scenes that pass their
    checks. `check` hashes every file of the finished scenes (default: sizes only). Returns a report.

    The output root is locked for the run (`command` is recorded for a second run's error); an
    existing manifest.json that this package did not write is refused, not overwritten. A run that
    fails removes the output folder again if it created it and left nothing in it; SIGTERM stops
    it like Ctrl-C (`Terminated`): the scenes in progress are removed, finished ones kept.

    Before the jobs start it logs the renders planned and, for a plan of ESTIMATE_MIN_RENDERS or more
    (estimate_time None), always (True) or never (False), a time estimate from a calibration on the
    first job (spikesim.generation.estimate), reading up to `estimate_scenes` scenes (None: its default)."""
    root = Path(root)
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise ValueError("two jobs share a scene name")
    if workers is not None and workers < 1:
        raise ValueError(f"workers={workers}: needs at least 1 (None: one per core)")
    created = _make_root(root)
    try:
        with sigterm_raises(), output_lock(root, command or shlex.join(sys.argv)):
            listed: dict[str, dict[str, Any]] = {}
            recorded_jobs: dict[str, Any] = {}
            if (root / MANIFEST).exists() or (root / MANIFEST).is_symlink():
                previous = read_manifest(root)
                listed = previous["scenes"]
                was, now = previous.get("kind"), (info or {}).get("kind")
                if listed and was is not None and now is not None and was != now:
                    # an LLR scene added to an RLLR dataset relabelled it, and training then took test scenes
                    raise ValueError(f"{root} is a {was} dataset ({len(listed)} scene(s)); generate {now} would add "
                                     f"{now} scenes to it: write them to another -o")
                if isinstance(previous.get("jobs"), dict):
                    recorded_jobs = previous["jobs"]
            todo, rebuilt = _jobs_to_run(jobs, root, overwrite_stale, check, listed)
            log.info("%d scene(s) planned, %d already complete, %d to generate in %s",
                     len(jobs), len(jobs) - len(todo), len(todo), root)
            estimated: dict[str, float] = {}
            processes = 1 if ray_address is not None else local_workers(todo, workers, device)
            if todo and estimate_time is not False and ray_address is None:
                from spikesim.generation.estimate import estimate
                est = estimate(todo, processes, device,
                               calibrate_at=0 if estimate_time else None, sample_scenes=estimate_scenes)
                log.info("%s", est.summary())
                estimated = dict(est.job_seconds)
            pace = Pace(len(todo), processes, estimated)
            t0 = time.perf_counter()
            results = _run_jobs(todo, root, workers, ray_address, show_progress, device,
                                on_done=lambda result: log.info("%s", pace.finished(result)))
            fresh = {j.name for j in todo}
            kept = {name: entries for name, entries in listed.items() if name not in fresh}
            listing = _passing_scenes(root, names, check, kept)
            # every listed scene's job, from whichever run made it: this run's, and earlier runs'
            jobs_record = {name: recorded_jobs[name] for name in listing if name in recorded_jobs}
            jobs_record.update({j.name: j.digest for j in jobs})
            manifest = write_manifest(root, {**(info or {}), "jobs": dict(sorted(jobs_record.items()))},
                                      scenes=listing, recorded=kept)
    except BaseException:
        _remove_if_empty(created)
        raise
    saturation = {name: scene_saturation(root, name) for name in names}
    _warn_saturated(saturation)
    for r in results:
        if r["name"] in rebuilt:
            r["rebuilt"] = rebuilt[r["name"]]
    return {"root": str(root), "generated": results, "skipped": len(jobs) - len(todo), "rebuilt": rebuilt,
            "checked": "sha256" if check else "sizes",
            "seconds": time.perf_counter() - t0, "manifest": str(manifest), "saturation": saturation}


def local_workers(todo: Sequence[SceneJob], workers: int | None, device: str) -> int:
    """The processes a local run uses: as asked, else one per core; one process feeds a GPU best."""
    if workers is not None:
        return workers
    return 1 if resolve_device(device) == "cuda" else max(1, min(len(todo), os.cpu_count() or 1))


def _run_jobs(todo: list[SceneJob], root: Path, workers: int | None, ray_address: str | None, show_progress: bool,
              device: str, on_done: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
    """Run `todo` locally or on Ray, calling `on_done(result)` as each job finishes; on any failure,
    once the local workers have ended, what the unfinished jobs left behind is removed."""
    if not todo:
        return []
    from spikesim.generation.pool import generate_local, generate_ray
    if ray_address is not None:  # tasks on other machines cannot be stopped from here: each cleans up itself
        return generate_ray(todo, root, ray_address, show_progress, device, on_done=on_done)
    workers = local_workers(todo, workers, device)
    try:
        return generate_local(todo, root, workers, show_progress, device, on_done=on_done)
    except BaseException:
        _remove_debris(root, [j for j in todo if not (root / j.name).exists()])
        raise


def _warn_saturated(saturation: dict[str, float | None]) -> None:
    """A warning for each scene whose ground truth lies above the sensor's saturation in more than
    SATURATION_WARN_FRACTION of its pixels: targets no spike stream can show (model/data.py clips
    them; docs/model.md)."""
    for name, fraction in saturation.items():
        if fraction is not None and fraction > SATURATION_WARN_FRACTION:
            log.warning("%s: %.1f %% of its ground-truth pixels are above the sensor's saturation (y > %g spike "
                        "per step), more than %g %%: its light is brighter than the camera can show",
                        name, 100 * fraction, SATURATION_Y, 100 * SATURATION_WARN_FRACTION)


def percent(fraction: float | None) -> str:
    return "n/a" if fraction is None else f"{100 * fraction:.2f} %"


def saturation_summary(saturation: dict[str, float | None]) -> str | None:
    """One line on the ground truth above the sensor's saturation, over the dataset's scenes; None
    when no pixel of any scene is above it (nothing to say)."""
    known = {k: v for k, v in saturation.items() if v is not None}
    if not known:
        return "ground truth above saturation: not recorded (scenes written before it was)"
    if max(known.values()) == 0:
        return None
    over = sorted((k for k, v in known.items() if v > SATURATION_WARN_FRACTION), key=lambda k: -known[k])
    worst = max(known, key=lambda k: known[k])
    text = (f"ground truth above saturation (y > {SATURATION_Y:g}): mean {percent(float(np.mean(list(known.values()))))} "
            f"of pixels over {len(known)} scene(s), most {percent(known[worst])} ({worst}); "
            f"{len(over)} scene(s) above {100 * SATURATION_WARN_FRACTION:g} %")
    return text + (f": {', '.join(over[:10])}{' ...' if len(over) > 10 else ''}" if over else "")
