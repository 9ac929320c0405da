"""`spikesim pick-checkpoint`: pick a run's network among the checkpoints it kept at each validation
(`train --keep-validated`) by another rule than the mean that chose best.pt.

    spikesim pick-checkpoint runs/mine --rule worst                  # the best floor over every scene
    spikesim pick-checkpoint runs/mine --rule mean --set val_nat8    # one validation set's mean
    spikesim pick-checkpoint runs/mine --average 4                   # the mean of the last 4 kept weights
    spikesim evaluate --data data/val_nat8 --methods mine=runs/mine/best.pt avg=runs/mine/average_last_4.pt

It prints the best validations by the rule (step, the rule's score, the mean, the worst scene) and
writes the pick to RUN/best_<rule>[_<set>].pt (a copy of validated/step_NNNNNN.pt, written whole
or not at all), a checkpoint `evaluate`, `reconstruct` and `train --init` take as they take best.pt.
Why a rule over scenes: a dark scene whose score swings by 2-3 dB between checkpoints moves a
mean over many scenes by little (model/selection.py). --average K instead writes
RUN/average_last_K.pt, the mean of the last K kept checkpoints' weights (the tail of the run):
score it on the validation sets beside best.pt before trusting it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pipelines.argtypes import positive_int


def at_least_two(text: str) -> int:
    """--average: a count of checkpoints to average, 2 or more."""
    value = positive_int(text)
    if value < 2:
        raise argparse.ArgumentTypeError(f"must be 2 or more checkpoints to average, got {text}")
    return value


def cmd_pick(args: argparse.Namespace) -> int:
    from model.selection import PICK_RULES, average_last, averaged_name, pick_validation, picked_name
    from model.training import VALIDATED_DIR, validated_name
    from model.checkpoint import load_checkpoint
    from spikesim.outputs import atomic_write_bytes, writable

    run = Path(args.run)
    if not run.is_dir():
        raise FileNotFoundError(f"{run}: no such run folder")
    if args.average is not None:
        if args.set is not None:
            raise ValueError("--set chooses the scenes a rule scores; --average scores none")
        target = writable(run, averaged_name(args.average))
        steps = average_last(run, args.average, target)
        print(f"[pick] the mean of the weights kept at steps {', '.join(map(str, steps))}: wrote {target}; score it "
              f"on the validation sets beside best.pt (--methods NAME={target})", file=sys.stderr)
        return 0
    assert args.rule in PICK_RULES
    best, ranked = pick_validation(run, args.rule, args.set)
    where = "every validation scene" if args.set is None else f"the scenes of {args.set}"
    print(f"[pick] {run}: {len(ranked)} validation(s), rule {args.rule} over {where} (aligned PSNR, dB)", file=sys.stderr)
    print("| step | score | mean | worst | worst scene | kept |")
    print("|---:|---:|---:|---:|---|---|")
    for v in ranked[:args.top]:
        print(f"| {v.step} | {v.score:.2f} | {v.mean:.2f} | {v.worst:.2f} | {v.worst_scene} | {'yes' if v.kept else 'no'} |")
    source = run / VALIDATED_DIR / validated_name(best.step)
    target = writable(run, picked_name(args.rule, args.set))
    load_checkpoint(source)  # a damaged kept checkpoint is named here, not copied
    atomic_write_bytes(target, source.read_bytes())
    print(f"[pick] step {best.step} ({args.rule} {best.score:.2f} dB): wrote {target}; score it with "
          f"--methods NAME={target}", file=sys.stderr)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    from model.selection import PICK_RULES
    p = sub.add_parser("pick-checkpoint", help="pick a run's network among its kept checkpoints by another rule",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="a run folder trained with --keep-validated")
    how = p.add_mutually_exclusive_group(required=True)
    how.add_argument("--rule", choices=PICK_RULES,
                     help="mean: the mean over the scenes; worst: the lowest scene's score")
    how.add_argument("--average", type=at_least_two, metavar="K",
                     help="write the mean of the last K kept checkpoints' weights instead of picking one")
    p.add_argument("--set", default=None, metavar="NAME",
                   help="score only the scenes of this validation set (its folder name, as --val-data gave it)")
    p.add_argument("--top", type=positive_int, default=10, help="validations to list (best first)")
    p.set_defaults(func=cmd_pick)
