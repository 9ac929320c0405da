"""The on-disk layout of a spike dataset (LLR, RLLR or a user's own), and its integrity checks.

    <root>/manifest.json                 name, preset, and per scene: files with bytes + sha256
    <root>/<scene>/spikes.dat            the stream, PKU .dat (flipped: the real-camera convention)
    <root>/<scene>/meta.json             camera, seed, geometry, num_steps, flip, gt_steps, windows,
                                         light and every other parameter needed to reproduce it
    <root>/<scene>/gt/step_{n:06d}.exr   ground truth y at step n (linear float32)

A scene folder is built under a temporary name and renamed when complete, so a folder with the
scene's name is always whole: an interrupted generation resumes by skipping complete scenes.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from .imageio import read_exr, write_exr
from .stream import DatReader, SpikeStream, write_dat

MANIFEST = "manifest.json"
SPIKES = "spikes.dat"
META = "meta.json"
GT_DIR = "gt"
LAYOUT_VERSION = 1


def gt_name(step: int) -> str:
    return f"step_{int(step):06d}.exr"


def sha256_file(path: Path, block: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


def _write_json(path: Path, data: Any) -> None:
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)


@dataclass
class SceneRecord:
    """One scene of a dataset, read lazily (spikes memory-mapped, ground truth on demand)."""

    path: Path
    meta: dict[str, Any]
    _reader: DatReader | None = field(default=None, repr=False)

    @classmethod
    def open(cls, path: str | Path) -> "SceneRecord":
        path = Path(path)
        meta_path = path / META
        if not meta_path.exists():
            raise FileNotFoundError(f"{path} is not a scene folder: {META} is missing")
        try:
            meta = json.loads(meta_path.read_text())
        except ValueError as exc:
            raise ValueError(f"{meta_path} is not valid JSON: {exc}") from exc
        for key in ("height", "width", "num_steps", "gt_steps", "flip"):
            if key not in meta:
                raise ValueError(f"{meta_path}: required key {key!r} is missing")
        return cls(path=path, meta=meta)

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def height(self) -> int:
        return int(self.meta["height"])

    @property
    def width(self) -> int:
        return int(self.meta["width"])

    @property
    def num_steps(self) -> int:
        return int(self.meta["num_steps"])

    @property
    def gt_steps(self) -> list[int]:
        return [int(s) for s in self.meta["gt_steps"]]

    @property
    def reader(self) -> DatReader:
        if self._reader is None:
            self._reader = DatReader(self.path / SPIKES, self.height, self.width, flip=bool(self.meta["flip"]))
            if self._reader.num_steps != self.num_steps:
                raise ValueError(f"{self.path / SPIKES}: {self._reader.num_steps} frames, meta.json says {self.num_steps}")
        return self._reader

    def stream(self, start: int = 0, stop: int | None = None) -> SpikeStream:
        return self.reader.read(start, stop)

    def spikes(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Frames [start, stop) as bool (n, H, W)."""
        return self.reader.read(start, stop).unpack()

    def ground_truth(self, step: int) -> np.ndarray:
        if int(step) not in set(self.gt_steps):
            raise KeyError(f"scene {self.name} has no ground truth at step {step}")
        return read_exr(self.path / GT_DIR / gt_name(step))


def write_scene(root: str | Path, name: str, stream: SpikeStream | Path, ground_truth: dict[int, np.ndarray] | Iterable[tuple[int, np.ndarray]],
                meta: dict[str, Any], flip: bool = True) -> SceneRecord:
    """Write a complete scene folder atomically (built as `.<name>.part`, then renamed).

    `stream` is either a SpikeStream or the path of an already written `.dat` (moved in).
    """
    root = Path(root)
    final = root / name
    if final.exists():
        raise FileExistsError(f"scene folder {final} already exists")
    tmp = root / f".{name}.part"
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / GT_DIR).mkdir(parents=True)
    try:
        if isinstance(stream, SpikeStream):
            write_dat(tmp / SPIKES, stream, flip=flip)
            h, w, n = stream.height, stream.width, stream.num_steps
        else:
            os.replace(stream, tmp / SPIKES)
            if "height" not in meta or "width" not in meta:
                raise ValueError(f"scene {name}: meta needs 'height' and 'width' when the stream is a file")
            h, w = int(meta["height"]), int(meta["width"])
            n = DatReader(tmp / SPIKES, h, w, flip=flip).num_steps
        items = ground_truth.items() if isinstance(ground_truth, dict) else ground_truth
        steps = []
        for step, img in items:
            if np.asarray(img).shape != (h, w):
                raise ValueError(f"scene {name}: ground truth at step {step} has shape {np.asarray(img).shape}, stream is {h}x{w}")
            if not 0 <= int(step) < n:
                raise ValueError(f"scene {name}: ground truth step {step} outside the stream's {n} steps")
            write_exr(tmp / GT_DIR / gt_name(step), img)
            steps.append(int(step))
        full_meta = {**meta, "name": name, "height": h, "width": w, "num_steps": n, "flip": flip,
                     "gt_steps": sorted(steps), "layout_version": LAYOUT_VERSION}
        _write_json(tmp / META, full_meta)
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return SceneRecord.open(final)


def scene_files(scene_dir: Path) -> dict[str, dict[str, Any]]:
    out = {}
    for p in sorted(scene_dir.rglob("*")):
        if p.is_file() and not p.name.startswith("."):
            out[p.relative_to(scene_dir.parent).as_posix()] = {"bytes": p.stat().st_size, "sha256": sha256_file(p)}
    return out


def write_manifest(root: str | Path, info: dict[str, Any] | None = None) -> Path:
    """(Re)write the dataset manifest from the complete scene folders present."""
    root = Path(root)
    scenes = {}
    for d in sorted(root.iterdir()):
        if d.is_dir() and not d.name.startswith(".") and (d / META).exists():
            scenes[d.name] = scene_files(d)
    data = {**(info or {}), "layout_version": LAYOUT_VERSION, "scenes": scenes,
            "total_bytes": sum(f["bytes"] for files in scenes.values() for f in files.values())}
    _write_json(root / MANIFEST, data)
    return root / MANIFEST


def read_manifest(root: str | Path) -> dict[str, Any]:
    path = Path(root) / MANIFEST
    if not path.exists():
        raise FileNotFoundError(f"{root} has no {MANIFEST}: not a dataset, or its generation did not finish")
    return json.loads(path.read_text())


def verify(root: str | Path, checksums: bool = True) -> list[str]:
    """Compare a dataset with its manifest; returns the problems found (empty: intact)."""
    root = Path(root)
    manifest = read_manifest(root)
    problems = []
    for scene, files in manifest["scenes"].items():
        if not (root / scene).is_dir():
            problems.append(f"{scene}: scene folder missing")
            continue
        for rel, want in files.items():
            p = root / rel
            if not p.exists():
                problems.append(f"{rel}: missing")
            elif p.stat().st_size != want["bytes"]:
                problems.append(f"{rel}: {p.stat().st_size} bytes, manifest says {want['bytes']} (truncated or altered)")
            elif checksums and sha256_file(p) != want["sha256"]:
                problems.append(f"{rel}: checksum differs from the manifest (altered)")
    return problems


def open_dataset(root: str | Path) -> list[SceneRecord]:
    """All complete scenes under `root` (a manifest is not required to read)."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"dataset folder {root} does not exist")
    scenes = [SceneRecord.open(d) for d in sorted(root.iterdir())
              if d.is_dir() and not d.name.startswith(".") and (d / META).exists()]
    if not scenes:
        raise FileNotFoundError(f"{root} holds no scene folders (each needs {META})")
    return scenes


__all__ = ["SceneRecord", "write_scene", "write_manifest", "read_manifest", "verify", "open_dataset",
           "gt_name", "MANIFEST", "SPIKES", "META", "GT_DIR"]
