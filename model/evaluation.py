"""Evaluation as a library: score methods on a dataset's scenes or on one external pair, pool the
scores by light condition, and write or print them (the tables of `spikesim evaluate`, which only
parses arguments and prints; a notebook can score without importing `pipelines`).

Which frames: per scene, the longest run of consecutive windows (T steps each, centres T apart)
whose centres all have ground truth, starting at the earliest such centre (an LLR scene: its 21
windows). Every method sees exactly these windows; a network sees the whole run as one sequence
(exact chunked streaming inference, model/streaming.py). Ground truth is clipped at the sensor's
saturation (y = 1 spike per step) before any metric (model/data.py), in three conventions (ours,
the authors' 8-bit one, light-normalised: model/metrics.py).

    from model.data import open_scenes
    from model.evaluation import evaluate, markdown_table
    from model.methods import method_from_spec
    rows = evaluate(open_scenes("data/llr_small"), [method_from_spec(m) for m in ("tfp", "lrrep")], 41)
    print(markdown_table(rows, ["TFP", "LR-Rep"]))
"""
from __future__ import annotations

import csv
import io
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from model.data import Scene
from model.methods import FLOORS, Method
from model.metrics import AUTHORS_CONVENTION, METRIC_CONVENTION, METRICS, NORMALISED_CONVENTION
from model.streaming import StepWindows
from spikesim.dataset import SATURATION_Y
from spikesim.outputs import atomic_write_text, output_folder, writable

ALL = "ALL"


def evaluation_run(scene: Scene, window: int) -> tuple[int, int]:
    """(first centre, number of windows) of the longest run of ground-truth window centres."""
    half = window // 2
    gt = set(int(s) for s in scene.gt_steps)
    best = (0, 0)
    for c in sorted(gt):
        if c - half < 0 or ((c - window) in gt and c - window - half >= 0):
            continue  # not inside the stream, or not the start of a run
        n = 0
        while (c + n * window) in gt and c + n * window + half <= scene.num_steps - 1:
            n += 1
        if n > best[1]:
            best = (c, n)
    if best[1] == 0:
        raise ValueError(f"scene {scene.name!r}: no ground-truth step is the centre of a full "
                         f"{window}-step window inside its {scene.num_steps} steps")
    return best


@dataclass
class Score:
    """Mean scores of one method over `frames` frames of one scene, or of a group of scenes
    (scene ALL, or ALL_<condition>); the metrics are model.metrics.METRICS."""

    scene: str
    method: str
    psnr: float
    ssim: float
    frames: int
    psnr_8bit: float = math.nan
    ssim_8bit: float = math.nan
    psnr_norm: float = math.nan
    ssim_norm: float = math.nan
    psnr_aligned: float = math.nan
    ssim_aligned: float = math.nan

    def value(self, metric: str) -> float:
        return float(getattr(self, metric))


CONDITIONS = ("low", "normal")
"""Light conditions told apart in the tables, from the scene name's last part (LLR: ball_low)."""


def light_condition(scene_name: str) -> str | None:
    """'low' or 'normal' for an LLR-style name (<scene>_<light>), else None."""
    last = scene_name.rsplit("_", 1)[-1] if "_" in scene_name else ""
    return last if last in CONDITIONS else None


def group_name(condition: str | None) -> str:
    """The scene column of a group's rows: ALL (every scene) or ALL_<condition>."""
    return ALL if condition is None else f"{ALL}_{condition}"


def unscored_note(scene: Scene, window: int) -> str | None:
    """What the evaluation run leaves out of a scene's ground truth, or None: the run scores
    consecutive windows (a recurrent network's input), so only ground-truth steps `window` apart
    in one run are scored."""
    half = window // 2
    inside = [int(s) for s in scene.gt_steps if int(s) - half >= 0 and int(s) + half <= scene.num_steps - 1]
    n = evaluation_run(scene, window)[1]
    if n >= len(inside):
        return None
    steps = sorted(int(s) for s in scene.gt_steps)
    gaps = sorted({b - a for a, b in zip(steps, steps[1:])})
    apart = f"; its ground truth is {gaps[0]} steps apart" if len(gaps) == 1 else ""
    return (f"{scene.name}: {n} of its {len(inside)} ground-truth frames scored: the scored windows are consecutive, "
            f"so their centres must be {window} steps apart{apart}")


def training_scene_notes(methods: Sequence[Method], scenes: Sequence[Any]) -> list[str]:
    """A note per checkpoint that trained (or validated) on scenes scored here, as its record says:
    those scores are training fit, not held-out ones. `compare` and `train` refuse such an overlap
    (model.data.shared_scenes); an evaluation may measure training fit on purpose, so it is said,
    not refused (round ten: no word at all). `scenes` are the scored scenes (or their names).

    A scene is matched by its stream's sha256 where both the record (`extra.data_streams`) and the
    scene's checksum record give one: names repeat across datasets (every RLLR set names its scenes
    rllr_0000, ...), so a match by name alone said a network had trained on held-out scenes. Where
    either lacks it (checkpoints written before the record, external pairs) the name decides, and the
    note says so. Shipped weights have no such record."""
    from model.checkpoint import load_checkpoint
    from model.data import stream_sha256
    from model.methods import ModelMethod

    def base(name: object) -> str:  # several roots' scenes are "folder:name"
        return str(name).rsplit(":", 1)[-1]
    scored = [(sc if isinstance(sc, str) else sc.name, None if isinstance(sc, str) else stream_sha256(sc))
              for sc in scenes]
    notes = []
    for named in methods:
        m = getattr(named, "inner", named)  # a flip self-ensemble's network
        if not isinstance(m, ModelMethod) or m.checkpoint is None:
            continue
        try:
            extra = load_checkpoint(m.checkpoint).get("extra") or {}
        except (OSError, ValueError):
            continue  # read once already to build the method; nothing to say
        order = extra.get("data_order") if isinstance(extra, dict) else None
        if not (isinstance(order, list) and len(order) == 2 and all(isinstance(part, list) for part in order)):
            continue  # checkpoints written before the record have none
        streams = extra.get("data_streams")
        if not (isinstance(streams, list) and len(streams) == 2
                and all(isinstance(p, list) and len(p) == len(o) for p, o in zip(streams, order))):
            streams = [[None] * len(part) for part in order]
        for names, digests, verb in ((order[0], streams[0], "trained"),
                                     (order[1], streams[1], "validated (its best.pt chosen by their scores)")):
            their_digests = {d for d in digests if isinstance(d, str)}
            all_names = {base(n) for n in names}
            unrecorded = {base(n) for n, d in zip(names, digests) if not isinstance(d, str)}
            by_stream = [n for n, d in scored if d is not None and d in their_digests]
            # a scored scene without a stream record can only be matched by name; one with a record only
            # against the run's scenes that have none
            by_name = [n for n, d in scored if (d is None and base(n) in all_names)
                       or (d is not None and d not in their_digests and base(n) in unrecorded)]
            for shared, how in ((by_stream, "the same spike streams (by sha256)"),
                                (by_name, "scenes of the same names (their streams not recorded: another "
                                          "dataset's scenes of those names would be named too)")):
                if shared:
                    notes.append(f"{named.name} ({m.checkpoint}) {verb} on {len(shared)} of the scenes scored here "
                                 f"({', '.join(shared[:6])}{' ...' if len(shared) > 6 else ''}): {how}, as its "
                                 "record (extra.data_order) names them; its scores there measure training fit, "
                                 "not held-out scenes")
    return notes


def notes_markdown(notes: Sequence[str]) -> str:
    """The notes as a section of metrics.md ("" when there are none)."""
    return "" if not notes else "\n**Notes**\n\n" + "".join(f"- {n}\n" for n in notes)


def evaluate_scene(scene: Scene, methods: Sequence[Method], window: int) -> list[Score]:
    """Every metric of every method on the scene's evaluation run; ground truth clipped at the
    sensor's saturation (y = 1 spike per step: above it no stream differs, model/data.py)."""
    first, n = evaluation_run(scene, window)
    source = StepWindows(scene.spikes, first - window // 2, window, n)
    gts = [np.clip(np.asarray(scene.ground_truth(first + i * window), dtype=np.float32), 0.0, SATURATION_Y)
           for i in range(n)]
    out = []
    for m in methods:
        values: dict[str, list[float]] = {k: [] for k in METRICS}
        for i, frame in m.frames(source):
            pred = frame.numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
            for k, (fn, _, _) in METRICS.items():
                values[k].append(fn(pred, gts[i]))
        out.append(Score(scene.name, m.name, frames=len(values["psnr"]),
                         **{k: float(np.mean(v)) for k, v in values.items()}))
    return out


def pooled(rows: Sequence[Score], scene: str, method: str) -> Score:
    """The frame-weighted mean of `rows` (one method), labelled `scene`."""
    frames = sum(r.frames for r in rows)
    return Score(scene, method, frames=frames,
                 **{k: sum(r.value(k) * r.frames for r in rows) / frames for k in METRICS})


def evaluate(scenes: Sequence[Scene], methods: Sequence[Method], window: int, progress: bool = True) -> list[Score]:
    """Per-scene scores, then per method the mean over all frames of the low-light scenes
    (ALL_low) and of the normal-light ones (ALL_normal) where there are such, then overall (ALL)."""
    windows = {m.name: m.window for m in methods}
    if any(w != window for w in windows.values()):
        raise ValueError(f"all methods must use {window}-step windows; got {windows}")
    names = [m.name for m in methods]
    if len(set(names)) != len(names):
        raise ValueError(f"method names must be unique, got {names}; name them with label=spec")
    rows: list[Score] = []
    for sc in scenes:
        rows += evaluate_scene(sc, methods, window)
        if note := unscored_note(sc, window):  # --window 3 scored 1 of 5 frames without a word (round eight)
            print(f"[evaluate] note: {note}", file=sys.stderr)
        if progress:
            print(f"[evaluate] {sc.name}: aligned PSNR " + ", ".join(f"{r.method} {r.psnr_aligned:.2f} dB"
                                                                  for r in rows[-len(methods):]),
                  file=sys.stderr)
    per_scene = list(rows)
    for cond in CONDITIONS:
        for m in names:
            mine = [r for r in per_scene if r.method == m and light_condition(r.scene) == cond]
            if mine:
                rows.append(pooled(mine, group_name(cond), m))
    for m in names:
        rows.append(pooled([r for r in per_scene if r.method == m], ALL, m))
    return rows


def evaluate_pair(dat: Path, gt: np.ndarray, center: int, methods: Sequence[Method], window: int,
                  height: int | None = None, width: int | None = None, header_columns: int | None = None,
                  flip: bool | None = None, center_is: str = "--center") -> tuple[list[Score], dict]:
    """Scores of each method on the window of `dat` centred on step `center` against `gt` (y);
    geometry as recorded beside the stream where not given. Returns the rows and what was read.
    `center_is` names the centre in errors (a Spike-Zoo pair's is its key step, not a flag)."""
    from model.streaming import StepWindows
    from spikesim.stream import DatReader, check_recorded_layout, detect_header_columns, stream_geometry

    given_size = bool(height and width)
    height, width, flip = stream_geometry(dat, height, width, flip)
    if header_columns is None:
        header_columns = detect_header_columns(dat, height, width)
    elif not given_size:  # part of the layout from the record: the rest must agree with it
        check_recorded_layout(dat, height, width, header_columns)
    if gt.shape != (height, width):
        raise ValueError(f"--gt is {gt.shape[0]} x {gt.shape[1]} but the stream is read as {height} x {width}; "
                         "check --height/--width (or the image)")
    # what read_image_y refuses of a file, refused of an array too: a negative or NaN ground truth was
    # clipped to 0 below and scored (round ten); y is light, >= 0 and finite
    bad, negative = int(np.count_nonzero(~np.isfinite(gt))), int(np.count_nonzero(np.asarray(gt) < 0))
    if bad or negative:
        what = f"{bad} NaN or infinite" if bad else f"{negative} negative (min {float(np.min(gt)):.3g})"
        raise ValueError(f"--gt (the ground truth of {dat}) has {what} pixel(s) of {gt.size}; the image's y (light, "
                         "in spikes per step) must be finite and >= 0")
    reader = DatReader(dat, height, width, flip=flip, header_columns=header_columns)
    half = window // 2
    if center - half < 0 or center + (window - half) > reader.num_steps:
        raise ValueError(f"{center_is} {center}: a {window}-step window around it needs steps {center - half}.."
                         f"{center + window - half - 1}, but {dat} has steps 0..{reader.num_steps - 1}"
                         + (f"; a shorter --window (odd, at most {max(1, reader.num_steps - 1 + reader.num_steps % 2)}) "
                            "scores it with a window average" if reader.num_steps < window else ""))
    # every whole window that fits on each side of the centre window: a network (and TFP over a
    # span) sees the stream around the frame, as on a dataset; TFP and TFI use the centre window only
    before = (center - half) // window
    after = (reader.num_steps - (center - half + window)) // window
    source = StepWindows(lambda a, b: reader.read(a, b).unpack(), center - half - before * window, window,
                         before + 1 + after)
    target = np.clip(gt.astype(np.float32), 0.0, SATURATION_Y)
    if float(target.max()) == float(target.min()):  # as generate refuses a black scene
        raise ValueError(f"--gt is one value everywhere (y = {float(target.min()):.4g} after clipping at saturation): a "
                         "constant image scores every method's PSNR as infinite or undefined; check the image and "
                         "--gt-scale")
    rows = []
    for m in methods:
        frame = next(f for i, f in m.frames(source) if i == before)
        pred = frame.numpy() if isinstance(frame, torch.Tensor) else np.asarray(frame)
        rows.append(Score(dat.stem, m.name, frames=1, **{k: fn(pred, target) for k, (fn, _, _) in METRICS.items()}))
    rows += [pooled([r], ALL, r.method) for r in rows]
    read = {"dat": str(dat), "center": center, "window": window, "windows": before + 1 + after,
            "first_step": center - half - before * window, "height": height, "width": width,
            "header_columns": header_columns, "flip": flip, "gt_mean_y": float(target.mean())}
    return rows, read


def scores_json(rows: Sequence[Score], methods: Sequence[str], extra: dict | None = None) -> dict:
    """{"methods": {label: metrics over all frames}, "groups": {ALL_low: ...}, "scenes": {...}}:
    every metric convention of model/metrics.py, with the frame counts."""
    def metrics(r: Score) -> dict:
        return {**{k: r.value(k) for k in METRICS}, "frames": r.frames}
    out: dict = {"methods": {r.method: metrics(r) for r in rows if r.scene == ALL},
                 "groups": {}, "scenes": {}, "conventions": {"psnr/ssim": METRIC_CONVENTION,
                                                             "psnr_8bit/ssim_8bit": AUTHORS_CONVENTION,
                                                             "psnr_norm/ssim_norm/psnr_aligned": NORMALISED_CONVENTION}}
    for r in rows:
        if r.scene != ALL:
            key = "groups" if r.scene.startswith(ALL + "_") else "scenes"
            out[key].setdefault(r.scene, {})[r.method] = metrics(r)
    out["methods"] = {m: out["methods"][m] for m in methods}
    return {**out, **(extra or {})}


def _cell(value: float, fmt: str, best: bool) -> str:
    text = fmt.format(value)
    return f"**{text}**" if best else text


#: The tables' row order: first the metric a black or constant image cannot win (aligned PSNR
#: scores it at the floor, model/metrics.py), then light-normalised, then the absolute ones, on
#: which a black image beats every method in low light (its ground truth is nearly black too).
TABLE_ROWS = ("psnr_aligned", "ssim_aligned", "psnr_norm", "ssim_norm", "psnr", "ssim", "psnr_8bit", "ssim_8bit")


def method_label(method: str) -> str:
    """A column's name: floors are marked as floors."""
    return f"{method} (floor)" if method in FLOORS else method


def _group_table(rows: Sequence[Score], methods: Sequence[str], group: str) -> list[str]:
    """Table 1 layout (metrics x methods) for one group of scenes; the best method of each row in
    bold (the floors are shown, never bolded: they are what no structure scores)."""
    by = {r.method: r for r in rows if r.scene == group}
    contenders = [m for m in methods if m not in FLOORS]
    lines = ["| Metric | " + " | ".join(method_label(m) for m in methods) + " |", "|---|" + "---|" * len(methods)]
    for key in TABLE_ROWS:
        _, label, fmt = METRICS[key]
        best = max((by[m].value(key) for m in contenders), default=math.nan)
        lines.append(f"| {label} | " + " | ".join(
            _cell(by[m].value(key), fmt, len(contenders) > 1 and m in contenders and by[m].value(key) == best)
            for m in methods) + " |")
    return lines


def markdown_table(rows: Sequence[Score], methods: Sequence[str]) -> str:
    """The low-light scenes, the normal-light ones (where the names say which), then all scenes, in
    Table 1 layout; then every metric per scene. The 8-bit rows are the convention of the paper's
    Table 1; docs/model.md says how to read the three."""
    lines: list[str] = []
    for cond in CONDITIONS + (None,):
        group = group_name(cond)
        present = [r for r in rows if r.scene == group]
        if not present:
            continue
        title = "All scenes" if cond is None else f"{cond.capitalize()} light"
        lines += [f"**{title}** ({present[0].frames} frames)", ""] + _group_table(rows, methods, group) + [""]
    # per scene, two narrow tables (aligned PSNR, then aligned SSIM; best in bold): a column per method, not
    # three (6 methods made 20 columns); metrics.csv has every metric of every scene
    scenes = [r.scene for r in rows if not r.scene.startswith(ALL) and r.method == methods[0]]
    for key, label, fmt in (("psnr_aligned", "aligned PSNR (dB)", "{:.2f}"), ("ssim_aligned", "aligned SSIM", "{:.4f}")):
        lines += [f"**Per scene: {label}** (every metric: metrics.csv)", "",
                  "| Scene | frames | " + " | ".join(method_label(m) for m in methods) + " |",
                  "|---|---|" + "---|" * len(methods)]
        for sc in scenes:
            by = {r.method: r for r in rows if r.scene == sc}
            vals = [by[m].value(key) for m in methods]
            best = max(v for m, v in zip(methods, vals) if m not in FLOORS) if any(m not in FLOORS for m in methods) else None
            cells = [f"**{fmt.format(v)}**" if v == best and m not in FLOORS else fmt.format(v) for m, v in zip(methods, vals)]
            lines.append(f"| {sc} | {by[methods[0]].frames} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["", f"Metric conventions. PSNR, SSIM: {METRIC_CONVENTION} {AUTHORS_CONVENTION} "
                  f"{NORMALISED_CONVENTION} Ground truth clipped at saturation (y = {SATURATION_Y:g}). "
                  "Groups = mean over all frames of their scenes."]
    return "\n".join(lines) + "\n"


CSV_FIELDS = ("scene", "method", *METRICS, "frames")
DEFAULT_OUT = "results/evaluate"


RESULT_FILES = ("metrics.csv", "metrics.md")


def check_results(out: Path) -> None:
    """The results' paths in `out` are no links (refused, naming them): checked before the work."""
    for name in RESULT_FILES:
        writable(out, name)


def write_results(rows: Sequence[Score], methods: Sequence[str], out: Path,
                  markdown: str | None = None) -> tuple[Path, Path]:
    """metrics.csv (every row, every metric) and metrics.md (`markdown`, else the Table 1 layout),
    each written whole (temporary file, then rename), inside `out` and never through a link."""
    out = Path(out)
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(CSV_FIELDS)
    for r in rows:
        w.writerow([r.scene, r.method, *(f"{r.value(k):.6f}" for k in METRICS), r.frames])
    with output_folder(out):
        check_results(out)
        atomic_write_text(writable(out, "metrics.csv"), buf.getvalue())
        atomic_write_text(writable(out, "metrics.md"), markdown_table(rows, methods) if markdown is None else markdown)
    return out / "metrics.csv", out / "metrics.md"


def json_safe(doc: object) -> object:
    """inf (a perfect PSNR) as the string "inf": JSON has no infinity."""
    if isinstance(doc, dict):
        return {k: json_safe(v) for k, v in doc.items()}
    if isinstance(doc, float) and not math.isfinite(doc):
        return str(doc)
    return doc


def pair_table(rows: Sequence[Score], methods: Sequence[str], read: dict) -> str:
    lines = [f"{read['dat']}: window of {read['window']} steps centred on step {read['center']}, "
             f"{read['height']} x {read['width']}, flip {read['flip']}; ground truth mean y {read['gt_mean_y']:.4f}", ""]
    lines += _group_table(rows, methods, ALL)
    lines += ["", f"Metric conventions. PSNR, SSIM: {METRIC_CONVENTION} {AUTHORS_CONVENTION} {NORMALISED_CONVENTION}"]
    return "\n".join(lines) + "\n"
