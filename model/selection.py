"""Pick a run's network among the checkpoints it kept at each validation (train.keep_validated) by
a rule over each scene's validation score (val_scenes.csv), instead of the mean that chose best.pt.

Why: best.pt is the validation with the best mean aligned PSNR over every validation scene. One
dark scene whose score swings by 2-3 dB between checkpoints moves a 16-scene mean by at most
0.2 dB, so the mean cannot see it, while a test set of six scenes with one such scene in it moves
by 0.4 dB (docs/model.md, "Picking the network by another rule"). The rules:
  mean   the mean over the scenes (over every scene: best.pt's own choice, to check the log by);
  worst  the lowest scene's score (the best floor);
each over every validation scene or over one validation set's (`set_name`: the folder the scenes
came from, the prefix of their names when a run validates on several roots). Ties go to the
earlier step, as best.pt's strict "better than" does.

Or no pick at all: the mean of the last K kept checkpoints' weights (`average_last`), the tail of
a cosine run, which smooths the step-to-step swings a single checkpoint carries (stochastic weight
averaging, Izmailov et al. 2018, "Averaging Weights Leads to Wider Optima and Better
Generalization"; the networks here hold no batch-norm statistics to recompute). Whether it pays is
a question for the validation sets: score it beside best.pt with `evaluate`.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

from spikesim.config_io import read_small_file

from .checkpoint import load_checkpoint, save_checkpoint
from .config import ExperimentConfig
from .data import scene_set
from .training import RUN_LOG_LIMIT, SCENE_LOG, VALIDATED_DIR, validated_name

#: The rules a network can be picked by.
PICK_RULES = ("mean", "worst")


@dataclass(frozen=True)
class Validation:
    """One validation of a run, scored by a rule over the scenes it was asked about."""

    step: int
    score: float
    mean: float
    worst: float
    worst_scene: str
    kept: bool  # whether its checkpoint was kept (validated/)


def read_scene_scores(run: str | Path) -> dict[int, dict[str, float]]:
    """step -> scene -> aligned PSNR (dB) from a run's val_scenes.csv. A step validated twice (a run
    resumed at an epoch's end validates again) has the same scores both times; the last row wins."""
    path = Path(run) / SCENE_LOG
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no per-scene validation log (runs validate scene by scene from "
                                "this version on; an older run has only val_log.csv)")
    text = read_small_file(path, "the run's per-scene validation log", limit=RUN_LOG_LIMIT)
    rows = list(csv.DictReader(io.StringIO(text, newline="")))
    scores: dict[int, dict[str, float]] = {}
    for n, row in enumerate(rows, start=2):
        try:
            step, scene, value = int(row["step"]), row["scene"], float(row["psnr_aligned"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{path} line {n}: expected step, scene and psnr_aligned, got {row}") from None
        if not scene or math.isnan(value):
            raise ValueError(f"{path} line {n}: scene {scene!r} has no usable score ({row['psnr_aligned']!r})")
        scores.setdefault(step, {})[scene] = value
    if not scores:
        raise ValueError(f"{path} holds no validation yet")
    return scores


def rank_validations(scores: dict[int, dict[str, float]], rule: str, set_name: str | None = None,
                     kept: set[int] | None = None) -> list[Validation]:
    """Every validation scored by `rule` over the scenes of `set_name` (all when None), best first
    (ties: the earlier step first)."""
    if rule not in PICK_RULES:
        raise ValueError(f"rule {rule!r}: expected one of {', '.join(PICK_RULES)}")
    ranked = []
    for step, by_scene in scores.items():
        chosen = {s: v for s, v in by_scene.items() if set_name is None or scene_set(s) == set_name}
        if not chosen:
            sets = sorted({scene_set(s) or "(one root: no set names)" for s in by_scene})
            raise ValueError(f"validation set {set_name!r}: no scene of the run's validation at step {step} is in it "
                             f"(its sets: {', '.join(sets)})")
        worst_scene = min(chosen, key=lambda s: (chosen[s], s))
        mean = math.fsum(chosen.values()) / len(chosen)
        worst = chosen[worst_scene]
        ranked.append(Validation(step, mean if rule == "mean" else worst, mean, worst, worst_scene,
                                 kept is None or step in kept))
    return sorted(ranked, key=lambda v: (-v.score, v.step))


def kept_steps(run: str | Path) -> set[int]:
    """The steps whose checkpoint the run kept in validated/."""
    folder = Path(run) / VALIDATED_DIR
    if not folder.is_dir():
        return set()
    steps = set()
    for p in folder.glob("step_*.pt"):
        digits = p.stem[len("step_"):]
        if digits.isdigit() and p.name == validated_name(int(digits)) and p.is_file():
            steps.add(int(digits))
    return steps


def picked_name(rule: str, set_name: str | None = None) -> str:
    """The file a pick is written to in the run folder: best_<rule>[_<set>].pt."""
    return f"best_{rule}{'' if set_name is None else '_' + set_name}.pt"


def pick_validation(run: str | Path, rule: str, set_name: str | None = None) -> tuple[Validation, list[Validation]]:
    """The best validation by `rule` among those whose checkpoint was kept, and every validation
    ranked (kept or not, so a table can show what was skipped)."""
    kept = kept_steps(run)
    ranked = rank_validations(read_scene_scores(run), rule, set_name, kept)
    usable = [v for v in ranked if v.kept]
    if not usable:
        raise FileNotFoundError(f"{Path(run) / VALIDATED_DIR}: no kept checkpoint of a logged validation (train "
                                "with --keep-validated to keep one at each validation)")
    return usable[0], ranked


def averaged_name(count: int) -> str:
    """The file the mean of the last `count` kept checkpoints is written to in the run folder."""
    return f"average_last_{count}.pt"


def average_last(run: str | Path, count: int, out: str | Path) -> list[int]:
    """Write to `out` a checkpoint whose weights are the mean of the last `count` kept checkpoints'
    (no optimiser state: a network to score or fine-tune, not a run to resume); returns their steps.
    Every one must hold the same model config, so the mean is of one architecture's weights."""
    import torch

    if not (isinstance(count, int) and count >= 2):
        raise ValueError(f"average: expected at least 2 checkpoints, got {count!r}")
    steps = sorted(kept_steps(run))
    if len(steps) < count:
        raise ValueError(f"{Path(run) / VALIDATED_DIR}: {len(steps)} kept checkpoint(s), fewer than the {count} to "
                         "average (train with --keep-validated, and validate that often)")
    steps = steps[-count:]
    total: dict[str, torch.Tensor] = {}
    first = None
    for step in steps:
        state = load_checkpoint(Path(run) / VALIDATED_DIR / validated_name(step))
        if first is None:
            first = state
        elif state["experiment"]["model"] != first["experiment"]["model"]:
            raise ValueError(f"{Path(run) / VALIDATED_DIR / validated_name(step)}: another model config than "
                             f"{validated_name(steps[0])}'s; only one network's checkpoints can be averaged")
        for key, value in state["model_state"].items():
            total[key] = total[key] + value.double() if key in total else value.double()
    assert first is not None
    mean = {key: (value / count).to(first["model_state"][key].dtype) for key, value in total.items()}
    experiment = ExperimentConfig.from_dict(first["experiment"])
    from .arch import build_model
    model = build_model(experiment.model)
    model.load_state_dict(mean)
    save_checkpoint(out, model, experiment, epoch=int(state["epoch"]), step=int(state["step"]),
                    extra={"averaged_steps": steps})
    return steps
