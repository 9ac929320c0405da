"""A `render -o D` folder holds one run: its record, D/render.json, lists every file the run
wrote (`files`), and a rerun replaces exactly those. A file in the output subfolders that no record
lists (frames of an earlier version's run, or the user's own) makes a rerun refuse, naming it,
rather than leave it beside the new frames; `simulate --frames D` reads only the frames the
record lists.

Records written before `files` existed list their `kind` and `steps`, from which the files they
wrote follow (`recorded_files`).
"""
from __future__ import annotations

import json
import logging
import os
import re
import shutil
from pathlib import Path
from typing import Any

from spikesim.outputs import atomic_write_text, make_dirs, remove, writable, writing

log = logging.getLogger("spikesim.render")

RECORD = "render.json"
KINDS = ("frames", "gt", "preview")
"""The subfolders a render writes, one per kind of output."""


def read_record(folder: Path) -> dict[str, Any] | None:
    """The render record in `folder`, or None when there is none; a ValueError naming it when it
    cannot be read."""
    path = Path(folder) / RECORD
    if not path.exists() and not path.is_symlink():
        return None
    from spikesim.config_io import read_json_file
    try:
        data = read_json_file(path, "render record", finite=False)
    except ValueError as exc:  # not JSON, not a regular file (a FIFO), too large
        reason = str(exc).replace(f"render record {path} ", "", 1)
        raise ValueError(f"{path}: not a render record ({reason}); remove it, with the frames beside it, "
                         "or choose another folder") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a render record (a JSON {type(data).__name__})")
    return data


def recorded_files(record: dict[str, Any] | None) -> list[str]:
    """The files (relative to the folder) a record lists: its `files`, or for a record written
    before it listed them, the files its kind and steps imply."""
    if record is None:
        return []
    files = record.get("files")
    if isinstance(files, list):
        return [f for f in files if isinstance(f, str)]
    kind, steps = record.get("kind"), record.get("steps")
    if kind not in KINDS or not isinstance(steps, list):
        return []
    suffixes = (".png",) if kind == "preview" else (".exr", ".png")
    return [f"{kind}/step_{int(n):06d}{s}" for n in steps for s in suffixes if isinstance(n, int)]


def _output_files(folder: Path) -> list[str]:
    """Every entry in the folder's output subfolders, relative to the folder."""
    out = []
    for kind in KINDS:
        sub = folder / kind
        if sub.is_dir() and not sub.is_symlink():
            out += [f"{kind}/{p.name}" for p in sorted(sub.iterdir())]
        elif sub.exists() or sub.is_symlink():
            out.append(kind)
    return out


def check_output_folder(folder: Path) -> list[str]:
    """Before a render writes into `folder`: the files of the previous run there (which the new
    run replaces), or a ValueError naming the files its record does not list (they would end up
    beside the new ones, and `simulate --frames` would mix them in)."""
    folder = Path(folder)
    for name in (RECORD, *KINDS):  # a link where a render writes: refused, naming it, never followed
        writable(folder, name)
    listed = recorded_files(read_record(folder))
    for rel in listed:  # what a rerun replaces or deletes: a record naming `..` or a link is refused
        writable(folder, rel)
    unlisted = [f for f in _output_files(folder) if f not in set(listed)]
    if unlisted:
        shown = ", ".join(unlisted[:3]) + (f" and {len(unlisted) - 3} more" if len(unlisted) > 3 else "")
        whose = f"its {RECORD} does not list" if (folder / RECORD).exists() else f"no {RECORD} lists"
        raise ValueError(f"{folder}: holds {len(unlisted)} file(s) that {whose} ({shown}): frames of another run "
                         "or your own files; a render folder holds one run, so remove them or choose another -o")
    return listed


def replace_outputs(stage: Path, folder: Path, new: list[str], old: list[str], record: dict[str, Any]) -> None:
    """Move a finished run's files from `stage` into `folder`, write its record, then remove what
    the previous run wrote that this one did not (so the folder and its record describe this run).
    Every path is checked first: inside `folder`, no link on the way (spikesim.outputs)."""
    stale = sorted(set(old) - set(new))
    for rel in (*new, *stale, RECORD):
        writable(folder, rel)
    for rel in new:
        make_dirs(folder, Path(rel).parent)
        with writing(folder / rel):
            os.replace(stage / rel, writable(folder, rel))
    from spikesim.dataset import sha256_file
    # each EXR frame's sha256: frames swapped or altered after the render were simulated, rc 0 (round nine)
    digests = {rel: sha256_file(folder / rel) for rel in sorted(new) if rel.endswith(".exr")}
    atomic_write_text(writable(folder, RECORD), json.dumps({**record, "files": sorted(new), "sha256": digests},
                                                           indent=2, default=str) + "\n")
    for rel in stale:
        remove(folder, rel)
    for kind in KINDS:
        try:
            writable(folder, kind).rmdir()  # a kind this run did not write
        except (OSError, ValueError):
            pass
    if stale:
        log.info("%s: removed %d file(s) of the previous render (its %s listed them)", folder, len(stale), RECORD)


def remove_stage(stage: Path) -> None:
    shutil.rmtree(stage, ignore_errors=True)


#: The camera fields a render's y depends on (y = electrons per readout period / threshold), as its
#: record's exposure gives them: a stream simulated with others is brighter or darker or faster
#: than the render meant (round eight: the period; round nine: the threshold).
RENDER_CAMERA_FIELDS = ("readout_period_s", "threshold_electrons")


def recorded_camera_fields(folder: Path) -> dict[str, float]:
    """The camera fields (RENDER_CAMERA_FIELDS) a render folder's frames were made for, from its
    record's exposure (the folder itself or a kind subfolder of one); empty for a folder of the
    user's own EXRs."""
    folder = Path(folder)
    base = folder if (folder / RECORD).is_file() else folder.parent if (folder.parent / RECORD).is_file() else None
    if base is None:
        return {}
    exposure = (read_record(base) or {}).get("exposure")
    if not isinstance(exposure, dict):
        return {}
    return {k: float(v) for k in RENDER_CAMERA_FIELDS if isinstance(v := exposure.get(k), (int, float))
            and not isinstance(v, bool) and v > 0}


def natural_key(name: str) -> tuple:
    """Sort key of a file name with the numbers in it compared as numbers: frame_2.exr before
    frame_10.exr (as text, frame_10 came first: round eleven). The name itself breaks ties
    (frame_01 and frame_1)."""
    parts = re.split(r"(\d+)", name)
    return tuple(int(p) if i % 2 else p for i, p in enumerate(parts)) + (name,)


def listed_frames(folder: Path, keyframe_every: int) -> list[Path] | None:
    """The EXR frames `simulate --frames folder` reads when `folder` is a render folder (holding
    render.json) or a kind subfolder of one: only those its record lists, in step order, checked
    to be steps `keyframe_every` apart. None when no render record covers the folder (a folder of
    the user's own EXR frames)."""
    folder = Path(folder)
    if (folder / RECORD).is_file():
        base, record = folder, read_record(folder)
    elif folder.name in KINDS and (folder.parent / RECORD).is_file():
        base, record = folder.parent, read_record(folder.parent)
    else:
        return None
    kind = record.get("kind")
    if kind == "preview":
        raise ValueError(f"{base}: its render wrote RGB previews (PNG), not y frames; render with --variant mono or "
                         "spectral")
    wanted = folder.name if base != folder else kind
    files = [f for f in recorded_files(record) if f.endswith(".exr") and f.startswith(f"{wanted}/")]
    if not files:
        raise ValueError(f"{folder}: its {RECORD} lists no EXR frames here (its render wrote {kind})")
    on_disk = {f"{wanted}/{p.name}" for p in (base / wanted).glob("*.exr")}
    if ignored := sorted(on_disk - set(files)):
        log.warning("%s: %d EXR file(s) its %s does not list are ignored (%s)", base / wanted, len(ignored), RECORD,
                    ", ".join(ignored[:3]))
    steps = record.get("steps")
    if isinstance(steps, list) and len(steps) > 1 and all(isinstance(n, int) for n in steps):
        gaps = {b - a for a, b in zip(sorted(steps), sorted(steps)[1:])}
        if len(gaps) != 1:
            raise ValueError(f"{base}: its frames are steps {sorted(steps)[:5]}..., not evenly spaced; simulate needs "
                             "frames one step (or --keyframe-every steps) apart")
        if (gap := gaps.pop()) != keyframe_every:
            raise ValueError(f"{base}: its frames are steps {gap} apart ({RECORD}); give --keyframe-every {gap}")
    # every frame must have its digest: a record with "sha256": {} (or none) let swapped frames through,
    # rc 0 (round ten); a record of a render before round nine, which wrote none, is re-rendered
    digests = record.get("sha256")
    digests = digests if isinstance(digests, dict) else {}
    if missing := [f for f in sorted(files) if not isinstance(digests.get(f), str)]:
        raise ValueError(f"{base / RECORD}: records no sha256 of {missing[0]}"
                         f"{f' and {len(missing) - 1} more frame(s)' if len(missing) > 1 else ''}, so the frames "
                         "cannot be checked to be the render's: the record is damaged or from an older version; "
                         "render again")
    from spikesim.dataset import sha256_file
    for f in sorted(files):
        if sha256_file(base / f) != digests[f]:
            raise ValueError(f"{base / f}: not the frame the render wrote (its sha256 differs from {RECORD}'s): "
                             "swapped or altered; render again")
    # in the record's step order, numbers compared as numbers: sorted as text, step_1000000.exr came before
    # step_999960.exr and the stream was silently reordered, rc 0 (round eleven)
    step_of = {f"{wanted}/step_{n:06d}.exr": n for n in (steps if isinstance(steps, list) else [])
               if isinstance(n, int) and not isinstance(n, bool)}
    if all(f in step_of for f in files):
        ordered = sorted(files, key=lambda f: step_of[f])
    else:  # a file named otherwise: the numbers in the names, compared as numbers
        ordered = sorted(files, key=natural_key)
    return [base / f for f in ordered]


__all__ = ["RECORD", "KINDS", "read_record", "recorded_files", "check_output_folder", "replace_outputs",
           "listed_frames", "natural_key", "remove_stage"]
