"""The on-disk layout of a spike dataset (LLR, RLLR or a user's own), and its integrity checks.

    <root>/manifest.json                 name, preset, and per scene: files with bytes + sha256, and
                                         the share of ground-truth pixels above saturation
    <root>/.spikesim.lock                held by the `generate` run writing here (pid, command);
                                         removed when that run ends
    <root>/<scene>/spikes.dat            the stream, PKU .dat (flipped: the real-camera convention)
    <root>/<scene>/meta.json             camera, seed, geometry, num_steps, flip, gt_steps, windows,
                                         light and every other parameter needed to reproduce it;
                                         gt_saturation: the share of ground-truth pixels above
                                         SATURATION_Y (y = 1), counted when written;
                                         inputs: what it was made from (XML, meshes, textures,
                                         motion and light files, a generator), with sha256
    <root>/<scene>/gt/step_{n:06d}.exr   ground truth y at step n (linear float32)
    <root>/<scene>/checksums.json        bytes + sha256 of each file above, recorded when written

A scene folder is built under a temporary name and renamed when complete, so a folder with the
scene's name is always whole: an interrupted generation resumes by skipping complete scenes. Each
scene carries its own checksums, so a resume can tell a damaged scene from a finished one without
trusting (or rewriting) the manifest from the files as they are now.

Scene names are plain folder names, and every path written, deleted or read under a root goes
through `inside_root`: neither a name, nor a manifest entry, nor a symlink can lead outside it.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence, TypeVar

import numpy as np

from . import outputs
from .imageio import read_exr, write_exr
from .config_io import parse_text, read_json_object, read_small_file
from .stream import META_LIMIT, DatReader, SpikeStream, check_stream_record, write_dat

MANIFEST = "manifest.json"
SPIKES = "spikes.dat"
#: The noise-free twin's stream (generate --twin: spikesim.simulate.twin_camera on the same frames).
TWIN_SPIKES = "spikes_twin.dat"
META = "meta.json"
GT_DIR = "gt"
CHECKSUMS = "checksums.json"
LOCK_FILE = ".spikesim.lock"
LAYOUT_VERSION = 2
"""2: each scene records its own checksums (checksums.json)."""

SATURATION_Y = 1.0
"""The sensor's saturation in y (expected spikes per readout step): a pixel fires at most once
per step, so above y = 1 its stream is all ones whatever the light, and ground truth above it is
a target no spike stream can show (model/data.py clips it there)."""
SATURATION_WARN_FRACTION = 0.01
"""`generate` warns about a scene whose ground truth has more than this share of pixels above
saturation."""

_PLAIN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,127}")
_SHA256 = re.compile(r"[0-9a-f]{64}")
_GT_FILE = re.compile(r"step_\d{6}\.exr")


def gt_name(step: int) -> str:
    return f"step_{int(step):06d}.exr"


def saturated_fraction(y: np.ndarray, saturation: float = SATURATION_Y) -> float:
    """The share of pixels of ground truth `y` above `saturation`."""
    y = np.asarray(y)
    return float(np.count_nonzero(y > saturation) / y.size) if y.size else 0.0


def check_scene_name(name: str) -> str:
    """`name` if it is a plain folder name (letters, digits, `_.+-`, not hidden, not the
    manifest's name); a ValueError otherwise. A scene name is never a path."""
    if not isinstance(name, str) or not _PLAIN_NAME.fullmatch(name) or name == MANIFEST:
        raise ValueError(f"scene name {name!r} is not a plain folder name (letters, digits and _.+-, "
                         "not starting with a dot); a scene given by path is a user scene: generate scene --xml PATH")
    return name


def inside_root(root: str | Path, *parts: str | Path, follow: bool = True) -> Path:
    """`root` joined with `parts` and resolved, if that lies strictly inside the resolved root; a
    ValueError naming both otherwise. Every write, delete and read under a dataset root goes
    through here, so no name or link in the data can reach a file outside it; writes and deletes
    pass `follow=False`, so no link planted in the output redirects them. One implementation
    for every command: `spikesim.outputs.inside`."""
    return outputs.inside(root, *parts, follow=follow, what="dataset root")


def remove_inside(root: str | Path, name: str) -> None:
    """Delete `root/name` (a folder or a file): `spikesim.outputs.remove`, never outside the
    root, never through a symlink."""
    outputs.remove(root, name)


def sha256_file(path: Path, block: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


def _write_json(path: Path, data: Any) -> None:
    """Write JSON atomically (spikesim.outputs); `path` must already have passed `inside_root`."""
    outputs.atomic_write_json(path, data, sort_keys=True)


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
        meta = read_json_object(meta_path, "scene record", finite=False, limit=META_LIMIT)  # fields checked below
        for key in ("height", "width", "num_steps", "gt_steps", "flip"):
            if key not in meta:
                raise ValueError(f"{meta_path}: required key {key!r} is missing")
        check_stream_record(meta, meta_path)
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

    @property
    def has_twin(self) -> bool:
        return isinstance(self.meta.get("twin"), dict)

    def twin_spikes(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """The noise-free twin's frames [start, stop) as bool (n, H, W) (generate --twin)."""
        if not self.has_twin:
            raise ValueError(f"scene {self.name} has no twin stream (made without generate --twin)")
        reader = DatReader(self.path / TWIN_SPIKES, self.height, self.width, flip=bool(self.meta["flip"]))
        if reader.num_steps != self.num_steps:
            raise ValueError(f"{self.path / TWIN_SPIKES}: {reader.num_steps} frames, meta.json says {self.num_steps}")
        return reader.read(start, stop).unpack()

    def spikes(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Frames [start, stop) as bool (n, H, W)."""
        return self.reader.read(start, stop).unpack()

    def ground_truth(self, step: int) -> np.ndarray:
        """y at `step` (expected spikes per step); an image holding a negative or non-finite value is
        a ValueError naming its file (light is never negative: a damaged or edited image)."""
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)):  # 20.5 read step 20 (round six)
            raise TypeError(f"scene {self.name}: a step is an integer, got {step!r}")
        if int(step) not in set(self.gt_steps):
            raise KeyError(f"scene {self.name} has no ground truth at step {step}")
        path = self.path / GT_DIR / gt_name(step)
        img = read_exr(path)
        if img.shape != (self.height, self.width):  # a meta.json with height and width swapped named no file
            raise ValueError(f"{path}: a {img.shape[0]} x {img.shape[1]} image, where {self.path / META} gives "
                             f"{self.height} x {self.width}")
        if not np.isfinite(img).all() or (img.size and float(img.min()) < 0):
            bad = int((~np.isfinite(img)).sum()) + int((np.nan_to_num(img, nan=0.0) < 0).sum())
            raise ValueError(f"{path}: {bad} ground-truth value(s) are negative or not finite (NaN or infinite); "
                             "light is neither: the image is damaged (spikesim verify checks a dataset)")
        return img


class _SaturationCount:
    """How much of a scene's ground truth lies above the sensor's saturation, counted image by
    image as the images are written (a scene's ground truth is never all in memory)."""

    def __init__(self) -> None:
        self.above, self.pixels, self.max_y = 0, 0, 0.0

    def add(self, img: np.ndarray) -> None:
        y = np.asarray(img)
        self.above += int(np.count_nonzero(y > SATURATION_Y))
        self.pixels += int(y.size)
        if y.size:
            self.max_y = max(self.max_y, float(np.max(y)))

    def record(self) -> dict[str, Any]:
        """meta.json's "gt_saturation": the share of ground-truth pixels above saturation."""
        return {"saturation_y": SATURATION_Y, "pixels": self.pixels,
                "saturated_fraction": self.above / self.pixels if self.pixels else 0.0, "max_y": self.max_y}


def scene_saturation(root: str | Path, name: str) -> float | None:
    """The saturated share of a scene's ground truth as its meta.json records it (None: a scene
    written before it was recorded, or a meta.json that cannot be read)."""
    try:
        meta = read_json_object(inside_root(root, name, META), "scene record", finite=False, limit=META_LIMIT)
        return float(meta["gt_saturation"]["saturated_fraction"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def write_scene(root: str | Path, name: str, stream: SpikeStream | Path, ground_truth: dict[int, np.ndarray] | Iterable[tuple[int, np.ndarray]],
                meta: dict[str, Any], flip: bool = True, twin: Path | None = None) -> SceneRecord:
    """Write a complete scene folder atomically (built as `.<name>.part`, then renamed), with the
    checksums of its files recorded last.

    `stream` is either a SpikeStream or the path of an already written `.dat` (moved in); `twin`,
    the path of the noise-free twin's `.dat` of as many steps (moved in as TWIN_SPIKES; meta.json's
    "twin" says which camera made it).
    """
    root = Path(root)
    check_scene_name(name)
    if not isinstance(flip, bool):  # flip="false" was written, then the scene refused to open: every read failed
        raise ValueError(f"scene {name}: flip must be True or False, got {flip!r}")
    final = inside_root(root, name, follow=False)
    if final.exists() or final.is_symlink():
        raise FileExistsError(f"scene folder {root / name} already exists")
    tmp = inside_root(root, f".{name}.part", follow=False)
    remove_inside(root, f".{name}.part")
    if not isinstance(stream, SpikeStream) and ("height" not in meta or "width" not in meta):
        raise ValueError(f"scene {name}: meta needs 'height' and 'width' when the stream is a file")
    (tmp / GT_DIR).mkdir(parents=True)
    moved: list[tuple[Path, Path]] = []  # files moved in, moved back if the scene is refused

    def move_in(src: Path, dst: Path) -> None:
        os.replace(src, dst)
        moved.append((Path(src), dst))
    try:
        if isinstance(stream, SpikeStream):
            write_dat(tmp / SPIKES, stream, flip=flip)
            h, w, n = stream.height, stream.width, stream.num_steps
        else:
            move_in(stream, tmp / SPIKES)
            h, w = int(meta["height"]), int(meta["width"])
            n = DatReader(tmp / SPIKES, h, w, flip=flip).num_steps
        if twin is not None:
            move_in(twin, tmp / TWIN_SPIKES)
            if (got := DatReader(tmp / TWIN_SPIKES, h, w, flip=flip).num_steps) != n:
                raise ValueError(f"scene {name}: the twin stream has {got} steps, the stream {n}")
            if not isinstance(meta.get("twin"), dict):
                raise ValueError(f"scene {name}: meta needs 'twin' (the camera that made {TWIN_SPIKES})")
        items = ground_truth.items() if isinstance(ground_truth, dict) else ground_truth
        steps = []
        saturation = _SaturationCount()
        for step, img in items:
            if isinstance(step, bool) or not isinstance(step, (int, np.integer)):  # 20.7 was stored as 20
                raise ValueError(f"scene {name}: a ground truth step is an integer, got {step!r}")
            if int(step) in steps:
                raise ValueError(f"scene {name}: ground truth step {step} given twice")
            if np.asarray(img).shape != (h, w):
                raise ValueError(f"scene {name}: ground truth at step {step} has shape {np.asarray(img).shape}, stream is {h}x{w}")
            if not 0 <= int(step) < n:
                raise ValueError(f"scene {name}: ground truth step {step} outside the stream's {n} steps")
            arr = np.asarray(img)
            if not np.isfinite(arr).all() or (arr.size and float(np.nanmin(arr)) < 0):  # a reader refuses it later
                raise ValueError(f"scene {name}: ground truth at step {step} holds negative or non-finite values")
            with outputs.writing(root / name / GT_DIR / gt_name(step), stage=tmp):  # a full disk names the file
                write_exr(tmp / GT_DIR / gt_name(step), img)
            saturation.add(img)
            steps.append(int(step))
        full_meta = {**meta, "name": name, "height": h, "width": w, "num_steps": n, "flip": flip,
                     "gt_steps": sorted(steps), "gt_saturation": saturation.record(),
                     "layout_version": LAYOUT_VERSION}
        check_stream_record(full_meta, root / name / META)  # what SceneRecord.open checks, before the rename
        _write_json(tmp / META, full_meta)
        _write_json(tmp / CHECKSUMS, {"layout_version": LAYOUT_VERSION, "files": _file_checksums(tmp)})
        os.replace(tmp, final)
    except BaseException:
        for src, dst in reversed(moved):  # a refused scene gives the caller's files back (it deleted them)
            if dst.exists() and not src.exists():
                os.replace(dst, src)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return SceneRecord.open(final)


# ---- checksums: each scene's own record, and the manifest built from them ------------------------
def _file_checksums(scene_dir: Path) -> dict[str, dict[str, Any]]:
    """bytes and sha256 of every file of a scene folder being written, keyed by its path in the
    folder (the checksum record itself excluded)."""
    out = {}
    for p in sorted(scene_dir.rglob("*")):
        if p.is_file() and not p.name.startswith(".") and p.name != CHECKSUMS:
            out[p.relative_to(scene_dir).as_posix()] = {"bytes": p.stat().st_size, "sha256": sha256_file(p)}
    return out


def _entry_problem(entry: Any) -> str | None:
    """Why a file entry ({"bytes": int >= 0, "sha256": 64 hex digits}) is malformed, or None."""
    if not isinstance(entry, dict):
        return f"expected an object with bytes and sha256, got {type(entry).__name__}"
    size = entry.get("bytes")
    if isinstance(size, bool) or not isinstance(size, int) or size < 0:
        return f"bytes={size!r} is not a size (an integer >= 0)"
    if not isinstance(entry.get("sha256"), str) or not _SHA256.fullmatch(entry["sha256"]):
        return f"sha256={entry.get('sha256')!r} is not 64 lowercase hex digits"
    return None


#: A manifest lists every file of a dataset with its checksum: far below this for any dataset.
RECORD_FILE_LIMIT = 256 << 20


def _read_json_file(path: Path, shown: Path, what: str) -> Any:
    """Parse a JSON file, or raise a ValueError naming it (`shown`, as the user gave it); a FIFO
    or device planted in its place is refused, not read (spikesim.config_io.read_small_file)."""
    try:
        text = read_small_file(path, what, RECORD_FILE_LIMIT)
    except ValueError as exc:
        reason = str(exc).replace(f"{what} {path} ", "", 1)
        raise ValueError(f"{shown}: not {what} ({reason})") from None
    try:
        return parse_text(text, f"{shown}: not {what}")
    except ValueError as exc:
        if str(exc).startswith(f"{shown}: not {what}:"):
            raise
        raise ValueError(f"{shown}: not {what} (invalid JSON: {exc})") from None


def read_scene_checksums(root: str | Path, name: str) -> dict[str, dict[str, Any]]:
    """The checksums recorded when scene `name` was written: {path in the folder: {bytes, sha256}}.
    A ValueError naming the record if it is missing or malformed."""
    shown = Path(root) / name / CHECKSUMS
    path = inside_root(root, name, CHECKSUMS)
    if not path.is_file():
        raise ValueError(f"{shown}: missing (the scene's checksum record)")
    data = _read_json_file(path, shown, "a scene checksum record")
    files = data.get("files") if isinstance(data, dict) else None
    if not isinstance(files, dict):
        raise ValueError(f"{shown}: not a scene checksum record (no 'files' object)")
    for rel, entry in files.items():
        if (why := _entry_problem(entry)) is not None:
            raise ValueError(f"{shown}: file {rel!r}: {why}")
    for required in (SPIKES, META):
        if required not in files:
            raise ValueError(f"{shown}: does not record {required}")
    return files


def _file_problem(base: Path, rel: str, want: dict[str, Any], checksums: bool, shown: str) -> str | None:
    """What is wrong with file `rel` under `base` against its record, or None; a path that leads
    outside `base` is reported and not read."""
    try:
        path = inside_root(base, rel)
    except ValueError:
        return f"{shown}: outside the dataset root, not read"
    if not path.is_file():
        return f"{shown}: missing" if not path.exists() else f"{shown}: not a regular file"
    size = path.stat().st_size
    if size != want["bytes"]:
        return f"{shown}: {size} bytes, {want['bytes']} recorded (truncated or altered)"
    if checksums and sha256_file(path) != want["sha256"]:
        return f"{shown}: checksum differs from the recorded one (altered)"
    return None


def check_scene(root: str | Path, name: str, checksums: bool = False) -> list[str]:
    """Problems of scene `name` against its own checksum record (empty: it is whole). Sizes only
    by default, which catches deleted and truncated files cheaply; `checksums=True` hashes every
    file, which also catches altered bytes."""
    try:
        folder = inside_root(root, name)
    except ValueError:
        return [f"{name}: outside the dataset root, not read"]
    if not folder.is_dir():
        return [f"{name}: scene folder missing"]
    try:
        files = read_scene_checksums(root, name)
    except (OSError, ValueError) as exc:
        return [str(exc)]
    problems = [_file_problem(folder, rel, want, checksums, f"{name}/{rel}") for rel, want in files.items()]
    if TWIN_SPIKES in files and SPIKES in files and files[TWIN_SPIKES].get("bytes") != files[SPIKES].get("bytes"):
        problems.append(f"{name}/{TWIN_SPIKES}: its record gives {files[TWIN_SPIKES].get('bytes')} bytes, "
                        f"{SPIKES} {files[SPIKES].get('bytes')}: a twin has the stream's steps")
    return [p for p in problems if p is not None]


def holds_only_scene_files(folder: Path) -> bool:
    """Whether `folder` holds nothing but what `write_scene` writes (possibly partly deleted), so
    that removing it to rebuild the scene cannot lose anything else."""
    known = {SPIKES: "file", TWIN_SPIKES: "file", META: "file", CHECKSUMS: "file", GT_DIR: "dir"}
    for entry in os.scandir(folder):
        kind = known.get(entry.name)
        if entry.is_symlink() or kind is None or (kind == "dir") != entry.is_dir(follow_symlinks=False):
            return False
        if kind == "dir":
            for gt in os.scandir(entry.path):
                if gt.is_symlink() or not gt.is_file(follow_symlinks=False) or not _GT_FILE.fullmatch(gt.name):
                    return False
    return True


def scene_folders(root: str | Path) -> list[str]:
    """Names of the folders under `root` that are scenes (not hidden, holding a meta.json or a
    checksum record), whole or not."""
    root = Path(root)
    return [d.name for d in sorted(root.iterdir())
            if d.is_dir() and not d.is_symlink() and not d.name.startswith(".")
            and ((d / META).exists() or (d / CHECKSUMS).exists())]


def write_manifest(root: str | Path, info: dict[str, Any] | None = None, scenes: Iterable[str] | None = None,
                   recorded: dict[str, dict[str, Any]] | None = None) -> Path:
    """(Re)write the dataset manifest listing `scenes`, which the caller has checked (default:
    every scene folder under `root` that passes the size check). A scene that `recorded` (the
    previous manifest's scenes) lists keeps the entries recorded there: the manifest keeps its own
    hashes and never takes them from the scene it checks, so a scene whose files and checksum
    record were both altered cannot make it say "intact". Other scenes (new ones) are listed from
    the checksum record written with them, never from the files as they are now."""
    root = Path(root)
    recorded = recorded or {}
    if scenes is None:
        scenes = [name for name in scene_folders(root) if not check_scene(root, name)]
    listed = {name: recorded[name] if name in recorded else
              {f"{name}/{rel}": want for rel, want in read_scene_checksums(root, name).items()}
              for name in sorted(scenes)}
    data = {**(info or {}), "layout_version": LAYOUT_VERSION, "scenes": listed,
            "total_bytes": sum(f["bytes"] for files in listed.values() for f in files.values()),
            "gt_saturated_fraction": {name: scene_saturation(root, name) for name in listed}}
    path = inside_root(root, MANIFEST, follow=False)
    _write_json(path, data)
    return root / MANIFEST


def drop_from_manifest(root: str | Path, names: Iterable[str]) -> None:
    """Remove scenes from an existing manifest (before their folders are rebuilt), leaving every
    other entry as it is, so that a run stopped midway never leaves a manifest whose entries
    disagree with a scene it rebuilt."""
    root = Path(root)
    if not (root / MANIFEST).is_file():
        return
    data = read_manifest(root)
    gone = [n for n in names if n in data["scenes"]]
    if not gone:
        return
    for n in gone:
        del data["scenes"][n]
        for record in ("gt_saturated_fraction", "jobs"):  # a job left behind is one for a scene not listed
            if isinstance(data.get(record), dict):
                data[record].pop(n, None)
    data["total_bytes"] = sum(f["bytes"] for files in data["scenes"].values() for f in files.values())
    _write_json(inside_root(root, MANIFEST, follow=False), data)


def manifest_disagreement(root: str | Path, name: str, entries: dict[str, Any]) -> list[str]:
    """Where scene `name`'s own checksum record differs from its `entries` in the manifest (empty:
    they agree). A difference means one of the records was rewritten after the scene was written:
    the manifest's is the one kept."""
    try:
        own = {f"{name}/{rel}": want for rel, want in read_scene_checksums(root, name).items()}
    except (OSError, ValueError) as exc:
        return [str(exc)]
    out = [f"{rel}: {CHECKSUMS} records another {'size' if own[rel]['bytes'] != want.get('bytes') else 'sha256'} "
           f"than {MANIFEST} (a record rewritten after the scene was written)"
           for rel, want in entries.items() if rel in own and own[rel] != want]
    out += [f"{rel}: listed in {MANIFEST} but not in {name}/{CHECKSUMS}" for rel in entries if rel not in own]
    out += [f"{rel}: in {name}/{CHECKSUMS} but not listed in {MANIFEST}" for rel in own if rel not in entries]
    return out


def _is_dataset_manifest(root: Path) -> bool:
    """Whether `root/manifest.json` is a spikesim dataset's: a web app's or an extension's manifest
    above an output blocked every output below it (round eleven)."""
    try:
        read_manifest(root)
    except (OSError, ValueError):
        return False
    return True


Named = TypeVar("Named")


def select_scenes(scenes: Sequence[Named], names: Sequence[str] | None, dataset: object) -> list[Named]:
    """The scenes (anything with a `.name`) named in `names`, all when it is empty or None, in the
    dataset's order; a name the dataset lacks is a ValueError listing what `dataset` has (what
    every command's `--scenes` takes)."""
    if not names:
        return list(scenes)
    have = [sc.name for sc in scenes]  # type: ignore[attr-defined]
    missing = sorted(set(names) - set(have))
    if missing:
        raise ValueError(f"--scenes: {', '.join(missing)} not in {dataset} (it has {', '.join(have)})")
    return [sc for sc, name in zip(scenes, have) if name in set(names)]


def check_outside_datasets(out: str | Path, roots: Sequence[str | Path] = (), flag: str = "-o") -> None:
    """Refuse an output at or inside one of the dataset roots a command reads, or inside any folder
    that holds a dataset manifest: `train -o` and `export -o` wrote into a dataset, which `verify`
    then reported damaged (round eight); `compare -o`, `reconstruct -o`, `panel -o` and `inspect
    --preview` into one read from elsewhere did the same (round ten)."""
    where = Path(out).resolve()
    for root in roots:
        base = Path(root).resolve()
        if where == base or base in where.parents:
            if not _is_dataset_manifest(base):  # no manifest: the message must not say one lists its files
                raise ValueError(f"{flag} {out}: inside the dataset {root}, which this command reads; choose a folder "
                                 "outside it")
            raise ValueError(f"{flag} {out}: inside the dataset {root}, whose files a manifest lists (verify would "
                             "report the outputs as extra files); choose a folder outside it")
    for base in (where, *where.parents):
        if (base / MANIFEST).is_file() and _is_dataset_manifest(base):
            raise ValueError(f"{flag} {out}: inside the dataset {base} (it holds {MANIFEST}; verify would report the "
                             "outputs as extra files); choose a folder outside it")


def read_manifest(root: str | Path) -> dict[str, Any]:
    """The manifest of the dataset at `root`, checked for shape: a ValueError naming the file if
    it is not one this package writes (so it is neither trusted nor overwritten)."""
    root = Path(root)
    shown = root / MANIFEST
    if not root.is_dir():
        raise FileNotFoundError(f"dataset folder {root} does not exist" if not root.exists() else
                                f"{root} is not a folder (a dataset is a folder)")
    path = inside_root(root, MANIFEST)
    if not path.exists():
        raise FileNotFoundError(f"{root} has no {MANIFEST}: not a dataset, or its generation did not finish")
    data = _read_json_file(path, shown, "a spikesim dataset manifest")
    if not isinstance(data, dict):
        raise ValueError(f"{shown}: not a spikesim dataset manifest (a JSON {type(data).__name__}, expected an object)")
    version = data.get("layout_version")
    if version is not None and (isinstance(version, bool) or not isinstance(version, int) or version > LAYOUT_VERSION):
        raise ValueError(f"{shown}: layout_version={version!r}; this spikesim reads layouts up to {LAYOUT_VERSION}")
    scenes = data.get("scenes")
    if not isinstance(scenes, dict):
        raise ValueError(f"{shown}: not a spikesim dataset manifest (no 'scenes' object)")
    for scene, files in scenes.items():
        if not isinstance(files, dict):
            raise ValueError(f"{shown}: scene {scene!r}: expected an object of files, got {type(files).__name__}")
        for rel, entry in files.items():
            if (why := _entry_problem(entry)) is not None:
                raise ValueError(f"{shown}: scene {scene!r}, file {rel!r}: {why}")
    return data


# ---- verify -----------------------------------------------------------------------------------------
@dataclass
class DatasetCheck:
    """What `check_dataset` found: damage (`problems`) and files the manifest does not list
    (`extras`: debris or additions, not damage)."""

    scenes: int
    problems: list[str]
    extras: list[str]


def _files_under(root: Path) -> list[str]:
    """Every file, symlink and other non-folder under `root` (symlinked folders not followed), as
    paths relative to it."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        base = Path(dirpath).relative_to(root)
        out += [(base / d).as_posix() for d in dirnames if os.path.islink(os.path.join(dirpath, d))]
        out += [(base / f).as_posix() for f in filenames]
    return sorted(out)


def check_dataset(root: str | Path, checksums: bool = True) -> DatasetCheck:
    """Compare a dataset with its manifest, reading only inside `root`: every listed file must be
    there with its size (and, with `checksums`, its sha256); a name that leads outside is reported,
    not read; files the manifest does not list are reported as extras."""
    root = Path(root)
    manifest = read_manifest(root)
    problems = []
    layout = {MANIFEST, LOCK_FILE}
    for scene, files in manifest["scenes"].items():
        try:
            folder = inside_root(root, scene)
        except ValueError:
            problems.append(f"{scene}: outside the dataset root, not read")
            continue
        try:
            check_scene_name(scene)
        except ValueError:
            problems.append(f"{scene}: not a plain scene name, not read")
            continue
        if not folder.is_dir():
            problems.append(f"{scene}: scene folder missing")
            continue
        layout.add(f"{scene}/{CHECKSUMS}")
        for rel, want in files.items():
            if (p := _file_problem(root, rel, want, checksums, rel)) is not None:
                problems.append(p)
        # the scene's own record is what a rerun of generate trusts: deleted or emptied, verify said "intact"
        # while generate rebuilt the scene as damaged (round seven)
        try:
            own = {f"{scene}/{rel}": entry for rel, entry in read_scene_checksums(root, scene).items()}
        except (OSError, ValueError) as exc:
            problems.append(str(exc))
        else:
            if own != {rel: want for rel, want in files.items()}:
                problems.append(f"{scene}/{CHECKSUMS}: differs from the manifest's record of the scene")
    problems += _manifest_field_problems(manifest)
    listed = layout | {str(Path(rel).as_posix()) for files in manifest["scenes"].values() for rel in files}
    extras = [f"{rel}: extra, not in the manifest" for rel in _files_under(root) if rel not in listed]
    return DatasetCheck(scenes=len(manifest["scenes"]), problems=problems, extras=extras)


#: The kinds `generate` records (`spikesim generate llr|rllr|scene`, and `spikesim demo`'s).
GENERATED_KINDS = ("llr", "rllr", "scene", "demo")


def _manifest_field_problems(manifest: dict[str, Any]) -> list[str]:
    """The manifest's own fields beside its file lists, as `write_manifest` and `generate` write
    them: edited (total_bytes -1, seed NaN, kind 7, a scene's job digest 123), `verify` said
    "intact" (round fourteen; round seventeen: layout_version 0, preset {} or height "x",
    gt_saturated_fraction NaN, a job for a scene not listed, kind "zzz"). Fields a manifest does not
    hold (older ones) are not asked for."""
    problems = []
    scenes = manifest["scenes"]
    version = manifest.get("layout_version")  # read_manifest refuses a non-integer or one above LAYOUT_VERSION
    if version is not None and version < 1:
        problems.append(f"{MANIFEST}: layout_version {version!r} is not a layout version (1 to {LAYOUT_VERSION})")
    if "total_bytes" in manifest:
        total = manifest["total_bytes"]
        want = sum(entry["bytes"] for files in scenes.values() for entry in files.values())
        if isinstance(total, bool) or not isinstance(total, int) or total != want:
            problems.append(f"{MANIFEST}: total_bytes {total!r} is not the {want} bytes its scenes' files list")
    if "seed" in manifest and (isinstance(manifest["seed"], bool) or not isinstance(manifest["seed"], int)
                               or manifest["seed"] < 0):
        problems.append(f"{MANIFEST}: seed {manifest['seed']!r} is not a seed (an integer, 0 or more)")
    if "kind" in manifest:
        kind = manifest["kind"]
        if not (isinstance(kind, str) and kind.isidentifier()):
            problems.append(f"{MANIFEST}: kind {kind!r} is not a dataset kind (llr, rllr, scene, ...)")
        elif "jobs" in manifest and kind not in GENERATED_KINDS:  # generate's record: one of its kinds (write_manifest alone takes any name)
            problems.append(f"{MANIFEST}: kind {kind!r} is not a kind generate writes ({', '.join(GENERATED_KINDS)})")
    if "preset" in manifest:
        preset = manifest["preset"]
        if not isinstance(preset, dict) or not preset:
            problems.append(f"{MANIFEST}: preset {preset!r} is not a preset's record (an object of its settings)")
        else:
            problems += [f"{MANIFEST}: preset.{side} {preset[side]!r} is not a number of pixels (an integer, 1 or more)"
                         for side in ("height", "width") if side in preset
                         and (isinstance(preset[side], bool) or not isinstance(preset[side], int) or preset[side] < 1)]
    if "gt_saturated_fraction" in manifest:
        saturated = manifest["gt_saturated_fraction"]
        if not isinstance(saturated, dict):
            problems.append(f"{MANIFEST}: gt_saturated_fraction {saturated!r} is not an object of each scene's "
                            "saturated share")
        else:  # None: a scene written before its saturation was recorded (scene_saturation)
            problems += [f"{MANIFEST}: gt_saturated_fraction.{name}: {v!r}, expected a share from 0 to 1"
                         for name, v in saturated.items() if v is not None and (
                             isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= 1)]
            problems += [f"{MANIFEST}: gt_saturated_fraction.{name}: a share for a scene the manifest does not list"
                         for name in saturated if name not in scenes]  # as for jobs (round eighteen)
    if "jobs" in manifest:
        jobs = manifest["jobs"]
        if not isinstance(jobs, dict):
            problems.append(f"{MANIFEST}: jobs is not an object of each scene's job digest")
        else:
            # a listed scene may have none (one kept from an earlier run that recorded none): only the type
            problems += [f"{MANIFEST}: jobs.{name}: {digest!r}, expected the scene's job digest (a string)"
                         for name, digest in jobs.items() if not isinstance(digest, str)]
            problems += [f"{MANIFEST}: jobs.{name}: a job for a scene the manifest does not list"
                         for name in jobs if name not in scenes]
    return problems


def verify(root: str | Path, checksums: bool = True) -> list[str]:
    """Compare a dataset with its manifest; returns the damage found (empty: intact). Extra files
    are not damage: `check_dataset` lists them."""
    return check_dataset(root, checksums).problems


class DatasetDamagedError(ValueError):
    """A dataset whose files are not the ones its manifest records (spikesim verify names each)."""


class DatasetBusyError(OSError):
    """A `generate` run is writing the dataset now: what a reader would see changes under it."""


def writer_of(root: str | Path) -> str | None:
    """The run writing dataset `root` now (the pid and command its lock file records), or None.
    A shared, non-blocking flock on the lock file fails only while a writer holds it; nothing is
    created or changed (spikesim.generation.lock)."""
    import fcntl
    path = Path(root) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | getattr(os, "O_NONBLOCK", 0))
    except OSError:  # no lock file (no run writes), or a link: not a lock this package made
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            text = os.pread(fd, 4096, 0).decode("utf-8", "replace").strip()
            return text.splitlines()[0] if text else "a process that has not recorded its pid yet"
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def open_dataset(root: str | Path, checksums: bool = True) -> list[SceneRecord]:
    """The scenes of the dataset at `root`, as its record lists them.

    With a manifest (every dataset `generate` writes), only the scenes it lists are read, after
    every listed file is checked against it: its size, and with `checksums` (the default; reading
    a dataset once costs about what this check does) its sha256, so that a swapped stream, a swapped
    or rewritten ground-truth image or a truncated file is refused naming the damage instead of
    being scored or trained on. Scene folders the manifest does not list (a copy under a new name,
    another run's scene) are not read, and a warning names them. Without a manifest (a generate run
    cut short, or scenes written by `write_scene` alone) every scene folder with a meta.json is
    read, each checked the same way against its own checksums.json, with a warning that the set may
    be incomplete."""
    root = Path(root)
    if not root.is_dir():  # a file given as a dataset was "missing" (round eight)
        raise FileNotFoundError(f"dataset folder {root} does not exist" if not root.exists() else
                                f"{root} is not a folder (a dataset is a folder)")
    if (writer := writer_of(root)) is not None:  # a reader saw files replaced under it (round six)
        raise DatasetBusyError(f"{root}: a generate run is writing it now ({writer}); read it when that run has "
                               "finished")
    if (root / MANIFEST).exists():
        check = check_dataset(root, checksums)
        if check.problems:
            shown = "; ".join(check.problems[:4]) + (f"; and {len(check.problems) - 4} more" if len(check.problems) > 4 else "")
            raise DatasetDamagedError(f"{root}: the dataset differs from its {MANIFEST}: {shown} (spikesim verify {root} "
                                      "lists every problem; regenerate the damaged scenes with the same generate command)")
        listed = sorted(read_manifest(root)["scenes"])
        unlisted = sorted(d.name for d in root.iterdir() if d.is_dir() and not d.name.startswith(".")
                          and d.name not in listed and (d / META).exists())
        if unlisted:
            import warnings
            warnings.warn(f"{root}: scene folder(s) {', '.join(unlisted[:6])}{' ...' if len(unlisted) > 6 else ''} "
                          f"are not in its {MANIFEST} and are not read", stacklevel=2)
        scenes = [SceneRecord.open(root / name) for name in listed]
    else:
        # no manifest: a first run that was cut short (generate writes the manifest last) or scenes
        # written by write_scene alone. Each scene's own checksums.json is its record, checked as the
        # manifest would be: a stream swapped between two scenes was read silently (issue 40, round 5)
        names = [d.name for d in sorted(root.iterdir()) if d.is_dir() and not d.name.startswith(".") and (d / META).exists()]
        problems = [p for name in names for p in check_scene(root, name, checksums)]
        if problems:
            shown = "; ".join(problems[:4]) + (f"; and {len(problems) - 4} more" if len(problems) > 4 else "")
            raise DatasetDamagedError(f"{root}: scenes differ from their own {CHECKSUMS} (the folder has no {MANIFEST}): "
                                      f"{shown}; regenerate the damaged scenes with the same generate command")
        if names:
            import warnings
            warnings.warn(f"{root} has no {MANIFEST} (a generate run that has not finished, or scenes written one by "
                          f"one): its {len(names)} scene(s) were checked against their own {CHECKSUMS}, but the set may "
                          "be incomplete; rerun the generate command to finish it", stacklevel=2)
        scenes = [SceneRecord.open(root / name) for name in names]
    if not scenes:
        raise FileNotFoundError(f"{root} holds no scene folders (each needs {META})")
    return scenes


__all__ = ["SceneRecord", "DatasetCheck", "DatasetDamagedError", "DatasetBusyError", "writer_of", "write_scene", "write_manifest", "read_manifest", "read_scene_checksums",
           "check_scene", "check_dataset", "verify", "open_dataset", "inside_root", "check_scene_name",
           "holds_only_scene_files", "scene_folders", "remove_inside", "gt_name", "MANIFEST", "SPIKES", "META", "GT_DIR",
           "CHECKSUMS", "LOCK_FILE", "SATURATION_Y", "SATURATION_WARN_FRACTION", "saturated_fraction",
           "scene_saturation", "drop_from_manifest", "manifest_disagreement"]
