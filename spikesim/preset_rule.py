"""The `fast` quality's render knobs, derived by a stated rule from the trade study measured at
the paper's 400 x 250 (`spikesim tradeoff`, its CSV shipped as spikesim/data/tradeoff_400.csv).

The rule, for a tolerance `tol_db` (FAST_TOLERANCE_DB, 0.2 dB, for `fast`):

- **Light classes.** The study's scene-lights fall into two light levels (the median of the
  reference ground truth, `ref_y_median`, spikes per step): the LLR's low light (about 1e-3) and
  normal light (about 1e-1). The split is the geometric mean of the brightest low-light and the
  darkest normal-light scene-light; the classes must not overlap.
- **Frame samples per class.** The fewest samples per pixel per step (a fresh render seed at every
  step, a render every step) whose loss of aligned PSNR against the reference run (TFP-205 and the
  shipped network, scored on the reference's ground truth) is within the larger of the study's
  noise floor (another sensor or render seed) and `tol_db`, in every scene of the class. Why it
  depends on light: Monte Carlo noise that is fresh at every step adds variance to a window's
  charge as shot noise does; its share of the charge variance grows with the light level
  (relative Monte Carlo variance c / spp of a per-step charge y against shot-noise variance
  y / N_e: a ratio y c N_e / spp), so dark scenes need fewer samples.
- **Ground-truth samples.** The ground truth's own error adds to every score's squared error:
  a reconstruction of aligned PSNR R scored against a ground truth of error e_gt loses
  10 log10(1 + e_gt / e_R) dB, e_R = 10^(-R / 10). The study measures e_gt at two sample counts
  against its reference ground truth (S samples); with variances going as 1 / spp, the
  single-sample error is e1 = e_self / (1 / s + 1 / S). The rule takes, per light class, the least
  power of two whose loss is within `tol_db` for the best reference score of every scene-light
  of the class (low light scores lower, so its ground truth can be noisier), and at most S: the
  study cannot vouch for a ground truth better than the one its scores are measured against
  (at S = 128 that one already costs Ball's 32.9 dB in normal light about 0.3 dB).

`choose_fast()` applies it; tests/test_preset_rule.py checks that `spikesim.quality.PRESETS`
holds what it returns, so a new study (a new CSV) changes the preset only through this rule.
"""
from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

from spikesim.tradeoff import RECON_AXES

#: The 400 x 250 study the presets were chosen from (`spikesim tradeoff --height 250 --width 400
#: --windows 5 --ref-spp 32 --gt-spp 128 --knobs spp seeds --gt-error-spp 16 64`).
STUDY_CSV = Path(__file__).parent / "data" / "tradeoff_400.csv"
#: The loss of aligned PSNR `fast` accepts beyond the noise floor: under the 0.3 dB by which the
#: shipped network's recipe, retrained with another seed, moves its LLR score (docs/model.md, the
#: factor study: 0.01-0.3 dB over 3 seeds), so data made at `fast` rank methods as reference data
#: do, up to retraining noise. At 0.1 dB the rule asks 16 spp in normal light (Car's 0.19 dB loss
#: at 4 spp decides), which puts the paper LLR past 10 minutes on 2 cores (docs/tradeoff.md s. 7).
FAST_TOLERANCE_DB = 0.2
_SPP_RUN = re.compile(r"^spp=(\d+)$")


@dataclass(frozen=True)
class LightRuleChoice:
    """What the rule chose, with the figures that decided it (for docs and meta.json)."""

    low_light_y: float
    """Split between the light classes (spikes per step, the probe frame's median)."""
    low_light_spp: int
    low_light_gt_spp: int
    spp: int
    """Samples per pixel per step above the split (normal light)."""
    gt_spp: int
    tolerance_db: float
    evidence: dict[str, Any] = field(default_factory=dict, compare=False)


def load_study(path: str | Path = STUDY_CSV) -> list[dict[str, Any]]:
    """The study's rows with numbers parsed (empty cells: NaN)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"trade study CSV {path} not found (write one with `spikesim tradeoff`)")
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or "ref_y_median" not in rows[0]:
        raise ValueError(f"{path}: not a trade study CSV with a ref_y_median column (rebuild it with "
                         "`spikesim tradeoff ... --report-only`)")
    out = []
    for r in rows:
        parsed: dict[str, Any] = {}
        for k, v in r.items():
            try:
                parsed[k] = float(v) if v != "" else math.nan
            except ValueError:
                parsed[k] = v
        out.append(parsed)
    return out


def _scene_lights(rows: Iterable[dict[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    out: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        if r["knob"] != "gt":
            out.setdefault((r["scene"], r["light"]), []).append(r)
    return out


def light_split(rows: Sequence[dict[str, Any]]) -> float:
    """The geometric mean of the brightest low-light and the darkest normal-light scene-light."""
    levels: dict[str, list[float]] = {}
    for (_, light), block in _scene_lights(rows).items():
        levels.setdefault(light, []).append(float(block[0]["ref_y_median"]))
    if set(levels) != {"low", "normal"}:
        raise ValueError(f"the study needs both lights, low and normal; it has {sorted(levels)}")
    lo, hi = max(levels["low"]), min(levels["normal"])
    if not (0 < lo < hi):
        raise ValueError(f"the light classes overlap: brightest low light y={lo:g}, darkest normal y={hi:g}")
    return math.sqrt(lo * hi)


def _within(row: dict[str, Any], tol_db: float) -> bool:
    for a in RECON_AXES:
        loss, floor = -float(row[f"{a}_gt_dpsnr"]), float(row[f"{a}_gt_floor"])
        if not (math.isfinite(loss) and math.isfinite(floor)) or loss > max(floor, tol_db):
            return False
    return True


def cheapest_spp(rows: Sequence[dict[str, Any]], light: str, tol_db: float) -> tuple[int, dict[str, Any]]:
    """The fewest samples per step within the tolerance in every scene of `light` (see the module)."""
    blocks = {k: v for k, v in _scene_lights(rows).items() if k[1] == light}
    if not blocks:
        raise ValueError(f"the study has no {light!r} light")
    by_spp: dict[int, dict[str, dict[str, Any]]] = {}
    for (scene, _), block in blocks.items():
        for r in block:
            if (m := _SPP_RUN.match(str(r["run"]))):
                by_spp.setdefault(int(m.group(1)), {})[scene] = r
    scenes = sorted(s for s, _ in blocks)
    for spp in sorted(by_spp):
        runs = by_spp[spp]
        if all(s in runs and _within(runs[s], tol_db) for s in scenes):
            return spp, {s: {a: round(-float(runs[s][f"{a}_gt_dpsnr"]), 3) for a in RECON_AXES} for s in scenes}
    raise ValueError(f"no measured spp keeps {light} light within {tol_db} dB (or the floor) in every scene "
                     f"({', '.join(scenes)}); measured spp: {sorted(by_spp)}")


def gt_spp_needed(rows: Sequence[dict[str, Any]], light: str, tol_db: float) -> tuple[int, dict[str, Any]]:
    """The least power of two whose ground-truth error costs at most `tol_db` of the best reference
    score of every scene-light of `light` (see the module)."""
    gt_ref = {(r["scene"], r["light"]): float(r["gt_spp"]) for r in rows
              if r["knob"] == "gt" and float(r["gt_self_err"]) == 0.0}
    e1: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        key = (r["scene"], r["light"])
        if r["knob"] == "gt" and key in gt_ref and math.isfinite(float(r["gt_self_psnr"])):
            s, big = float(r["gt_spp"]), gt_ref[key]
            e1.setdefault(key, []).append(10 ** (-float(r["gt_self_psnr"]) / 10) / (1 / s + 1 / big))
    need, evidence = 1.0, {}
    blocks = {k: v for k, v in _scene_lights(rows).items() if k[1] == light}
    if not blocks:
        raise ValueError(f"the study has no {light!r} light")
    for key, block in blocks.items():
        if key not in e1:
            raise ValueError(f"{key[0]}, {key[1]}: no ground-truth error rows (knob gt) in the study")
        best = max(float(r[f"{a}_gt_psnr"]) for r in block if r["knob"] == "reference" for a in RECON_AXES)
        e_r = 10 ** (-best / 10)
        spp = max(e1[key]) / (e_r * (10 ** (tol_db / 10) - 1))
        need = max(need, spp)
        evidence[f"{key[0]}_{key[1]}"] = {"best_reference_psnr": round(best, 2), "spp_needed": round(spp, 1)}
    cap = min(gt_ref[k] for k in blocks)
    return int(min(2 ** math.ceil(math.log2(need)), cap)), {**evidence, f"cap_{light}": int(cap)}


def choose_fast(rows: Sequence[dict[str, Any]] | None = None, tol_db: float = FAST_TOLERANCE_DB) -> LightRuleChoice:
    """The rule applied to the study (default: the shipped CSV)."""
    if not (math.isfinite(tol_db) and tol_db > 0):
        raise ValueError(f"tol_db={tol_db!r} must be a positive number of dB")
    rows = load_study() if rows is None else rows
    low, low_ev = cheapest_spp(rows, "low", tol_db)
    normal, normal_ev = cheapest_spp(rows, "normal", tol_db)
    gt_low, gt_low_ev = gt_spp_needed(rows, "low", tol_db)
    gt, gt_ev = gt_spp_needed(rows, "normal", tol_db)
    split = light_split(rows)
    return LightRuleChoice(float(f"{split:.3g}"), low, gt_low, normal, gt, tol_db,
                           {"loss_db_low": low_ev, "loss_db_normal": normal_ev, "gt": {**gt_low_ev, **gt_ev}})


__all__ = ["STUDY_CSV", "FAST_TOLERANCE_DB", "LightRuleChoice", "load_study", "light_split", "cheapest_spp",
           "gt_spp_needed", "choose_fast"]
