"""Training / validation samples: K consecutive windows of T steps with ground truth at each
window centre, read from scenes in the project's dataset layout (docs/CONTRACTS.md, Datasets).

A scene is anything with SceneRecord's methods: .name, .num_steps, .height, .width, .gt_steps,
.spikes(start, stop) -> bool (n, H, W), .ground_truth(step) -> float32 (H, W).

Ground truth is clipped at the sensor's saturation (spikesim.dataset.SATURATION_Y, y = 1 spike per
step) in every sample: a pixel fires at most once per readout step, so above y = 1 its stream is
all ones whatever the light, and a target above it is one no spike stream can show. The authors'
ground truth is at most 1 by construction; ours is rendered radiance and is not.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from spikesim.dataset import SATURATION_Y

from .config import SHARE_TOLERANCE


class Scene(Protocol):
    name: str
    num_steps: int
    height: int
    width: int
    gt_steps: Sequence[int]

    def spikes(self, start: int, stop: int) -> np.ndarray: ...

    def ground_truth(self, step: int) -> np.ndarray: ...


def open_scenes(root: str | Path | Sequence[str | Path]) -> list[Scene]:
    """All scenes of a dataset root, through spikesim.dataset.open_dataset; of several roots (a list,
    or one text `ROOT+ROOT...` where no such path exists: what `--data` and `--test-data` take), all
    of theirs, each named `<root folder>:<scene>` so that two datasets' `rllr_0000` stay apart."""
    if isinstance(root, (str, Path)) and "+" in str(root) and not Path(root).exists():
        root = [part for part in str(root).split("+") if part]
    if not isinstance(root, (str, Path)):
        roots = [Path(r) for r in root]
        if len(roots) == 1:
            return open_scenes(roots[0])
        if not roots:
            raise ValueError("no dataset root given")
        folders = [r.resolve().name for r in roots]
        if len(set(folders)) != len(folders) or len(set(r.resolve() for r in roots)) != len(roots):
            raise ValueError(f"dataset roots {[str(r) for r in roots]}: each must be given once, and their folders "
                             "must have different names (they prefix the scenes' names)")
        return [RenamedScene(sc, f"{folder}:{sc.name}") for r, folder in zip(roots, folders) for sc in open_scenes(r)]
    try:
        from spikesim.dataset import open_dataset
    except ImportError as e:
        raise RuntimeError(f"spikesim.dataset is not available to read {root}: {e}") from e
    scenes = list(open_dataset(Path(root)))
    if not scenes:
        raise ValueError(f"dataset {root} has no scenes")
    return scenes


def stream_sha256(sc: Any) -> str | None:
    """The sha256 of a scene's spike stream as its dataset's checksum record (checksums.json) gives
    it, or None (a scene made in memory, or a record that is missing or unreadable). Names do not
    identify scenes across datasets (every RLLR set names its scenes rllr_0000, ...); this does."""
    path = getattr(getattr(sc, "scene", sc), "path", None)  # a TimeSlice's scene's
    if not isinstance(path, (str, Path)):
        return None
    try:
        digest = json.loads((Path(path) / "checksums.json").read_text()).get("files", {})["spikes.dat"]["sha256"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return digest if isinstance(digest, str) else None


def shared_scenes(a: Sequence[Scene], b: Sequence[Scene]) -> list[str]:
    """Names of the scenes of `a` that are also in `b`: the same folder on disk, or a copy of one
    (the same spike stream, by the sha256 its checksum record gives: a copied dataset passed as
    validation data was taken as held out, round seven). Two time slices of one scene are shared
    only where their steps overlap (split_by_time's parts share none)."""
    def keys(sc: Scene) -> set[Any]:
        path = getattr(getattr(sc, "scene", sc), "path", None)  # a TimeSlice's scene's
        if not isinstance(path, (str, Path)):
            return set()
        out: set[Any] = {("path", Path(path).resolve())}
        if (digest := stream_sha256(sc)) is not None:
            out.add(("stream", digest))
        return out

    def steps(sc: Scene) -> tuple[float, float]:
        return (sc.start, sc.stop) if isinstance(sc, TimeSlice) else (-math.inf, math.inf)

    theirs = [(keys(sc), steps(sc)) for sc in b]
    def shared(sc: Scene) -> bool:
        mine, (lo, hi) = keys(sc), steps(sc)
        return any(mine & k and lo < their_hi and their_lo < hi for k, (their_lo, their_hi) in theirs)
    return [sc.name for sc in a if shared(sc)]


class RenamedScene:
    """A scene under another name (open_scenes of several roots); everything else is the scene's."""

    def __init__(self, scene: Scene, name: str) -> None:
        self._scene, self.name = scene, name

    def __getattr__(self, attr: str) -> Any:
        if attr == "_scene":  # not yet set (unpickling): no recursion
            raise AttributeError(attr)
        return getattr(self._scene, attr)


def sequence_starts(scene: Scene, window: int, num_windows: int, stride: int = 1) -> list[int]:
    """First-window centres c such that windows centred at c, c+T, ..., c+(K-1)T all lie inside
    the stream and all have ground truth; consecutive kept starts are at least `stride` apart."""
    half = window // 2
    gt = set(int(s) for s in scene.gt_steps)
    starts: list[int] = []
    for c in sorted(gt):
        if c - half < 0 or c + (num_windows - 1) * window + half > scene.num_steps - 1:
            continue
        if all(c + i * window in gt for i in range(num_windows)) and (not starts or c - starts[-1] >= stride):
            starts.append(c)
    return starts


@dataclass(frozen=True)
class TimeSlice:
    """Steps [start, stop) of a scene, seen as a scene of its own: one scene split in time gives a
    training part and a validation part that share no step (split_by_time)."""

    scene: Scene
    start: int
    stop: int

    @property
    def name(self) -> str:
        return f"{self.scene.name}[{self.start}:{self.stop}]"

    @property
    def num_steps(self) -> int:
        return self.stop - self.start

    @property
    def height(self) -> int:
        return self.scene.height

    @property
    def width(self) -> int:
        return self.scene.width

    @property
    def gt_steps(self) -> list[int]:
        return [int(g) - self.start for g in self.scene.gt_steps if self.start <= int(g) < self.stop]

    def spikes(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        stop = self.num_steps if stop is None else stop
        if not 0 <= start <= stop <= self.num_steps:
            raise IndexError(f"{self.name}: steps [{start}, {stop}) are outside its {self.num_steps} steps")
        return self.scene.spikes(self.start + start, self.start + stop)

    def ground_truth(self, step: int) -> np.ndarray:
        if not 0 <= step < self.num_steps:
            raise KeyError(f"{self.name}: no step {step}")
        return self.scene.ground_truth(self.start + step)


def split_by_time(scene: Scene, window: int, num_windows: int,
                  val_fraction: float) -> tuple[TimeSlice, TimeSlice] | None:
    """(train, validation) parts of one scene: validation is its last stretch, at least
    `val_fraction` of the steps and at least one sample of `num_windows` windows; training is
    everything before it, so no step is in both (the content, objects and motion, is shared: a
    weaker check than held-out scenes, and said so where it is used). The cut is at the start of
    a window centred on a ground-truth step, as late as allows. None when the scene is too short
    for a sample on each side."""
    half = window // 2
    n = scene.num_steps
    for cut in sorted({int(g) - half for g in scene.gt_steps if int(g) - half > 0}, reverse=True):
        if n - cut < val_fraction * n:
            continue
        train, val = TimeSlice(scene, 0, cut), TimeSlice(scene, cut, n)
        if sequence_starts(val, window, num_windows) and sequence_starts(train, window, num_windows):
            return train, val
    return None


def split_scenes(scenes: Sequence[Scene], val_fraction: float, val_names: Sequence[str] = (),
                 seed: int = 0, window: int | None = None,
                 num_windows: int | None = None) -> tuple[list[Scene], list[Scene]]:
    """(train, validation) split by scene, so no validation frame is seen in training. A single
    scene (no names given, `val_fraction` > 0, `window` and `num_windows` given) is split in time
    instead, when it is long enough (split_by_time): else there is no validation."""
    if len(scenes) == 1 and not val_names and val_fraction > 0 and window and num_windows:
        parts = split_by_time(scenes[0], window, num_windows, val_fraction)
        if parts is not None:
            return [parts[0]], [parts[1]]
    by_name = {s.name: s for s in scenes}
    if val_names:
        missing = sorted(set(val_names) - set(by_name))
        if missing:
            raise ValueError(f"validation scenes {missing} are not in the dataset ({sorted(by_name)})")
        val = [by_name[n] for n in val_names]
    else:
        n_val = math.ceil(val_fraction * len(scenes)) if val_fraction > 0 and len(scenes) > 1 else 0
        order = np.random.default_rng(seed).permutation(len(scenes))
        val = [scenes[i] for i in sorted(order[:n_val])]
    val_set = {s.name for s in val}
    train = [s for s in scenes if s.name not in val_set]
    if not train:
        raise ValueError("no training scenes left after the validation split")
    return train, val


@dataclass(frozen=True)
class SampleRef:
    scene: int
    first_centre: int


def scene_set(name: str) -> str | None:
    """The dataset a scene came from: the `<root folder>` of a name open_scenes gave `<root folder>:<scene>`
    (several roots), else None (one root)."""
    return name.split(":", 1)[0] if ":" in name else None


def set_probabilities(samples_per_set: dict[str, int], shares: dict[str, float]) -> dict[str, float]:
    """The probability that a training sample comes from each set: the shares named, and what they
    leave split over the other sets in proportion to their samples (as if they were drawn alike).

    A share naming no set, a set left with nothing, or shares that leave something with no set to
    take it are errors naming the sets: a typo would otherwise train on another mix without a word.
    """
    unknown = sorted(set(shares) - set(samples_per_set))
    if unknown:
        raise ValueError(f"train.set_shares names {unknown}, not among the training sets {sorted(samples_per_set)} "
                         "(a set is the folder name of a --data root)")
    empty = sorted(name for name in shares if samples_per_set[name] == 0)
    if empty:
        raise ValueError(f"train.set_shares gives a share to {empty}, which have no training sample")
    named = math.fsum(shares.values())
    rest = {name: n for name, n in samples_per_set.items() if name not in shares and n > 0}
    left = 1.0 - named
    if rest and left <= SHARE_TOLERANCE:
        raise ValueError(f"train.set_shares add up to {named:g}, leaving nothing for {sorted(rest)}: lower the "
                         "shares or leave those sets out of --data")
    if not rest and abs(left) > SHARE_TOLERANCE:
        raise ValueError(f"train.set_shares add up to {named:g}, not 1, and name every training set: the rest "
                         "would have no set to come from")
    total_rest = sum(rest.values())
    probs = {name: float(shares[name]) if name in shares else left * rest[name] / total_rest
             for name in samples_per_set if name in shares or name in rest}  # in the sets' order
    norm = math.fsum(probs.values())
    return {name: p / norm for name, p in probs.items()}


class SequenceDataset(Dataset):
    """Samples of K windows: {"spikes": uint8 (K, T, h, w), "gt": float32 (K, h, w), ...}.

    Training (random_crop=True): each item draws its crop position from a generator seeded by
    (seed, epoch, index), so a run is reproducible whatever the worker count; with
    samples_per_epoch the sequence itself is drawn the same way. Validation (random_crop=False):
    a centre crop (or the full frame when crop is None). Ground truth is clipped to
    [0, saturation] (the module's docstring says why). With set_shares (training only) each item
    first draws its set by set_probabilities, then a sample of that set alike, from the same
    generator; an epoch keeps its length (samples_per_epoch, or every sample's count).
    """

    def __init__(self, scenes: Sequence[Scene], window: int, num_windows: int, crop: int | None,
                 random_crop: bool = True, seed: int = 0, start_stride: int = 1,
                 samples_per_epoch: int | None = None, max_per_scene: int | None = None,
                 saturation: float = SATURATION_Y, set_shares: dict[str, float] | None = None) -> None:
        if not saturation > 0:
            raise ValueError(f"saturation must be > 0 (expected spikes per step), got {saturation!r}")
        self.scenes = list(scenes)
        self.saturation = float(saturation)
        self.window, self.num_windows, self.crop = window, num_windows, crop
        self.random_crop, self.seed, self.samples_per_epoch = random_crop, seed, samples_per_epoch
        self.epoch = 0
        refs: list[SampleRef] = []
        for i, sc in enumerate(self.scenes):
            if random_crop and crop is not None and (crop > sc.height or crop > sc.width):
                raise ValueError(f"crop {crop} is larger than scene {sc.name!r} ({sc.height}x{sc.width})")
            starts = sequence_starts(sc, window, num_windows, start_stride)
            if max_per_scene is not None and len(starts) > max_per_scene:
                pick = np.linspace(0, len(starts) - 1, max_per_scene).round().astype(int)
                starts = [starts[j] for j in pick]
            refs += [SampleRef(i, c) for c in starts]
        if not refs:
            raise ValueError(f"no scene has {num_windows} consecutive windows of {window} steps with ground "
                             f"truth at every centre (scenes: {[s.name for s in self.scenes]})")
        self.refs = refs
        self.set_probs: dict[str, float] | None = None
        self._set_refs: list[list[int]] = []
        self._set_cum: np.ndarray | None = None
        if set_shares is not None:
            if not random_crop:
                raise ValueError("set_shares draws training samples; a validation set scores every sample")
            sets = [scene_set(sc.name) for sc in self.scenes]
            if None in sets:
                raise ValueError("train.set_shares needs the training data as several --data roots (each scene named "
                                 f"<root folder>:<scene>); these scenes are one set: {[sc.name for sc in self.scenes][:3]} ...")
            names = list(dict.fromkeys(sets))  # the order of --data
            members = {name: [j for j, r in enumerate(refs) if sets[r.scene] == name] for name in names}
            self.set_probs = set_probabilities({name: len(m) for name, m in members.items()}, set_shares)
            kept = [name for name in names if self.set_probs.get(name, 0.0) > 0]
            self._set_refs = [members[name] for name in kept]
            self._set_cum = np.cumsum([self.set_probs[name] for name in kept])

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.samples_per_epoch or len(self.refs)

    def __getitem__(self, index: int) -> dict[str, Any]:
        rng = np.random.default_rng([self.seed, self.epoch, index])
        if self._set_cum is not None:
            pick = min(int(np.searchsorted(self._set_cum, rng.random() * self._set_cum[-1], side="right")),
                       len(self._set_refs) - 1)
            members = self._set_refs[pick]
            ref = self.refs[members[int(rng.integers(len(members)))]]
        else:
            ref = self.refs[int(rng.integers(len(self.refs)))] if self.samples_per_epoch else self.refs[index]
        sc = self.scenes[ref.scene]
        t, k, half = self.window, self.num_windows, self.window // 2
        h, w = sc.height, sc.width
        # validation's centre crop is cut to a scene smaller than it (a dataset of several pixel
        # scales); its samples are scored one at a time, so their sizes may differ
        ch, cw = (h, w) if self.crop is None else (min(self.crop, h), min(self.crop, w))
        if self.random_crop:
            y0, x0 = int(rng.integers(h - ch + 1)), int(rng.integers(w - cw + 1))
        else:
            y0, x0 = (h - ch) // 2, (w - cw) // 2
        start = ref.first_centre - half
        spikes = np.asarray(sc.spikes(start, start + k * t))
        if spikes.shape != (k * t, h, w):
            raise ValueError(f"scene {sc.name!r}: spikes({start}, {start + k * t}) gave {spikes.shape}, "
                             f"expected {(k * t, h, w)}")
        spikes = spikes[:, y0:y0 + ch, x0:x0 + cw].reshape(k, t, ch, cw)
        gt = np.stack([np.asarray(sc.ground_truth(ref.first_centre + i * t), dtype=np.float32)[y0:y0 + ch, x0:x0 + cw]
                       for i in range(k)])
        np.clip(gt, 0.0, self.saturation, out=gt)
        return {"spikes": torch.from_numpy(spikes.astype(np.uint8)), "gt": torch.from_numpy(gt),
                "scene": sc.name, "first_centre": ref.first_centre, "first_step": start,
                "y0": y0, "x0": x0}
