"""The paper's three comparisons as named studies (`spikesim compare --study NAME`): which configs
train, which seedless methods stand beside them, and the paper's own figures for each row.

Every config of a study is the shipped network's size and recipe with one part swapped
(model/configs/cpu_*.json, `"base": "lrrep_cpu"`), or a published network scaled to the shipped
network's FLOP per frame, so equal steps are equal compute; the study's table states each row's
parameters, GFLOP per frame, steps, CPU minutes and seeds (model/flops.py, COMPUTE_FILE).

The paper's figures are PSNR and SSIM on its own LLR (8-bit frames, its normalisation), not on this
project's data: they sit beside ours so a reader compares orderings, not values.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence


#: Stands for `tfp:N` with N the steps one training sample of the study's networks spans (K x T).
SPAN_TFP = "tfp:span"


def resolve_baselines(baselines: Sequence[str], span_steps: int) -> list[str]:
    """The study's seedless methods with SPAN_TFP made `tfp:<span_steps>`."""
    return [f"tfp:{span_steps}" if b == SPAN_TFP else b for b in baselines]


@dataclass(frozen=True)
class StudyRow:
    """One row: a label, the config it trains (None for a seedless method, `method` then), and the
    paper's PSNR/SSIM for it (None where the paper has no such row)."""

    label: str
    config: str | None = None
    method: str | None = None
    paper_psnr: float | None = None
    paper_ssim: float | None = None


@dataclass(frozen=True)
class Study:
    name: str
    title: str
    rows: tuple[StudyRow, ...]
    baselines: tuple[str, ...] = ("tfp", SPAN_TFP)
    """Seedless methods beside the rows: plain TFP, the floor any network must clear, and TFP over the
    span the networks see (SPAN_TFP: K windows, the fair photon count; tfp:205 for the shipped K = 5);
    a study whose rows hold a TFP config leaves plain TFP out (one label, one column)."""
    orderings: tuple[tuple[str, str], ...] = field(default_factory=tuple)
    """The paper's claims as (better, worse) label pairs, each marked held / not held / within spread."""

    @property
    def configs(self) -> list[tuple[str, str]]:
        return [(r.label, r.config) for r in self.rows if r.config]



def _paper_order(rows: Sequence[StudyRow]) -> tuple[tuple[str, str], ...]:
    """Every pair the paper's PSNR orders (higher first)."""
    ranked = [r for r in rows if r.paper_psnr is not None]
    return tuple((a.label, b.label) for a in ranked for b in ranked if a.paper_psnr > b.paper_psnr)


def _study(name: str, title: str, rows: Sequence[StudyRow], baselines: Sequence[str] = ("tfp", SPAN_TFP)) -> Study:
    methods = tuple(r.method for r in rows if r.method)
    return Study(name, title, tuple(rows), methods + tuple(b for b in baselines if b not in methods),
                 _paper_order(rows))


#: Paper Table 3 (representations in its framework), Table 4 (ablation), Table 1 (methods): PSNR, SSIM.
STUDIES: dict[str, Study] = {s.name: s for s in (
    _study("representations", "Representations inside the shipped framework (paper Table 3)", [
        StudyRow("TFP", "cpu_rep_tfp", paper_psnr=38.615, paper_ssim=0.96641),
        StudyRow("TFI", "cpu_rep_tfi", paper_psnr=37.617, paper_ssim=0.93632),
        StudyRow("AST", "cpu_rep_ast", paper_psnr=37.997, paper_ssim=0.95463),
        StudyRow("AMIM", "cpu_rep_amim", paper_psnr=41.950, paper_ssim=0.97493),
        StudyRow("SALI", "cpu_rep_sali", paper_psnr=43.314, paper_ssim=0.98304),
        StudyRow("WGSE-1d", "cpu_rep_wgse1d", paper_psnr=42.302, paper_ssim=0.97438),
        StudyRow("LR-Rep", "lrrep_cpu", paper_psnr=45.075, paper_ssim=0.98681),
    ], baselines=(SPAN_TFP,)),
    _study("ablation", "The ablation at the shipped size (paper Table 4)", [
        StudyRow("A", "cpu_ablation_a", paper_psnr=42.743, paper_ssim=0.97403),
        StudyRow("B", "cpu_ablation_b", paper_psnr=44.151, paper_ssim=0.98514),
        StudyRow("C", "cpu_ablation_c", paper_psnr=44.739, paper_ssim=0.98636),
        StudyRow("D", "cpu_ablation_d", paper_psnr=44.956, paper_ssim=0.98678),
        StudyRow("E", "lrrep_cpu", paper_psnr=45.075, paper_ssim=0.98681),
        StudyRow("F", "cpu_ablation_f", paper_psnr=44.997, paper_ssim=0.98676),
    ]),
    _study("table1", "The paper's Table 1 at equal compute", [
        StudyRow("TFI", method="tfi", paper_psnr=31.409, paper_ssim=0.72312),
        StudyRow("STP", method="stp", paper_psnr=24.882, paper_ssim=0.55537),
        StudyRow("SNM", method="snm", paper_psnr=25.741, paper_ssim=0.80281),
        StudyRow("RSIR", "cpu_rsir", paper_psnr=34.121, paper_ssim=0.88337),
        StudyRow("SSML", "cpu_ssml", paper_psnr=38.432, paper_ssim=0.89942),
        StudyRow("S2I", "cpu_s2i", paper_psnr=40.883, paper_ssim=0.95915),
        StudyRow("WGSE", "cpu_wgse", paper_psnr=42.959, paper_ssim=0.97066),
        StudyRow("Ours", "lrrep_cpu", paper_psnr=45.075, paper_ssim=0.98681),
    ]),
)}

def get_study(name: str) -> Study:
    try:
        return STUDIES[name]
    except KeyError:
        raise ValueError(f"unknown study {name!r}; known: {', '.join(STUDIES)}") from None


def _cell(stats: dict[tuple[str, str, str], Any], label: str, group: str, metric: str, digits: int) -> str:
    s = stats.get((label, group, metric))
    if s is None or not math.isfinite(s.mean):
        return "n/a"
    return f"{s.mean:.{digits}f}" if s.n <= 1 else f"{s.mean:.{digits}f} ± {s.std:.{digits}f}"


def ordering_verdict(stats: dict[tuple[str, str, str], Any], better: str, worse: str, group: str,
                     metric: str = "psnr_aligned") -> str:
    """'held', 'not held' or 'within spread' for the paper's claim better > worse, from our seeds."""
    from .comparison import difference_holds
    a, b = stats.get((better, group, metric)), stats.get((worse, group, metric))
    if a is None or b is None:
        return "not measured"
    if not difference_holds(a, b):
        return "within spread"
    return "held" if a.mean > b.mean else "not held"


def study_markdown(study: Study, stat_list: Sequence[Any], costs: dict[str, dict[str, Any]],
                   labels_of: dict[str, str]) -> str:
    """The study's table: a row per method (ours: mean ± std over seeds), aligned PSNR per light first,
    the paper's 8-bit PSNR/SSIM and the paper's own figures beside them, then the cost columns; and the
    paper's orderings, each marked. `labels_of` maps a row's label to its column in the stats (a
    seedless method's column is its baseline label, e.g. STP)."""
    stats = {(s.label, s.group, s.metric): s for s in stat_list}
    groups = sorted({s.group for s in stat_list})
    low = "ALL_low" if "ALL_low" in groups else None
    normal = "ALL_normal" if "ALL_normal" in groups else None
    head = ["Method"]
    if low:
        head.append("aligned PSNR, low")
    if normal:
        head.append("aligned PSNR, normal")
    head += ["PSNR 8-bit (all)", "SSIM 8-bit (all)", "paper PSNR", "paper SSIM", "parameters",
             "GFLOP / frame", "steps", "CPU-min / run", "seeds"]
    lines = [f"**{study.title}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    rows = list(study.rows) + [r for r in _extra_rows(study, labels_of)]
    for r in rows:
        col = labels_of.get(r.label, r.label)
        cost = costs.get(r.label, {})
        cells = [r.label]
        if low:
            cells.append(_cell(stats, col, low, "psnr_aligned", 2))
        if normal:
            cells.append(_cell(stats, col, normal, "psnr_aligned", 2))
        cells += [_cell(stats, col, "ALL", "psnr_8bit", 2), _cell(stats, col, "ALL", "ssim_8bit", 4),
                  "—" if r.paper_psnr is None else f"{r.paper_psnr:.2f}",
                  "—" if r.paper_ssim is None else f"{r.paper_ssim:.4f}",
                  f"{cost['parameters']:,}" if "parameters" in cost else "—",
                  f"{cost['gflop_per_frame']:.1f}" if "gflop_per_frame" in cost else "—",
                  str(cost.get("steps", "—")),
                  f"{cost['cpu_minutes']:.1f}" if cost.get("cpu_minutes") is not None else "—",
                  str(cost.get("seeds", "—"))]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    if study.orderings:
        where = [g for g in (low, normal) if g] or ["ALL"]
        lines += ["The paper's orderings (its PSNR), on ours (aligned PSNR; a difference counts only beyond "
                  "the seeds' spread):", "", "| Paper: better > worse | " + " | ".join(where) + " |",
                  "|---|" + "---|" * len(where)]
        for better, worse in study.orderings:
            cells = [ordering_verdict(stats, labels_of.get(better, better), labels_of.get(worse, worse), g)
                     for g in where]
            lines.append(f"| {better} > {worse} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def _extra_rows(study: Study, labels_of: dict[str, str]) -> list[StudyRow]:
    """The study's fixed baselines, shown below its own rows."""
    mine = {r.label for r in study.rows}
    return [StudyRow(label) for label in labels_of if label not in mine]
