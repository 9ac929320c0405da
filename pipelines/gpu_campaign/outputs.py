"""What a GPU campaign (pipelines/gpu_campaign/) hands back, within what a lent machine returns:
at most 8 files, 16 MiB each, 64 MiB together, no deeper than 2 folders, plain names
(docs/gpu_campaign.md). Everything is written so that it fits, and checked before the campaign
ends: a file that would not come back is lost without a word, so the limits are enforced here
rather than discovered afterwards.

- `logs.txt`: every stage's log in one file, each cut to its head and tail if all of them together
  would pass LOGS_MAX_BYTES;
- the trained network as weights-only files (`write_weights`): fp32 in one file where it fits,
  else a bf16 copy that loads as it is plus the fp32 weights split into parts that
  `join_weight_parts` puts back together, bit for bit (checked by the weights' fingerprint);
- `report.md`: the tables of docs/gpu_campaign.md with this run's figures.
"""
from __future__ import annotations

import hashlib
import math
import shutil
import re
from pathlib import Path
from typing import Any, Iterable, Sequence

from spikesim import outputs

MAX_FILES = 8
MAX_FILE_BYTES = 16 * 2**20
MAX_TOTAL_BYTES = 64 * 2**20
MAX_DEPTH = 2
"""Folders below the output folder a returned file may sit in ($OUT/a/b/file comes back)."""
LOGS_MAX_BYTES = 4 * 2**20
"""All logs together: enough for every traceback, small beside the weights."""
_NAME = re.compile(r"^[A-Za-z0-9._-]+$")
#: Weights files are kept this far below the per-file limit (pickle framing, the config): 1 MiB,
#: or an eighth of a smaller limit.
_WEIGHTS_MARGIN_BYTES = 2**20


# ---- the limits -------------------------------------------------------------------------------
def out_problems(out: Path) -> list[str]:
    """Every way the files under `out` break what a lent machine returns (empty: all come back)."""
    problems: list[str] = []
    files = sorted(p for p in out.rglob("*") if not p.is_dir())
    if len(files) > MAX_FILES:
        problems.append(f"{len(files)} files, more than {MAX_FILES}: {', '.join(str(f.relative_to(out)) for f in files)}")
    total = 0
    for f in files:
        rel = f.relative_to(out)
        if f.is_symlink() or not f.is_file():
            problems.append(f"{rel}: not a plain file")
            continue
        size = f.stat().st_size
        total += size
        if size > MAX_FILE_BYTES:
            problems.append(f"{rel}: {size / 2**20:.1f} MiB, over {MAX_FILE_BYTES // 2**20} MiB")
        if len(rel.parts) - 1 > MAX_DEPTH:
            problems.append(f"{rel}: {len(rel.parts) - 1} folders deep, more than {MAX_DEPTH}")
        bad = [p for p in rel.parts if not _NAME.match(p)]
        if bad:
            problems.append(f"{rel}: {bad[0]!r} is not letters, digits, '.', '_' and '-' alone")
    if total > MAX_TOTAL_BYTES:
        problems.append(f"{total / 2**20:.1f} MiB in all, over {MAX_TOTAL_BYTES // 2**20} MiB")
    return problems


def check_out(out: Path) -> None:
    """Raise ValueError naming every problem if some file under `out` would not come back."""
    problems = out_problems(out)
    if problems:
        raise ValueError(f"{out}: would not all come back from a lent machine: " + "; ".join(problems))


def file_record(path: Path) -> dict[str, Any]:
    """Name, size and sha256 of a file handed back (the summary lists them)."""
    data = path.read_bytes()
    return {"name": path.name, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}


# ---- logs -------------------------------------------------------------------------------------
def _cut(text: str, limit: int) -> str:
    """`text` within `limit` characters: its head and its tail (where errors are), the middle
    replaced by a line that says how much was left out."""
    if len(text) <= limit:
        return text
    head = limit // 4
    tail = limit - head
    return (text[:head] + f"\n[... {len(text) - limit} characters left out: this log was cut to fit "
            f"{LOGS_MAX_BYTES // 2**20} MiB of logs in all ...]\n" + text[-tail:])


def combined_logs(sections: Sequence[tuple[str, str]], limit: int = LOGS_MAX_BYTES) -> str:
    """One text of (title, log) sections, each under a `===== title =====` line; when together they
    pass `limit`, each long log gets an equal share of what is left after the short ones."""
    share = limit
    lengths = sorted(len(t) for _, t in sections)
    for i, n in enumerate(lengths):
        rest = limit - sum(lengths[:i])
        if n * (len(lengths) - i) > rest:
            share = max(rest // (len(lengths) - i), 1024)
            break
    parts = [f"===== {title} =====\n{_cut(text, share).rstrip()}\n" for title, text in sections]
    return "\n".join(parts)


# ---- weights ----------------------------------------------------------------------------------
def _torch_doc(path: Path) -> dict[str, Any]:
    import torch
    return torch.load(path, map_location="cpu", weights_only=True)


def write_weights(checkpoint: Path, out: Path, work: Path, max_bytes: int = MAX_FILE_BYTES,
                  provenance: dict[str, Any] | None = None, stem: str = "weights") -> list[dict[str, Any]]:
    """The network of a training checkpoint as weights-only files in `out`, each under `max_bytes`
    (named `stem`.pt, `stem`_bf16.pt and `stem`_fp32.partIofN.pt; `stem` "weights" by default).

    fp32 in `weights.pt` where that fits. Otherwise (the paper's network is 21.3 MiB in fp32):
    `weights_bf16.pt`, loadable as it is by `evaluate`, `reconstruct` and `model_from_checkpoint`
    (bf16 keeps float32's range; its own fingerprint is stored, with the fp32 one it came from),
    and the fp32 weights in parts `weights_fp32.partIofN.pt` for `join_weight_parts`. Returns a
    record per file: name, bytes, sha256, dtype, fingerprint."""
    import torch
    from model.checkpoint import FORMAT_VERSION, state_fingerprint
    from model.pretrained import export_weights

    work.mkdir(parents=True, exist_ok=True)
    fp32_path = work / "weights_fp32.pt"
    exported = export_weights(checkpoint, fp32_path, provenance)
    limit = max_bytes - min(_WEIGHTS_MARGIN_BYTES, max_bytes // 8)
    out.mkdir(parents=True, exist_ok=True)
    if fp32_path.stat().st_size <= limit:
        target = out / f"{stem}.pt"
        outputs.atomic_write_bytes(target, fp32_path.read_bytes())  # a link there is refused, not followed
        return [{**file_record(target), "dtype": "float32", "weights_sha256": exported["weights_sha256"]}]
    doc = _torch_doc(fp32_path)
    state = doc["model_state"]
    records = []

    low = {k: v.to(torch.bfloat16) if v.is_floating_point() else v for k, v in state.items()}
    bf16_doc = {**doc, "model_state": low, "weights_sha256": state_fingerprint(low),
                "extra": {**doc.get("extra", {}), "cast": {"dtype": "bfloat16", "from": "float32",
                                                           "float32_weights_sha256": exported["weights_sha256"]}}}
    bf16_path = _save_within(bf16_doc, out / f"{stem}_bf16.pt", work, max_bytes, "even in bf16")
    records.append({**file_record(bf16_path), "dtype": "bfloat16", "weights_sha256": bf16_doc["weights_sha256"]})

    sizes = {k: v.numel() * v.element_size() for k, v in state.items()}
    groups: list[list[str]] = [[]]
    used = 0
    for k in state:  # greedy in the state's order; a tensor larger than a part gets a part of its own
        if groups[-1] and used + sizes[k] > limit:
            groups.append([])
            used = 0
        groups[-1].append(k)
        used += sizes[k]
    header = {k: v for k, v in doc.items() if k != "model_state"}
    for i, keys in enumerate(groups, 1):
        part = {"format_version": FORMAT_VERSION, "kind": "spikesim weights part", "part": i, "parts": len(groups),
                "header": header, "model_state": {k: state[k] for k in keys}}
        path = _save_within(part, out / f"{stem}_fp32.part{i}of{len(groups)}.pt", work, max_bytes,
                            "with one tensor alone")
        records.append({**file_record(path), "dtype": "float32", "part": i, "parts": len(groups),
                        "weights_sha256": exported["weights_sha256"]})
    return records


def _save_within(doc: dict[str, Any], path: Path, work: Path, max_bytes: int, what: str) -> Path:
    """Save `doc` in the work folder, then move it to `path` if it is at most `max_bytes`: a file
    too large never reaches the output folder (where it would not come back, and would fail the
    check of everything else)."""
    from model.checkpoint import atomic_torch_save

    staged = work / path.name
    atomic_torch_save(doc, staged)
    size = staged.stat().st_size
    if size > max_bytes:
        staged.unlink()
        raise ValueError(f"{path.name}: {size / 2**20:.1f} MiB {what}, over the {max_bytes / 2**20:.1f} MiB a "
                         "returned file may have")
    outputs.check_not_link(path)
    shutil.move(staged, path)  # the output folder may be on another filesystem
    return path


def join_weight_parts(parts: Iterable[str | Path], out: str | Path) -> str:
    """Put fp32 weights split by `write_weights` back into one weights-only file; returns its
    weights' fingerprint, checked against the one recorded before the split."""
    from model.checkpoint import atomic_torch_save, load_checkpoint, state_fingerprint

    docs = sorted((_torch_doc(Path(p)) for p in parts), key=lambda d: d.get("part", 0))
    if not docs or any(d.get("kind") != "spikesim weights part" for d in docs):
        raise ValueError("join_weight_parts: expected the weights_fp32.part*.pt files written by a GPU campaign")
    n = docs[0]["parts"]
    if [d["part"] for d in docs] != list(range(1, n + 1)) or any(d["parts"] != n for d in docs):
        raise ValueError(f"join_weight_parts: parts {[d['part'] for d in docs]} given, expected 1 to {n}")
    state: dict[str, Any] = {}
    for d in docs:
        state.update(d["model_state"])
    header = docs[0]["header"]
    fingerprint = state_fingerprint(state)
    if fingerprint != header.get("weights_sha256"):
        raise ValueError("join_weight_parts: the joined weights do not match the fingerprint recorded before the split")
    atomic_torch_save({**header, "model_state": state}, out)
    load_checkpoint(out)  # the joined file is a checkpoint like any other
    return fingerprint


# ---- the report ---------------------------------------------------------------------------------
NOT_MEASURED = "not measured"


def _fmt(value: Any, spec: str = ".3g", unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return NOT_MEASURED
    return f"{value:{spec}}{unit}"


def _stage(summary: dict[str, Any], name: str) -> dict[str, Any]:
    return next((s for s in summary.get("stages", []) if s["name"] == name), {"status": "skipped", "figures": {}})


def _bench_rows(summary: dict[str, Any], stage: str) -> list[dict[str, Any]]:
    return _stage(summary, stage).get("figures", {}).get("results", [])


def _row_value(rows: list[dict[str, Any]], stage: str, what: str, device_kind: str) -> dict[str, Any] | None:
    """The bench row of `stage` whose description starts with `what`, measured on the campaign's
    device ("device": cuda or llvm) or on the NumPy reference ("numpy")."""
    for r in rows:
        is_numpy = r["device"] == "numpy" or r["device"].endswith("+numpy")
        if r["stage"] == stage and r["what"].startswith(what) and (is_numpy == (device_kind == "numpy")):
            return r
    return None


def report_markdown(summary: dict[str, Any]) -> str:
    """docs/gpu_campaign.md's tables with this run's column; a stage that did not run reads
    'not measured', one that failed says so."""
    mode = summary.get("mode", "?")
    machine = summary.get("machine", {})
    lines = [f"# GPU campaign report ({mode})", "",
             f"Machine: {machine.get('gpu') or 'no GPU'}; CPU {machine.get('cpu', '?')} x {machine.get('cores', '?')}; "
             f"torch {machine.get('torch', '?')}, drjit {machine.get('drjit', '?')}, mitsuba {machine.get('mitsuba', '?')}. "
             f"Started {summary.get('started', '?')}, part {summary.get('part', '?')}.", "",
             "| stage | status | seconds | note |", "|---|---|---|---|"]
    for s in summary.get("stages", []):
        lines.append(f"| {s['name']} | {s['status']} | {_fmt(s.get('seconds'), '.1f')} | {s.get('note') or ''} |")

    sensor = _bench_rows(summary, "bench_sensor")
    lines += ["", "## Sensor throughput (pixel-steps/s; x real time)", "", "| case | this run | x NumPy | x real time |",
              "|---|---|---|---|"]
    for what in ("noiseless, frames every step", "noiseless, keyframes every 8", "realistic, frames every step",
                 "realistic, keyframes every 8"):
        r = _row_value(sensor, "sensor", what, "device")
        lines.append(f"| {what} | {_fmt(r and r['pixel_steps_per_s'])} | {_fmt(r and r['vs_reference'], '.1f')} | "
                     f"{_fmt(r and r['vs_real_time'], '.3g')} |")
    for model in ("noiseless", "realistic"):
        r = next((x for x in sensor if x["what"].startswith(f"{model},") and "streams per launch" in x["what"]), None)
        label = r["what"] if r else f"{model}, S streams per launch"
        lines.append(f"| {label} | {_fmt(r and r['pixel_steps_per_s'])} | {_fmt(r and r['vs_reference'], '.1f')} | "
                     f"{_fmt(r and r['vs_real_time'], '.3g')} |")
        ref = _row_value(sensor, "sensor", f"{model}, frames every step", "numpy")
        lines.append(f"| NumPy reference, {model} | {_fmt(ref and ref['pixel_steps_per_s'])} | 1 | "
                     f"{_fmt(ref and ref['vs_real_time'], '.3g')} |")

    render = _bench_rows(summary, "bench_render")
    r = next((x for x in render if x["stage"] == "render"), None)
    lines += ["", "## Render and render + sensor", "", "| case | this run |", "|---|---|",
              f"| {r['what'] if r else 'render, Fan mono'}: ms per render | "
              f"{_fmt(r and 1e3 * r['seconds_per_render'], '.3g')} |",
              f"| render, pixel-steps/s | {_fmt(r and r['pixel_steps_per_s'])} |"]
    for label in ("frames stay on the device", "host round trip"):
        p = next((x for x in render if x["stage"] == "pipeline" and label in x["what"]), None)
        share = _fmt(p and 100 * p.get("render_share", math.nan), '.0f', ' %')
        lines.append(f"| render + sensor, {label}: pixel-steps/s (rendering share) | "
                     f"{_fmt(p and p['pixel_steps_per_s'])} ({share}) |")

    llr, rllr = _stage(summary, "llr").get("figures", {}), _stage(summary, "rllr").get("figures", {})
    lines += ["", "## Dataset generation", "", "| dataset | this run |", "|---|---|",
              f"| LLR ({llr.get('scenes', '?')} scene-lights): wall time | {_fmt(llr.get('seconds'), '.1f', ' s')} |",
              f"| LLR: per scene-light, min-max | {_fmt(llr.get('scene_seconds_min'), '.1f')}-"
              f"{_fmt(llr.get('scene_seconds_max'), '.1f')} s |",
              f"| RLLR: scenes made | {rllr.get('scenes', NOT_MEASURED)} |",
              f"| RLLR: seconds per scene (mean) | {_fmt(rllr.get('scene_seconds_mean'), '.1f', ' s')} |",
              f"| RLLR: 100 scenes, extrapolated | {_fmt(rllr.get('extrapolated_100_minutes'), '.1f', ' min')} |"]

    train = _stage(summary, "train").get("figures", {})
    lines += ["", "## Training", "", "| figure | this run |", "|---|---|",
              f"| config, precision | {train.get('config', NOT_MEASURED)}, {train.get('precision', NOT_MEASURED)} |",
              f"| samples/s (median of the steps after the first) | {_fmt(train.get('samples_per_s_steady'), '.3g')} |",
              f"| seconds per step (median; mean over the run, data loading and validation included) | "
              f"{_fmt(train.get('seconds_per_step_steady'), '.3g')} ({_fmt(train.get('seconds_per_step'), '.3g')}) |",
              f"| steps in the budget ({_fmt(train.get('budget_minutes'), '.2f', ' min')}) | {train.get('steps', NOT_MEASURED)} |",
              f"| data-wait share | {_fmt(train.get('data_wait_share'), '.2f')} |",
              f"| best validation aligned PSNR | {_fmt(train.get('best_val_psnr_aligned'), '.2f', ' dB')} |"]

    lines += _recipe_lines(_stage(summary, "recipe"))

    ev = _stage(summary, "evaluate").get("figures", {})
    methods = ev.get("methods", {})
    lines += ["", "## Evaluation on the LLR of stage llr", ""]
    if not methods:
        lines.append(NOT_MEASURED)
    else:
        names = list(methods)
        for group, title in (("ALL_low", "Low light"), ("ALL_normal", "Normal light"), ("ALL", "All scenes")):
            table = methods if group == "ALL" else ev.get("groups", {}).get(group)
            if not table:
                continue
            lines += [f"**{title}**", "", "| metric | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
            for key, label in (("psnr", "PSNR"), ("ssim", "SSIM"), ("psnr_8bit", "PSNR 8-bit"),
                               ("psnr_aligned", "PSNR aligned")):
                lines.append(f"| {label} | " + " | ".join(_fmt(table.get(m, {}).get(key), '.4g') for m in names) + " |")
            lines.append("")
        for note in ev.get("notes", []):
            lines.append(f"Note: {note}")
    lines += _tradeoff_lines(_stage(summary, "tradeoff"))
    lines += _table1_lines(_stage(summary, "table1"))
    return "\n".join(lines).rstrip() + "\n"


def _recipe_lines(stage: dict[str, Any]) -> list[str]:
    """Stage recipe: each dataset made (scenes, seconds, status) and the training run's figures."""
    fig = stage.get("figures", {})
    lines = ["", "## The shipped network's recipe at GPU scale (stage recipe)", ""]
    if not fig:
        return lines + [f"{NOT_MEASURED} ({stage.get('status', '?')}{': ' + stage['note'] if stage.get('note') else ''})"]
    lines += ["| dataset | role | scenes | seconds | status |", "|---|---|---|---|---|"]
    for name, r in fig.get("sets", {}).items():
        lines.append(f"| {name} | {r.get('role', '?')} | {r.get('scenes', '?')} | {_fmt(r.get('seconds'), '.1f')} | "
                     f"{r.get('status', '?')}{' (' + r['note'] + ')' if r.get('note') else ''} |")
    vals = fig.get("validations") or []
    lines += ["", "| figure | this run |", "|---|---|",
              f"| config, `train` options | {fig.get('config', '?')}, `{' '.join(fig.get('train_args', []))}` |",
              f"| training scenes, budget | {fig.get('data_scenes', NOT_MEASURED)}, {_fmt(fig.get('budget_minutes'), '.2f', ' min')} |",
              f"| steps, samples/s (median) | {fig.get('steps', NOT_MEASURED)}, {_fmt(fig.get('samples_per_s_steady'), '.3g')} |",
              f"| seconds per step (median) | {_fmt(fig.get('seconds_per_step_steady'), '.3g')} |",
              f"| data-wait share | {_fmt(fig.get('data_wait_share'), '.2f')} |",
              f"| validation aligned PSNR (step: dB) | {', '.join(f'{s}: {v:.2f}' for s, v in vals) or NOT_MEASURED} |",
              f"| best | {_fmt(fig.get('best_val_psnr_aligned'), '.2f', ' dB')} |"]
    return lines


def _tradeoff_lines(stage: dict[str, Any]) -> list[str]:
    """Stage tradeoff: what it measured, and the network's loss per cheap run (the CSV has all)."""
    fig = stage.get("figures", {})
    lines = ["", "## Trade study at 400 x 250 (stage tradeoff)", ""]
    if not fig.get("scene_lights"):
        return lines + [NOT_MEASURED + (f" ({stage['note']})" if stage.get("note") else "")]
    lines += [f"{len(fig['scene_lights'])} scene-light(s) ({', '.join(fig['scene_lights'])}), "
              f"{'complete' if fig.get('complete') else 'cut by its box: a later call goes on'}; every figure in "
              f"{fig.get('csv', 'tradeoff.csv')}.", "",
              "| scene-light: run | loss of TFP-205 (dB) | loss of the shipped network (dB) |", "|---|---|---|"]
    lines += [f"| {k} | {_fmt(v.get('tfp'), '.3f')} | {_fmt(v.get('net'), '.3f')} |" for k, v in fig.get("loss_db", {}).items()]
    return lines


def _table1_lines(stage: dict[str, Any]) -> list[str]:
    """Stage table1's table: per network its size, cost, training and aligned PSNR on the LLR."""
    fig = stage.get("figures", {})
    nets = fig.get("networks", {})
    lines = ["", "## Table 1 networks at equal training FLOP (stage table1)", ""]
    if not nets:
        return lines + [NOT_MEASURED + (f" ({stage['note']})" if stage.get("note") else "")]
    h, w = fig.get("frame") or ("?", "?")
    each = fig.get("train_gflop_each")
    lines += [f"Trained on {fig.get('data_scenes', '?')} RLLR scene(s) in {fig.get('precision', '?')}, each for "
              f"{_fmt(each and each / 1e3, '.4g', ' TFLOP')} of training (the steps of {fig.get('reference') or 'none'} "
              f"in its share of the box), scored on {fig.get('test_scenes', '?')} LLR scene-light(s).", "",
              f"| network | config | parameters | GFLOP per {w} x {h} frame | steps | training TFLOP | seconds | "
              "aligned PSNR low | aligned PSNR normal | note |", "|---|---|---|---|---|---|---|---|---|---|"]
    for label, n in nets.items():
        scores = n.get("scores", {})
        note = n.get("error") or n.get("note") or ("" if n.get("equal_flop", True) else "not at equal FLOP")
        params = n.get("parameters")
        lines.append(f"| {label} | {n.get('config', '?')} | {NOT_MEASURED if params is None else f'{params:,}'} | "
                     f"{_fmt(n.get('gflop_per_frame'), '.4g')} | {n.get('steps', NOT_MEASURED)} | "
                     f"{_fmt(n.get('train_gflop') and n['train_gflop'] / 1e3, '.4g')} | {_fmt(n.get('seconds'), '.1f')} | "
                     f"{_fmt(scores.get('low', {}).get('psnr_aligned'), '.2f', ' dB')} | "
                     f"{_fmt(scores.get('normal', {}).get('psnr_aligned'), '.2f', ' dB')} | {note.replace('|', '/')} |")
    return lines


__all__ = ["MAX_FILES", "MAX_FILE_BYTES", "MAX_TOTAL_BYTES", "MAX_DEPTH", "LOGS_MAX_BYTES", "out_problems",
           "check_out", "file_record", "combined_logs", "write_weights", "join_weight_parts", "report_markdown",
           "NOT_MEASURED"]
