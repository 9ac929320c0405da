"""What a scene job is made from, and the sha256 of each: the one place that decides what a
scene's identity covers (`SceneJob.digest`) and what its meta.json records about its inputs.

- A scene from files (a bundled LLR scene or the user's own): the XML, its motion and light files,
  and every mesh, texture or spectrum file the XML references (resolved relative to the XML), each
  by the sha256 of its bytes, so an edited reflectance, lamp power or rpm is another scene even
  under the same file names.
- An RLLR random scene: it is built by code (scenes/random_scene.py) from the seed its job
  records, so no file exists before the job runs; its input is that generator's version
  (`scenes.random_scene.GENERATOR_VERSION`), raised whenever a change of the generator builds
  another scene from the same seed.
- The built-in pattern: nothing but the job's own parameters.
- A job with a quality preset (`--quality`): the preset's settings, by the sha256 of their
  record, so a version whose preset chooses other samples (the `fast` rule) rebuilds its scenes.
- Every job: the version of the code that turns a job into bytes (`DATA_VERSION`) and the dataset
  layout (`spikesim.dataset.LAYOUT_VERSION`).

The camera, render settings, windows, seed and light power factor are the job's parameters
(`SceneJob.to_dict`), compared by value; a changed parameter needs `--overwrite`, a changed input
is rebuilt by a plain rerun (spikesim.generation.run).

Inputs are named as a person finds them: relative to the scene XML's folder (`scene.xml`,
`lights.json`, `textures/desk.jpg`), or by absolute path for a file outside it.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from spikesim.dataset import LAYOUT_VERSION, sha256_file

DATA_VERSION = 3
"""The version of the code that turns a job into bytes (renderer, sensor, seeds, layout of a
scene folder). Raise it when a change makes the same job write other bytes: every scene is then
rebuilt once by the next rerun, and says why. 2: the per-step shot and comparator normals are
drawn from Philox counted by (pixel, step) (spikesim/philox.py), bit-identical on every backend.
3: a ground-truth image's gt_spp are its samples in all, spread over its motion-blur sub-step
renders (spikesim.render.renderer.samples_per_substep), not each render's; only ground truth at
steps that move past the blur threshold changes."""

CODE_INPUT = "spikesim"
"""The name of the code's entry among a job's inputs."""


@dataclass(frozen=True)
class JobInput:
    """One thing a job is made from."""

    name: str
    """How a person finds it: a path relative to the scene XML's folder, an absolute path for a
    file outside it, or the name of the code that builds it."""
    role: str
    """"xml", "motion", "lights", "file" (referenced by the XML), "generator", "quality" or "code"."""
    identity: str
    """The sha256 of a file's bytes, or "version N" for code."""
    path: str | None = None
    bytes: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if v is not None}


def code_input() -> JobInput:
    return JobInput(CODE_INPUT, "code", f"data version {DATA_VERSION}, layout {LAYOUT_VERSION}")


def _file_input(path: Path, base: Path, role: str) -> JobInput:
    path = Path(path).resolve()
    name = path.relative_to(base).as_posix() if path.is_relative_to(base) else str(path)
    return JobInput(name, role, sha256_file(path), str(path), path.stat().st_size)


def scene_file_inputs(scene: str, motion: str | None = None, lights: str | None = None) -> list[JobInput]:
    """The XML (a bundled scene's name or a path), its motion and light files (given, or the
    defaults beside the XML) and every file the XML references, each with its sha256; a
    SceneError (a ValueError naming the file) when one is missing."""
    from spikesim.render.scene_files import SceneFiles, referenced_files

    files = SceneFiles.resolve(scene, motion=motion, lights=lights)
    base = files.xml.parent.resolve()
    out = [_file_input(files.xml, base, "xml")]
    out += [_file_input(getattr(files, role), base, role) for role in ("motion", "lights")
            if getattr(files, role) is not None]
    out += [_file_input(path, base, "file") for _, path in referenced_files(files.xml)]
    seen: set[str] = set()
    return [i for i in out if not (i.name in seen or seen.add(i.name))]


def quality_input(quality: str) -> JobInput:
    """A quality preset by the sha256 of its settings (rule included): a version whose preset
    chooses other samples or terms makes other bytes from the same job, so the job's scenes are
    rebuilt, with the reason "quality fast changed"."""
    from spikesim.quality import QualitySettings
    text = json.dumps(QualitySettings.from_name(quality).to_dict(), sort_keys=True, default=str)
    return JobInput(f"quality {quality}", "quality", hashlib.sha256(text.encode()).hexdigest()[:16])


def job_inputs(source: dict[str, Any], quality: str | None = None) -> list[JobInput]:
    """Everything a job with this `source` (SceneJob.source) and `quality` is made from, with its
    sha256 or version (see the module's docstring)."""
    kind = source.get("type")
    if kind == "scene":
        out = scene_file_inputs(source["scene"], source.get("motion"), source.get("lights"))
    elif kind == "random" and source.get("content", "procedural") == "natural":
        from scenes.natural_scene import NATURAL_GENERATOR_VERSION
        from scenes.natural_textures import photo_version
        out = [JobInput("scenes/natural_scene.py", "generator",
                        f"version {NATURAL_GENERATOR_VERSION}, scikit-image {photo_version()}")]
    elif kind == "random":
        from scenes.random_scene import GENERATOR_VERSION
        out = [JobInput("scenes/random_scene.py", "generator", f"version {GENERATOR_VERSION}")]
    elif kind == "photo":
        from scenes.natural_textures import photo_version
        from scenes.photo_pan import PHOTO_PAN_VERSION
        out = [JobInput("scenes/photo_pan.py", "generator",
                        f"version {PHOTO_PAN_VERSION}, scikit-image {photo_version()}")]
    elif kind == "pattern":
        out = []
    else:
        raise ValueError(f"job source type {kind!r}; expected 'scene', 'random', 'photo' or 'pattern'")
    return [*out, *([quality_input(quality)] if quality is not None else []), code_input()]


def identities(inputs: Iterable[JobInput]) -> dict[str, str]:
    """{name: sha256 or version}: the part of the inputs that is the job's identity (paths and
    sizes are not: a bundled scene is the same scene in every checkout)."""
    return {i.name: i.identity for i in inputs}


def changes(recorded: dict[str, str], planned: dict[str, str]) -> list[str]:
    """What differs between two inputs' identities, in words: "lights.json changed",
    "textures/new.png added", "meshes/old.ply no longer used"."""
    out = []
    for name in sorted(set(recorded) | set(planned), key=lambda n: (n == CODE_INPUT, n)):
        old, new = recorded.get(name), planned.get(name)
        if old == new:
            continue
        if old is None:
            out.append(f"{name} added")
        elif new is None:
            out.append(f"{name} no longer used")
        elif not _is_sha256(old) or not _is_sha256(new):
            out.append(f"{name} changed ({old} -> {new})")
        else:
            out.append(f"{name} changed")
    return out


def _is_sha256(text: str) -> bool:
    return len(text) == 64 and all(c in "0123456789abcdef" for c in text)


def legacy_changes(source: dict[str, Any], recorded_sha256: Any, planned: list[JobInput]) -> list[str] | None:
    """For a scene written before its inputs were recorded (its meta.json's source has only the
    sha256 of its XML, motion and light files): what differs from the planned inputs in those
    three, or None when the record cannot tell (then the scene is rebuilt). Meshes and textures
    were not recorded then, so they cannot be compared."""
    if source.get("type") != "scene":
        return []
    if not isinstance(recorded_sha256, dict):
        return None
    now = {i.role: i for i in planned if i.role in ("xml", "motion", "lights")}
    out = []
    for role in ("xml", "motion", "lights"):
        old, new = recorded_sha256.get(role), now.get(role)
        if old is None and new is None:
            continue
        if new is None:
            out.append(f"its {role} file no longer used")
        elif old != new.identity:
            out.append(f"{new.name} {'added' if old is None else 'changed'}")
    return out


__all__ = ["JobInput", "job_inputs", "scene_file_inputs", "identities", "changes", "legacy_changes",
           "DATA_VERSION", "CODE_INPUT", "code_input"]
