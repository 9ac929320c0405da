"""The `fast` quality's render knobs, derived by a stated rule from the trade study measured at
the paper's 400 x 250 (`spikesim tradeoff`, its CSV shipped as spikesim/data/tradeoff_400.csv).

The rule, for a tolerance `tol_db` (FAST_TOLERANCE_DB, 0.2 dB, for `fast`):

- **Samples per step, per scene, from its Monte Carlo ratio.** With a fresh render seed at every
  step, Monte Carlo noise adds variance to a window's charge as shot noise does, so its cost to a
  reconstruction grows with its variance against the shot noise's: the Monte Carlo ratio
  rho = N_e mean(var_1spp) / mean(y) of probe renders (spikesim.quality.monte_carlo_ratio; the
  study's column `ref_mc_ratio`, read from spectral probes as its spp runs rendered), and it falls
  as 1 / spp. So each scene-light's loss at 1 spp against an infinite-sample reference is
  L1 = loss(1 spp) / (1 - 1 / ref_spp) (its reference renders ref_spp), and the rule takes
  a = max L1 / rho over the scene-lights whose 1-spp loss is beyond both the noise floor and
  `tol_db` (on either axis, TFP-205 and the shipped network): the worst loss per unit of ratio
  among the scenes that need more than 1 spp. A scene within the tolerance at 1 spp already gets
  what it needs (1 spp or more) from any a; its loss is mostly the sensor's noise (a 0.06 dB
  "loss" of a dark scene of ratio 0.27 would claim a slope of 0.24 dB per unit, seven times the
  slope of every scene that does lose). A scene of ratio rho
  then gets the fewest samples with a rho / spp <= tol_db (whole samples), at most the most the
  study measured (spikesim.quality.SampleRule). Why not the light level (the rule before): in the
  study, light level and ratio moved together (dark scenes had ratios 0.1-1.4, bright ones 6-140),
  but out of sample two dark random scenes of ratio 28-30 lost 0.7-1.3 dB at 1 spp while two of
  ratio 0.7-1.3 lost nothing (docs/tradeoff.md section 7).
- **Ground-truth samples.** The ground truth's own error adds to every score's squared error:
  a reconstruction of aligned PSNR R scored against a ground truth of error e_gt loses
  10 log10(1 + e_gt / e_R) dB, e_R = 10^(-R / 10). The study measures e_gt at two sample counts
  against its reference ground truth (S samples); with variances going as 1 / spp, the
  single-sample error is e1 = e_self / (1 / s + 1 / S). The rule takes the least power of two
  whose loss is within `tol_db` for the best reference score of every scene-light, and at most S:
  the study cannot vouch for a ground truth better than the one its scores are measured against
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

#: The reconstruction axes of the trade study (pipelines/tradeoff_study.py): TFP over the study's
#: span of steps and the shipped network.
RECON_AXES = ("tfp", "net")

#: The 400 x 250 study the presets were chosen from (`spikesim tradeoff --height 250 --width 400
#: --windows 5 --ref-spp 32 --gt-spp 128 --knobs spp seeds --gt-error-spp 16 64`).
STUDY_CSV = Path(__file__).parent / "data" / "tradeoff_400.csv"
#: The rule's out-of-sample check set, in the study's columns (light "rllr"): 4 random RLLR scenes
#: at 200 x 125 (dataset seed 7) at 1 and 4 spp against 16 spp (logs of the session that built the
#: rule: `spikesim generate rllr --preset paper --gt-stride 41 --count 4 --scales 0.5 --seed 7`
#: with `--quality fast` when it meant 1 spp here, `--spp 4`, `--spp 16 --gt-spp 128`; then
#: `spikesim evaluate --methods tfp tfp:205 lrrep`). Its scenes are more sensitive to Monte Carlo
#: noise per unit of ratio than the study's (0.048 against 0.027 dB), so it takes part in the slope.
CHECK_CSV = Path(__file__).parent / "data" / "rllr_check_200.csv"
#: The loss of aligned PSNR `fast` accepts beyond the noise floor: under the 0.3 dB by which the
#: shipped network's recipe, retrained with another seed, moves its LLR score (docs/model.md, the
#: factor study: 0.01-0.3 dB over 3 seeds), so data made at `fast` rank methods as reference data
#: do, up to retraining noise. At 0.1 dB every scene's samples double (the slope is the same), which
#: puts the paper LLR far past 10 minutes on 2 cores (docs/tradeoff.md section 7).
FAST_TOLERANCE_DB = 0.2
_SPP_RUN = re.compile(r"^spp=(\d+)$")


@dataclass(frozen=True)
class FastChoice:
    """What the rule chose, with the figures that decided it (for docs and tests)."""

    loss_db_per_ratio: float
    """a: the largest 1-spp loss per unit of Monte Carlo ratio (dB), rounded up to 3 decimals."""
    max_spp: int
    """The most samples per step the study measured: the rule's cap."""
    gt_spp: int
    tolerance_db: float
    evidence: dict[str, Any] = field(default_factory=dict, compare=False)


def load_study(path: str | Path = STUDY_CSV) -> list[dict[str, Any]]:
    """The study's rows (or the check set's: CHECK_CSV) with numbers parsed (empty cells: NaN)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"trade study CSV {path} not found (write one with `spikesim tradeoff`)")
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    missing = [c for c in ("ref_mc_ratio", "ref_spp") if not rows or c not in rows[0]]
    if missing:
        raise ValueError(f"{path}: not a trade study CSV with the columns {', '.join(missing)} (run "
                         "`spikesim tradeoff` again with the study's options: it renders only the probes)")
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


def _spp_runs(block: Sequence[dict[str, Any]]) -> dict[int, dict[str, Any]]:
    return {int(m.group(1)): r for r in block if (m := _SPP_RUN.match(str(r["run"])))}


def _loss(row: dict[str, Any], axis: str) -> float:
    return -float(row[f"{axis}_gt_dpsnr"])


def loss_per_ratio(rows: Sequence[dict[str, Any]], tol_db: float) -> tuple[float, dict[str, Any]]:
    """a = max L1 / rho over the scene-lights whose 1-spp loss is beyond the noise floor and
    `tol_db` (see the module), with each scene-light's figures."""
    best, evidence = 0.0, {}
    for (scene, light), block in sorted(_scene_lights(rows).items()):
        runs = _spp_runs(block)
        if 1 not in runs:
            raise ValueError(f"{scene}, {light}: the study has no spp=1 run (knob spp)")
        r, rho, ref_spp = runs[1], float(block[0]["ref_mc_ratio"]), float(block[0]["ref_spp"])
        if not (math.isfinite(rho) and rho >= 0 and math.isfinite(ref_spp) and ref_spp > 1):
            raise ValueError(f"{scene}, {light}: ref_mc_ratio={rho!r}, ref_spp={ref_spp!r}; run the study again")
        losses = [_loss(r, a) for a in RECON_AXES if math.isfinite(_loss(r, a))]
        l1 = max(losses, default=0.0) / (1 - 1 / ref_spp)
        counts = any(_loss(r, a) > max(float(r[f"{a}_gt_floor"]), tol_db) for a in RECON_AXES)
        evidence[f"{scene}_{light}"] = {"mc_ratio": round(rho, 3), "loss_1spp_db": round(l1, 3), "counts": counts}
        if counts and rho > 0:
            best = max(best, l1 / rho)
    if best == 0.0:
        raise ValueError(f"no scene-light of the study loses more than its noise floor and {tol_db} dB at 1 spp: "
                         "the study cannot measure what Monte Carlo noise costs")
    rounded = math.ceil(best * 1000) / 1000  # 3 decimals, rounded up: never below the measured worst
    return rounded, evidence


def gt_spp_needed(rows: Sequence[dict[str, Any]], tol_db: float, light: str | None = None) -> tuple[int, dict[str, Any]]:
    """The least power of two whose ground-truth error costs at most `tol_db` of the best reference
    score of every scene-light (of `light`, if given; see the module)."""
    gt_ref = {(r["scene"], r["light"]): float(r["gt_spp"]) for r in rows
              if r["knob"] == "gt" and float(r["gt_self_err"]) == 0.0}
    e1: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        key = (r["scene"], r["light"])
        if r["knob"] == "gt" and key in gt_ref and math.isfinite(float(r["gt_self_psnr"])):
            s, big = float(r["gt_spp"]), gt_ref[key]
            e1.setdefault(key, []).append(10 ** (-float(r["gt_self_psnr"]) / 10) / (1 / s + 1 / big))
    need, evidence = 1.0, {}
    blocks = {k: v for k, v in _scene_lights(rows).items() if light is None or k[1] == light}
    if not blocks:
        raise ValueError(f"the study has no {light!r} light" if light else "the study has no runs")
    for key, block in blocks.items():
        if key not in e1:
            raise ValueError(f"{key[0]}, {key[1]}: no ground-truth error rows (knob gt) in the study")
        best = max(float(r[f"{a}_gt_psnr"]) for r in block if r["knob"] == "reference" for a in RECON_AXES)
        e_r = 10 ** (-best / 10)
        spp = max(e1[key]) / (e_r * (10 ** (tol_db / 10) - 1))
        need = max(need, spp)
        evidence[f"{key[0]}_{key[1]}"] = {"best_reference_psnr": round(best, 2), "spp_needed": round(spp, 1)}
    cap = min(gt_ref[k] for k in blocks)
    return int(min(2 ** math.ceil(math.log2(need)), cap)), {**evidence, "cap": int(cap)}


def choose_fast(rows: Sequence[dict[str, Any]] | None = None, check: Sequence[dict[str, Any]] | None = None,
                tol_db: float = FAST_TOLERANCE_DB) -> FastChoice:
    """The rule applied to the study and the check set (default: the shipped CSVs): the slope
    from both, the cap and the ground truth from the study."""
    if not (math.isfinite(tol_db) and tol_db > 0):
        raise ValueError(f"tol_db={tol_db!r} must be a positive number of dB")
    rows = load_study() if rows is None else rows
    check = load_study(CHECK_CSV) if check is None else check
    a, ratio_ev = loss_per_ratio([*rows, *check], tol_db)
    measured = sorted({spp for block in _scene_lights(rows).values() for spp in _spp_runs(block)})
    gt, gt_ev = gt_spp_needed(rows, tol_db)
    return FastChoice(a, measured[-1], gt, tol_db, {"scenes": ratio_ev, "gt": gt_ev})


__all__ = ["STUDY_CSV", "CHECK_CSV", "FAST_TOLERANCE_DB", "FastChoice", "load_study", "loss_per_ratio", "gt_spp_needed",
           "choose_fast"]
