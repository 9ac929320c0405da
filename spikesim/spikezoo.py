"""Spike-Zoo's dataset layout: write a spikesim dataset in it, and read such a folder back.

Spike-Zoo (github.com/chenkang455/Spike-Zoo) reads a paired dataset as

    ROOT/{train,test}/spike/NAME.dat     one spike stream per sample
    ROOT/{train,test}/gt/NAME.png        its ground truth at the stream's key step

and `spikesim export --format spikezoo` writes one pair per ground-truth step of a dataset, plus
ROOT/spikezoo.json (what was written: sizes, key step, each pair's scene, step and rate) and
ROOT/README.md. Each convention below is read from Spike-Zoo's code (file named):

- `.dat` (spikezoo/utils/spike_utils.py, `load_vidar_dat`): H * W / 8 bytes per frame, pixel i of
  the row-major frame in bit i % 8 of byte i // 8 (least significant first), then `np.flipud`:
  rows stored bottom-up. This is the project's `.dat` with flip=True (spikesim/stream.py). The
  reader takes H * W // 8 bytes per frame, so H x W must be a multiple of 8.
- size (spikezoo/datasets/base_dataset.py, `BaseDatasetConfig`): one height and width per
  dataset, given in its config (default 250 x 400); the files carry no size.
- window and key step: the REDS test streams are 301 steps (reds_base_dataset.py,
  `spike_length_test`; the `base` samples are named `..._key_id151`), and every method reads
  around the middle step `T // 2` (archs/tfp/nets.py, `BaseModel.crop_spike_length`): index 150,
  the 151st step. An export cuts `steps` steps around each ground-truth step g, [g - steps // 2,
  g - steps // 2 + steps), so g is that middle step; a g whose window leaves the stream is skipped.
- ground truth (base_dataset.py, `get_img`): `cv2.imread` (colour), BGR to grey, / 255; pairs
  match by name (reds_base_dataset.py: NAME.dat <-> NAME.png).
- rate (pipeline/base_pipeline.py, `_post_process_img`): a reconstruction is divided by `rate`
  and clipped to [0, 1] before it is compared with the PNG / 255; so PNG = round(255 clip(y /
  rate, 0, 1)) and y = rate x PNG / 255. The sample's rate is `cfg.rate` (`__getitem__`: the
  same for every sample; the config's "-1 denotes variant" is a comment that no code reads), and
  the models that use it read it per sample (`batch["rate"].view(-1, 1, 1, 1)`). An export takes
  a rate per scene, so that low light is not quantised to a few grey levels; spikezoo.json
  records it and README.md shows the few lines a Spike-Zoo dataset class needs to return it.

This module does not import the model: `spikesim evaluate --spikezoo` scores what `read_layout`
returns.
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from . import outputs
from .config_io import read_json_object
from .dataset import (LOCK_FILE, SATURATION_Y, SceneRecord, check_outside_datasets, open_dataset, select_scenes,
                      sha256_file)
from .stream import write_dat

SPLITS = ("train", "test")
SPIKE_DIR, GT_DIR = "spike", "gt"
RECORD, README = "spikezoo.json", "README.md"
RECORD_VERSION = 1
STEPS = 301
"""Steps per exported stream: Spike-Zoo's REDS test length; the key step is `STEPS // 2`."""
HEIGHT, WIDTH = 250, 400
"""Spike-Zoo's default frame size (`BaseDatasetConfig`), for a folder whose size is not recorded."""
RATE = 0.6
"""Spike-Zoo's default rate (`BaseDatasetConfig.rate`, REDS), for a folder without spikezoo.json."""
RATE_DIGITS = 3
"""A scene's rate is its brightest ground truth rounded up to this many significant digits."""


# ---- conventions ---------------------------------------------------------------------------------
def key_index(steps: int) -> int:
    """The step of a `steps`-long stream that its ground truth shows: the middle one, as every
    Spike-Zoo method crops around `T // 2`."""
    return int(steps) // 2


def window_of(gt_step: int, steps: int) -> tuple[int, int]:
    """The stream steps [start, stop) exported for ground truth at `gt_step`."""
    start = int(gt_step) - key_index(steps)
    return start, start + int(steps)


def scene_rate(max_y: float) -> float:
    """The rate of a scene whose brightest ground truth is `max_y`: that level, capped at the
    sensor's saturation (above it every stream is all ones) and rounded up to RATE_DIGITS
    significant digits, so that no pixel below saturation clips and the darkest scene still
    spans the PNG's 255 levels."""
    top = min(float(max_y), SATURATION_Y)
    if not top > 0:
        return SATURATION_Y  # a black ground truth: any rate writes zeros
    quantum = 10.0 ** (math.floor(math.log10(top)) - (RATE_DIGITS - 1))
    units = math.ceil(top / quantum)
    while float(f"{units * quantum:.{RATE_DIGITS}g}") < top:  # floating point: never below the top
        units += 1
    return min(float(f"{units * quantum:.{RATE_DIGITS}g}"), SATURATION_Y)


def png_levels(y: np.ndarray, rate: float) -> np.ndarray:
    """Ground truth y as Spike-Zoo's 8-bit PNG levels: round(255 clip(y / rate, 0, 1))."""
    scaled = np.clip(np.asarray(y, dtype=np.float64) / float(rate), 0.0, 1.0)
    return np.round(255.0 * scaled).astype(np.uint8)


def gray8(path: str | Path) -> np.ndarray:
    """A PNG or JPEG as Spike-Zoo reads its ground truth: 8-bit colour (alpha dropped, grey
    repeated), then OpenCV's BGR-to-grey in fixed point, (4899 R + 9617 G + 1868 B + 2^13) >> 14
    (exact for a grey image)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            if im.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
                raise ValueError(f"{path}: {im.mode} pixels; Spike-Zoo's ground truth is an 8-bit image")
            if im.mode in ("L", "LA", "1"):
                return np.asarray(im.convert("L"), dtype=np.uint8)
            rgb = np.asarray(im.convert("RGB"), dtype=np.int64)
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"{path} is not a readable image: {exc}") from None
    grey = (rgb[..., 0] * 4899 + rgb[..., 1] * 9617 + rgb[..., 2] * 1868 + (1 << 13)) >> 14
    return grey.astype(np.uint8)


# ---- export ------------------------------------------------------------------------------------
@dataclass
class ScenePlan:
    """Which ground-truth steps of one scene are exported (their window fits in the stream)."""

    scene: SceneRecord
    steps: list[int]
    skipped: list[int]

    def pair_name(self, gt_step: int) -> str:
        return f"{self.scene.name}_step{int(gt_step):06d}"


def _spaced(steps: Sequence[int], gt_stride: int) -> list[int]:
    """The first of `steps`, then each one at least `gt_stride` steps after the last kept."""
    kept: list[int] = []
    for g in sorted(steps):
        if not kept or g - kept[-1] >= gt_stride:
            kept.append(g)
    return kept


def plan_export(scenes: Sequence[SceneRecord], steps: int = STEPS, gt_stride: int = 1) -> list[ScenePlan]:
    """Per scene, the ground-truth steps whose `steps`-step window lies inside the stream, at
    least `gt_stride` steps apart (an RLLR scene has ground truth at every step: its 1000 steps
    would make 700 overlapping 301-step pairs)."""
    plans = []
    for sc in scenes:
        fits = [g for g in sc.gt_steps if window_of(g, steps)[0] >= 0 and window_of(g, steps)[1] <= sc.num_steps]
        plans.append(ScenePlan(sc, _spaced(fits, gt_stride), [g for g in sc.gt_steps if g not in fits]))
    return plans


def check_geometry(dataset: str | Path, scenes: Sequence[SceneRecord]) -> tuple[int, int]:
    """The (height, width) every scene shares: Spike-Zoo's config gives one size per dataset, and
    its reader needs H x W to be a multiple of 8. A ValueError names what breaks either."""
    sizes = {(sc.height, sc.width) for sc in scenes}
    if len(sizes) > 1:
        shown = ", ".join(f"{sc.name} {sc.height} x {sc.width}" for sc in scenes[:6])
        raise ValueError(f"{dataset}: scenes of different sizes ({shown}); Spike-Zoo's config gives one height and "
                         "width per dataset: export the scenes of each size to a folder of their own (--scenes)")
    (h, w), = sizes
    if (h * w) % 8:
        raise ValueError(f"{dataset}: frames are {h} x {w} = {h * w} pixels; Spike-Zoo's load_vidar_dat reads "
                         "H x W / 8 whole bytes per frame, so H x W must be a multiple of 8")
    return h, w


def _no_window_error(dataset: str | Path, plans: Sequence[ScenePlan], steps: int) -> ValueError:
    lengths = sorted({p.scene.num_steps for p in plans})
    return ValueError(f"{dataset}: no ground-truth step has a {steps}-step window around it inside its stream (streams "
                      f"of {lengths[0]}{'..' + str(lengths[-1]) if len(lengths) > 1 else ''} steps, ground truth at "
                      f"steps {', '.join(map(str, plans[0].scene.gt_steps[:6]))} ...); --steps N cuts shorter windows "
                      "(Spike-Zoo's methods read 41 steps around the key step)")


def read_record(out: str | Path) -> dict[str, Any]:
    """The spikezoo.json of an export, checked for shape; a ValueError naming it otherwise."""
    path = outputs.inside(out, RECORD)
    record = read_json_object(path, "Spike-Zoo export record", finite=False)
    splits = record.get("splits")
    if record.get("format") != "spikezoo" or not isinstance(splits, dict) or not all(
            isinstance(s, dict) and isinstance(s.get("pairs"), dict) for s in splits.values()):
        raise ValueError(f"{path}: not a Spike-Zoo export record written by spikesim export")
    return record


def _listed_files(record: dict[str, Any] | None, split: str) -> set[str]:
    """The files (relative to the export's root) an earlier export wrote in `split`."""
    pairs = ((record or {}).get("splits", {}).get(split) or {}).get("pairs", {})
    return {f"{split}/{sub}/{name}.{ext}" for name in pairs for sub, ext in ((SPIKE_DIR, "dat"), (GT_DIR, "png"))}


def check_output(out: str | Path, split: str, clean: Callable[[str], None] | None = None) -> dict[str, Any] | None:
    """The record of the export already in `out` (None: `out` is new or empty). Any other
    non-empty folder is refused, and so is a file in `out/split/{spike,gt}` that no earlier export
    wrote: Spike-Zoo would read it as one more sample. The temporary files of the files an export
    wrote or was writing (`.NAME.XXXXXXXX.part`, left by a killed export) are not refused: `clean`
    (given under the export's lock, when no other export writes there) removes them, saying each
    with it; a rerun was refused its own killed run's temporary file (round seventeen)."""
    out = Path(out)
    if not out.exists() and not out.is_symlink():
        return None
    if not out.is_dir():
        raise NotADirectoryError(f"-o {out}: exists and is not a folder")
    if not [e for e in os.listdir(out) if e != LOCK_FILE]:
        return None
    if not (out / RECORD).is_file():
        raise ValueError(f"-o {out}: the folder is not empty and is not a Spike-Zoo export (no {RECORD}); give a new or "
                         "empty folder, or the folder of an earlier export to add or replace a split")
    record = read_record(out)
    ours = _listed_files(record, split)
    # only where the record shows that an export wrote, as spikesim.outputs.results_writing does
    written = sorted(set().union(*(_listed_files(record, name) for name in record["splits"])))
    temporaries = set(outputs.stale_temporaries(out, [*written, RECORD, README]))
    if clean is not None:
        outputs.remove_temporaries(out, sorted(temporaries), "export", clean)
    for sub in (SPIKE_DIR, GT_DIR):
        folder = out / split / sub
        for path in sorted(folder.rglob("*")) if folder.is_dir() else ():
            rel = path.relative_to(out).as_posix()
            if (path.is_file() or path.is_symlink()) and rel not in ours and path not in temporaries:
                raise ValueError(f"{path}: not written by an earlier export into {out}, and Spike-Zoo would read it as "
                                 f"part of the {split} split; remove it or choose another folder")
    return record


def _light(scene: SceneRecord) -> dict[str, Any]:
    """What the scene's meta.json records of its light (illuminance in lux, power factor) and of its
    stream's timing (the camera's readout period, seconds per step)."""
    meta = scene.meta
    found = {k: meta.get(k) for k in ("subject_illuminance_lux", "light_power_factor") if meta.get(k) is not None}
    # the stream's timing: an export of a 20 kHz camera's dataset did not say so (round sixteen)
    period = meta.get("camera", {}).get("readout_period_s") if isinstance(meta.get("camera"), dict) else None
    if isinstance(period, (int, float)) and not isinstance(period, bool) and period > 0:
        found["readout_period_s"] = float(period)
    return found


def _licences(node: Any) -> list[str]:
    """Every "licence" string recorded in a scene's source description (its textures' origins)."""
    found: list[str] = []
    if isinstance(node, dict):
        for key, value in node.items():
            if key in ("licence", "license") and isinstance(value, str):
                found.append(value)
            else:
                found += _licences(value)
    elif isinstance(node, list):
        for value in node:
            found += _licences(value)
    return found


def _write_png(path: Path, levels: np.ndarray) -> None:
    from PIL import Image

    grey = Image.fromarray(np.ascontiguousarray(levels, dtype=np.uint8))  # 2-D uint8: mode L
    outputs.atomic_write_with(path, lambda tmp: grey.save(tmp, format="PNG"))


def _export_scene(out: Path, split: str, plan: ScenePlan, steps: int, rate: float | None) -> dict[str, Any]:
    """Write one scene's pairs; returns its record entry (rate, light, pairs)."""
    sc = plan.scene
    gts = {g: sc.ground_truth(g) for g in plan.steps}
    top = max(float(np.max(y)) for y in gts.values())
    r = scene_rate(top) if rate is None else float(rate)
    pairs = {}
    for g, y in gts.items():
        name = plan.pair_name(g)
        start, stop = window_of(g, steps)
        dat = write_dat(outputs.writable(out, split, SPIKE_DIR, f"{name}.dat"), sc.stream(start, stop), flip=True)
        png = outputs.writable(out, split, GT_DIR, f"{name}.png")
        _write_png(png, png_levels(y, r))
        # each file's sha256: swapped streams were scored against each other's truth, rc 0 (round eight)
        pairs[name] = {"scene": sc.name, "gt_step": g, "first_step": start, "steps": steps, "rate": r,
                       "mean_y": float(np.mean(y)), "sha256": {"spike": sha256_file(dat), "gt": sha256_file(png)}}
    entry = {"rate": r, "max_y": top, "mean_y": float(np.mean([p["mean_y"] for p in pairs.values()])),
             "pairs": len(pairs), "skipped_gt_steps": plan.skipped, **_light(sc),
             "licences": sorted(set(_licences(sc.meta.get("source"))))}
    return {"scene": entry, "pairs": pairs}


def export_spikezoo(dataset: str | Path, out: str | Path, split: str = "test", steps: int = STEPS,
                    rate: float | None = None, scenes: Sequence[str] | None = None, gt_stride: int = 1,
                    log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Write the dataset at `dataset` (its `scenes`, all when None) into `out` in Spike-Zoo's
    layout (split `split`): one pair per ground-truth step whose `steps`-step window fits in its
    stream, at least `gt_stride` steps apart; `rate` None: a rate per scene (`scene_rate`). Every
    file is written whole (temporary file, then rename); spikezoo.json says "complete" only once
    all are. Returns the record."""
    from .generation.lock import output_lock

    log = log or (lambda text: print(text, file=sys.stderr))
    if split not in SPLITS:
        raise ValueError(f"--split {split!r}: Spike-Zoo's splits are {', '.join(SPLITS)}")
    if steps < 1 or gt_stride < 1:
        raise ValueError(f"--steps {steps}, --gt-stride {gt_stride}: each must be at least one step")
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"--rate {rate}: must be a finite number > 0")
    dataset, out = Path(dataset), Path(out)
    chosen = select_scenes(open_dataset(dataset), scenes, dataset)  # an input that is no dataset is said first
    check_outside_datasets(out, [dataset])
    height, width = check_geometry(dataset, chosen)
    plans = plan_export(chosen, steps, gt_stride)
    if not any(p.steps for p in plans):
        raise _no_window_error(dataset, plans, steps)
    check_output(out, split)  # refused before any folder is made
    with outputs.output_folder(out), output_lock(out, f"export {dataset}", what="export run"):
        # again, now that no other export writes here: a killed export's temporary files removed
        old = check_output(out, split, clean=lambda text: log(f"[export] {text}"))
        record = _start_record(out, split, old, dataset, steps, gt_stride, height, width, plans)
        split_entry = record["splits"][split]
        for plan in plans:
            if plan.skipped:
                log(f"[export] {plan.scene.name}: skipped ground-truth step(s) {', '.join(map(str, plan.skipped))}: a "
                    f"{steps}-step window around them leaves the stream's {plan.scene.num_steps} steps")
            if not plan.steps:
                continue
            done = _export_scene(out, split, plan, steps, rate)
            split_entry["scenes"][plan.scene.name] = done["scene"]
            split_entry["pairs"].update(done["pairs"])
            log(f"[export] {plan.scene.name}: {len(done['pairs'])} pair(s), rate {done['scene']['rate']:g}, "
                f"mean y {done['scene']['mean_y']:.4g}")
        split_entry["complete"] = True
        outputs.atomic_write_text(outputs.writable(out, README), readme_text(record))
        outputs.atomic_write_json(outputs.writable(out, RECORD), record, sort_keys=True)
    return record


def _check_unchanged(out: Path, record: dict[str, Any] | None, split: str) -> None:
    """Every file of `split` the record lists with its sha256 still has that content: one the user
    changed since is theirs, and a rerun would delete or replace it, rc 0 (round seventeen), as a
    results folder keeps a changed result (spikesim.outputs). A ValueError names it."""
    pairs = ((record or {}).get("splits", {}).get(split) or {}).get("pairs", {})
    for name, info in sorted(pairs.items()):
        recorded = info.get("sha256") if isinstance(info, dict) else None  # none while a run is not finished
        if not isinstance(recorded, dict):
            continue
        for sub, ext, key in ((SPIKE_DIR, "dat", "spike"), (GT_DIR, "png", "gt")):
            path = out / split / sub / f"{name}.{ext}"
            if recorded.get(key) is None or not path.is_file() or path.is_symlink():
                continue
            if sha256_file(path) != recorded[key]:
                raise ValueError(f"{path}: changed since the export wrote it (its sha256 differs from {RECORD}'s); "
                                 "move it away or choose another folder")


def _start_record(out: Path, split: str, old: dict[str, Any] | None, dataset: Path, steps: int, gt_stride: int,
                  height: int, width: int, plans: Sequence[ScenePlan]) -> dict[str, Any]:
    """Remove the files of `split` an earlier export wrote that this one will not, make the
    split's folders, and write the record that lists this export's pairs as not complete yet:
    an interrupted run leaves a folder a rerun recognises and replaces."""
    record = old or {"format": "spikezoo", "version": RECORD_VERSION, "written_by": "spikesim export", "splits": {}}
    others = [name for name, entry in (old or {}).get("splits", {}).items() if name != split and entry.get("pairs")]
    if others and (old.get("height"), old.get("width")) != (height, width):
        raise ValueError(f"-o {out}: its {others[0]} split is {old.get('height')} x {old.get('width')}, this dataset "
                         f"{height} x {width}; Spike-Zoo's config gives one size per dataset")
    record.update({"height": height, "width": width, "flip": True, "bit_order": "least significant bit first",
                   "png": "round(255 * clip(y / rate, 0, 1)), 8-bit grey; y = rate * PNG / 255"})
    keep = {f"{split}/{sub}/{p.pair_name(g)}.{ext}" for p in plans for g in p.steps
            for sub, ext in ((SPIKE_DIR, "dat"), (GT_DIR, "png"))}
    _check_unchanged(out, old, split)  # before any file is removed or replaced
    for rel in sorted(_listed_files(old, split) - keep):
        outputs.remove(out, rel)
    outputs.make_dirs(out, split, SPIKE_DIR)
    outputs.make_dirs(out, split, GT_DIR)
    record["splits"][split] = {"source": str(dataset), "steps": steps, "key_index": key_index(steps),
                               "gt_stride": gt_stride, "complete": False, "scenes": {},
                               "pairs": {p.pair_name(g): {"scene": p.scene.name, "gt_step": g}
                                         for p in plans for g in p.steps}}
    outputs.atomic_write_json(outputs.writable(out, RECORD), record, sort_keys=True)
    record["splits"][split]["pairs"] = {}  # filled as each pair is written
    return record


PROJECT_LICENCE = "MIT (the spikesim project's LICENSE)"


def readme_text(record: dict[str, Any]) -> str:
    """README.md of an export: how Spike-Zoo reads it, the rates, each scene's light, the licence."""
    h, w = record["height"], record["width"]
    lines = ["# Spike-Zoo dataset exported by spikesim", "",
             f"Layout: `{{train,test}}/spike/NAME.dat` with `{{train,test}}/gt/NAME.png`, {h} x {w} (give Spike-Zoo's "
             f"dataset config `height: {h}`, `width: {w}`). Streams are PKU `.dat` as Spike-Zoo's `load_vidar_dat` reads "
             "them (least significant bit first, rows bottom-up); the ground truth shows the stream's middle step, "
             "index `T // 2`, where every Spike-Zoo method centres its input. Ground truth: 8-bit grey PNG = "
             "round(255 * clip(y / rate, 0, 1)), y the light in expected spikes per step, so a reconstruction "
             "divided by the rate (Spike-Zoo's `recon / rate`) compares with PNG / 255.", ""]
    for split, entry in sorted(record["splits"].items()):
        rates = sorted({s["rate"] for s in entry["scenes"].values()})
        lines += [f"## {split} ({len(entry['pairs'])} pairs of {entry['steps']} steps, key index {entry['key_index']}; "
                  f"from `{entry['source']}`)", "",
                  "| scene | pairs | rate | mean y | max y | illuminance (lux) | light power factor | readout (Hz) | skipped gt steps |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for name, s in sorted(entry["scenes"].items()):
            lux, power = s.get("subject_illuminance_lux"), s.get("light_power_factor")
            period = s.get("readout_period_s")
            lines.append(f"| {name} | {s['pairs']} | {s['rate']:g} | {s['mean_y']:.4g} | {s['max_y']:.4g} | "
                         f"{'-' if lux is None else f'{lux:.4g}'} | {'-' if power is None else f'{power:.4g}'} | "
                         f"{'-' if not period else f'{1 / period:,.0f}'} | "
                         f"{', '.join(map(str, s['skipped_gt_steps'])) or '-'} |")
        lines += ["", ("One rate for every pair: set `rate: " + f"{rates[0]:g}` in the dataset config." if len(rates) == 1
                       else "A rate per scene (so low light is not quantised to a few levels): Spike-Zoo's "
                            "`BaseDataset` returns `cfg.rate` for every sample, so return each pair's own rate from "
                            "spikezoo.json (`splits.<split>.pairs.<NAME>.rate`):"), ""]
        if len(rates) > 1:
            lines += ["```python", "import json, pathlib", "class SpikesimExport(BaseDataset):",
                      "    def __getitem__(self, idx):",
                      "        batch = super().__getitem__(idx)",
                      "        record = json.loads((self.cfg.root_dir / 'spikezoo.json').read_text())",
                      "        name = pathlib.Path(self.spike_list[idx]).stem",
                      "        batch['rate'] = record['splits'][self.split]['pairs'][name]['rate']",
                      "        return batch", "```", ""]
    licences = sorted({lic for e in record["splits"].values() for s in e["scenes"].values() for lic in s.get("licences", [])})
    lines += ["## Licence", "",
              f"Simulated with spikesim from the dataset named above; the data is under the project's licence, "
              f"{PROJECT_LICENCE}" + (f", and its pictures under their own: {'; '.join(licences)}." if licences else "."),
              "", "Scored back by `spikesim evaluate --spikezoo THIS_FOLDER --split test --methods tfp`.", ""]
    return "\n".join(lines)


# ---- reading -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class SpikeZooPair:
    """One sample of a Spike-Zoo folder: the stream, its ground truth, the rate that maps one to
    the other, and (for an export) where it came from."""

    name: str
    spike: Path
    gt: Path
    rate: float
    key_step: int
    steps: int
    scene: str | None = None
    gt_step: int | None = None

    def ground_truth(self) -> np.ndarray:
        """The ground truth as y (expected spikes per step): rate x PNG / 255, PNG read as
        Spike-Zoo reads it (`gray8`)."""
        return (gray8(self.gt).astype(np.float32) / np.float32(255.0)) * np.float32(self.rate)


@dataclass
class SpikeZooLayout:
    """A split of a Spike-Zoo folder: its frame size and pairs (`record`: its spikezoo.json, if any)."""

    root: Path
    split: str
    height: int
    width: int
    pairs: list[SpikeZooPair] = field(default_factory=list)
    record: dict[str, Any] | None = None


def _frames(path: Path, height: int, width: int) -> int:
    """Frames in a `.dat` of H x W; a file that is not whole frames is refused (wrong size)."""
    size, per = path.stat().st_size, height * width // 8
    if size == 0 or size % per:
        raise ValueError(f"{path}: {size} bytes is not a whole number of {height} x {width} frames ({per} bytes "
                         "each); give the dataset's height and width (Spike-Zoo's config has them)")
    return size // per


def _recorded_count(path: Path, node: dict[str, Any], name: str, where: str = "") -> int:
    """`node[name]`, a positive integer of the record at `path` (an int, not 64.0 nor "64"); a
    ValueError naming the file and the field otherwise: height 0 ended in a ZeroDivisionError, a
    missing one in "error: height" (round seventeen)."""
    value = node.get(name)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{path}: {where}\"{name}\" is {'missing' if name not in node else repr(value)}; it must be a "
                         "positive integer (the export wrote it): export again")
    return value


def _recorded_rate(path: Path, info: dict[str, Any], pair: str) -> float:
    """A pair's recorded rate: a positive finite number (a ValueError naming the file, the pair and the field)."""
    value = info.get("rate")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ValueError(f"{path}: pair {pair}: \"rate\" is {'missing' if 'rate' not in info else repr(value)}; it must "
                         "be a positive finite number (the y the PNG's white stands for): export again")
    return float(value)


def _geometry(root: Path, record: dict[str, Any] | None, height: int | None, width: int | None) -> tuple[int, int]:
    if record is None:
        h, w = height or HEIGHT, width or WIDTH
    else:
        h, w = (_recorded_count(root / RECORD, record, name) for name in ("height", "width"))
        if (height and height != h) or (width and width != w):
            raise ValueError(f"{root / RECORD} records {h} x {w}; the height and width given ({height} x {width}) differ")
    if (h * w) % 8:
        raise ValueError(f"{h} x {w}: Spike-Zoo's load_vidar_dat reads H x W / 8 whole bytes per frame; H x W must be "
                         "a multiple of 8")
    return h, w


def read_layout(root: str | Path, split: str = "test", height: int | None = None, width: int | None = None,
                rate: float | None = None) -> SpikeZooLayout:
    """The pairs of `root/split` as Spike-Zoo reads them (every `spike/**/*.dat` with the PNG of
    its name in `gt/`, the key step in the middle). An export's spikezoo.json gives the size and
    each pair's rate; a folder without one takes `height` x `width` and `rate` (Spike-Zoo's
    defaults when None: 250 x 400, 0.6)."""
    root = Path(root)
    if split not in SPLITS:
        raise ValueError(f"--split {split!r}: Spike-Zoo's splits are {', '.join(SPLITS)}")
    if not root.is_dir():
        raise FileNotFoundError(f"Spike-Zoo folder {root} does not exist" if not root.exists() else
                                f"{root} is not a folder (a Spike-Zoo dataset is a folder)")
    record = read_record(root) if (root / RECORD).exists() else None
    if record is not None and rate is not None:
        raise ValueError(f"{root / RECORD} records each pair's rate; a rate is given only for a folder without one")
    h, w = _geometry(root, record, height, width)
    entry = record["splits"].get(split) if record is not None else None
    if record is not None and (entry is None or not entry.get("complete")):
        raise ValueError(f"{root / RECORD}: the {split} split was " + ("never exported" if entry is None else
                         "not finished (the export was interrupted); run the export again"))
    spike_dir, gt_dir = root / split / SPIKE_DIR, root / split / GT_DIR
    files = sorted(spike_dir.rglob("*.dat")) if spike_dir.is_dir() else []
    if not files:
        raise FileNotFoundError(f"{spike_dir}: no .dat streams; a Spike-Zoo dataset holds {split}/{SPIKE_DIR}/NAME.dat "
                                f"with {split}/{GT_DIR}/NAME.png")
    pairs = [_pair(f, spike_dir, gt_dir, h, w, entry, RATE if rate is None else rate, root / RECORD) for f in files]
    if entry is not None:
        # round ten: pairs the record lists but the folder lacks were left out of the scores (rc 0, 5 of 10 frames)
        found = {p.name for p in pairs}
        missing = [name for name in entry["pairs"] if name not in found]
        if missing:
            shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
            are = "is" if len(missing) == 1 else "are"
            raise FileNotFoundError(f"{root / RECORD} lists {len(entry['pairs'])} {split} pairs, but {len(missing)} "
                                    f"{are} not in {spike_dir}: {shown} (NAME.dat and {GT_DIR}/NAME.png each); "
                                    "scoring the rest would report part of the export as all of it: restore them, "
                                    "or export again")
    return SpikeZooLayout(root, split, h, w, pairs, record)


def _pair(dat: Path, spike_dir: Path, gt_dir: Path, height: int, width: int, entry: dict[str, Any] | None,
          rate: float, record: Path) -> SpikeZooPair:
    rel = dat.relative_to(spike_dir).with_suffix("")
    png = gt_dir / rel.with_suffix(".png")
    if not png.is_file():
        raise FileNotFoundError(f"{dat}: no ground truth {png} (Spike-Zoo pairs NAME.dat with NAME.png)")
    steps = _frames(dat, height, width)
    if entry is None:
        return SpikeZooPair(rel.as_posix(), dat, png, float(rate), key_index(steps), steps)
    info = entry["pairs"].get(rel.as_posix())
    if info is None:
        raise ValueError(f"{dat}: not listed in the export's {RECORD}; Spike-Zoo would read it as one more sample")
    if not isinstance(info, dict):
        raise ValueError(f"{record}: pair {rel.as_posix()} is {info!r}, not the object the export wrote: export again")
    pair_rate = _recorded_rate(record, info, rel.as_posix())
    if _recorded_count(record, info, "steps", f"pair {rel.as_posix()}: ") != steps:
        raise ValueError(f"{dat}: {steps} frames of {height} x {width}; {RECORD} records {info['steps']}")
    recorded = info.get("sha256")  # exports before round eight recorded none
    if isinstance(recorded, dict):
        for path, key in ((dat, "spike"), (png, "gt")):
            if recorded.get(key) is not None and sha256_file(path) != recorded[key]:
                raise ValueError(f"{path}: not the file the export wrote for {rel.as_posix()} (its sha256 differs from "
                                 f"{RECORD}'s): swapped or altered; export again")
    return SpikeZooPair(rel.as_posix(), dat, png, pair_rate, key_index(steps), steps,
                        info.get("scene"), info.get("gt_step"))


__all__ = ["SPLITS", "STEPS", "HEIGHT", "WIDTH", "RATE", "RECORD", "README", "key_index", "window_of", "scene_rate",
           "png_levels", "gray8", "ScenePlan", "plan_export", "check_geometry", "check_output", "read_record",
           "export_spikezoo", "readme_text", "SpikeZooPair", "SpikeZooLayout", "read_layout"]
