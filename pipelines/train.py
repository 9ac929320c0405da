"""`spikesim train`: train a reconstruction network on a dataset in the project's layout.

The default config ("full") is the paper's recipe: 41-step windows, 64x64 random crops, batch 8,
K = 21 consecutive windows, Adam (0.9, 0.99), lr 1e-4 x0.1 at epoch 70 of 100, L1 summed over the
K windows. Writes <out>/last.pt (every ckpt_every epochs and on stopping; atomic), <out>/best.pt
(best validation aligned PSNR), <out>/train_log.csv, <out>/val_log.csv, <out>/val_scenes.csv (each
validation scene's aligned PSNR), <out>/tb/ (TensorBoard) and <out>/config.json (with --keep-validated
also <out>/validated/, a checkpoint per validation, for `spikesim pick-checkpoint`); `--resume` continues from <out>/last.pt exactly where it stopped. Precision:
bf16 autocast on GPUs that support it, fp32 on the CPU, `--precision` to choose (model/precision.py).
The loop itself is model/training.py; this module parses arguments and prints.
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from model.config import LR_SCHEDULES, ExperimentConfig, available_configs, load_config
from model.data import open_scenes, shared_scenes, split_scenes
from model.precision import PRECISIONS, resolve_precision
from model.training import resolve_device, run_training
from model.threads import set_cpu_threads
from pipelines.argtypes import seed_int, add_threads_argument, nonnegative_int, positive_float, positive_int
from spikesim.config_io import standard_json

__all__ = ["add_parser", "cmd_train", "resolve_device", "run_training"]


def _apply_overrides(exp: ExperimentConfig, args: argparse.Namespace) -> ExperimentConfig:
    mapping = {"epochs": "epochs", "max_steps": "max_steps", "batch_size": "batch_size",
               "num_windows": "num_windows", "crop": "crop", "lr": "lr", "seed": "seed",
               "num_workers": "num_workers", "samples_per_epoch": "samples_per_epoch", "val_crop": "val_crop",
               "ckpt_every_steps": "ckpt_every_steps", "budget_minutes": "budget_minutes",
               "lr_schedule": "lr_schedule"}
    changes = {field: getattr(args, arg) for arg, field in mapping.items() if getattr(args, arg, None) is not None}
    if getattr(args, "precision", None) is not None:
        changes["precision"] = args.precision
    if getattr(args, "no_amp", False):
        changes["precision"] = "fp32"
    if getattr(args, "keep_validated", False):
        changes["keep_validated"] = True
    return dataclasses.replace(exp, train=dataclasses.replace(exp.train, **changes)) if changes else exp


def resumed_experiment(out: Path, config: str | None) -> ExperimentConfig:
    """The config a run in `out` was started with (its last.pt), so that `--resume` alone continues
    the same plan: its length (max_steps, epochs, budget) included. Flags given with --resume
    still override the fields a resumed run may change (a longer --max-steps extends it)."""
    from model.checkpoint import load_checkpoint
    last = out / "last.pt"
    if not last.is_file():
        raise FileNotFoundError(f"--resume: no checkpoint at {last} (a run folder holds last.pt from its first "
                                "checkpoint on; start the run without --resume)")
    state = load_checkpoint(last, "cpu")
    try:
        saved = ExperimentConfig.from_dict(state["experiment"], where=f"{last} experiment")
    except (KeyError, TypeError) as exc:
        raise ValueError(f"--resume: {last} holds no valid config ({exc})") from None
    if config is not None and config != saved.name:
        given = load_config(config)
        if (given.model, given.name) != (saved.model, saved.name):
            raise ValueError(f"--resume: {last} is a run of config {saved.name!r}, not {config!r}; drop --config "
                             "(a resumed run takes its own) or start a new run in another --out")
    return saved


def cmd_train(args: argparse.Namespace) -> int:
    dev = resolve_device(args.device)  # before any work: a missing GPU is one line, not a late traceback
    set_cpu_threads(args.threads)  # before any torch work; the run log says how many and why
    if args.resume:
        out = Path(args.out) if args.out else Path("runs") / (args.config or "full")
        exp = _apply_overrides(resumed_experiment(out, args.config), args)
    else:
        exp = _apply_overrides(load_config(args.config or "full"), args)
        out = Path(args.out) if args.out else Path("runs") / exp.name
    resolve_precision(exp.train.precision, dev)  # bf16 on a GPU without it: one line, before any work
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(out, [*args.data, *(args.val_data or [])])
    scenes = open_scenes(args.data)
    if args.val_data:
        train_scenes, val_scenes = scenes, open_scenes(args.val_data)
        if both := shared_scenes(train_scenes, val_scenes):  # best.pt chose by training-set scores (round six)
            raise ValueError(f"--val-data: {len(both)} scene(s) are also in --data ({', '.join(both[:3])}"
                             f"{' ...' if len(both) > 3 else ''}): validation on training scenes measures "
                             "nothing held out; give other scenes, or no --val-data (a split of --data)")
    else:
        train_scenes, val_scenes = split_scenes(scenes, exp.train.val_fraction, exp.train.val_scenes, exp.train.seed,
                                                window=exp.model.window, num_windows=exp.train.num_windows)
    summary = run_training(exp, train_scenes, val_scenes, out, args.device, args.resume, progress=not args.quiet,
                           overwrite=args.overwrite, init=args.init)
    if summary.get("rank", 0) == 0:  # under torchrun one summary, rank 0's (the others hold no validation)
        print(standard_json({k: v for k, v in summary.items() if k != "rank"}, indent=2, default=str))
    # stopped by a signal: last.pt is written; the status says which (128 + its number), as a shell does
    return {"SIGINT": 130, "SIGTERM": 143}.get(summary["stopped_by"], 0)


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `train` on the CLI's subparsers."""
    p = subparsers.add_parser("train", help="train the reconstruction network",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default=None,
                   help=f"named config ({', '.join(available_configs())}) or a JSON file (default: full; with "
                        "--resume, the run's own, from its last.pt)")
    p.add_argument("--data", required=True, nargs="+", metavar="ROOT",
                   help="dataset root (project layout: manifest.json, <scene>/...); several roots train on all their "
                        "scenes, named <root folder>:<scene>")
    p.add_argument("--val-data", nargs="+", metavar="ROOT",
                   help="separate validation dataset root(s) (default: split --data by scene)")
    p.add_argument("-o", "--out", help="run folder (default: runs/<config name>)")
    resume = p.add_mutually_exclusive_group()
    resume.add_argument("--resume", action="store_true",
                        help="continue from <out>/last.pt with the run's own config and plan (its length, budget and "
                             "schedule), bit for bit; the data flags must name the same data")
    resume.add_argument("--overwrite", action="store_true",
                        help="replace the run in --out (its checkpoints, logs and config); without it a folder "
                             "holding a run is refused")
    p.add_argument("--init", metavar="WEIGHTS",
                   help="start from these weights instead of a random draw (fine-tuning): a shipped network "
                        "(lrrep) or a checkpoint; its model section must equal the config's (not with --resume)")
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N or mps")
    add_threads_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    g = p.add_argument_group("overrides of the config's train section (default: the config's value)")
    g.add_argument("--epochs", type=positive_int, help="passes over the training samples")
    g.add_argument("--max-steps", type=positive_int, help="stop after this many optimiser steps")
    g.add_argument("--budget-minutes", type=positive_float,
                   help="wall-clock budget: the steps that fit it are planned from the rate of the first steps, "
                        "and a cosine schedule ends its decay there (a resumed run keeps the plan)")
    g.add_argument("--lr-schedule", choices=LR_SCHEDULES,
                   help="multistep (the paper's: x lr_gamma at the milestone epochs) or cosine (per step, to the "
                        "run's last step)")
    g.add_argument("--batch-size", type=positive_int, help="samples per step, over all processes (torchrun)")
    g.add_argument("--num-windows", type=positive_int, help="K, consecutive windows per sample")
    g.add_argument("--crop", type=positive_int, help="side of the random training crop, pixels")
    g.add_argument("--val-crop", type=positive_int, help="side of the central validation crop, pixels")
    g.add_argument("--lr", type=positive_float, help="Adam learning rate")
    g.add_argument("--seed", type=seed_int, help="seed of the weights, the sample order and the crops")
    g.add_argument("--num-workers", type=nonnegative_int, help="data-loader processes (0: load in the training process)")
    g.add_argument("--samples-per-epoch", type=positive_int, help="random samples drawn per epoch (default: every start once)")
    g.add_argument("--keep-validated", action="store_true",
                   help="also keep the checkpoint of every validation in <out>/validated/, beside the per-scene "
                        "scores of <out>/val_scenes.csv, to pick the network by another rule afterwards "
                        "(spikesim pick-checkpoint)")
    g.add_argument("--ckpt-every-steps", type=positive_int,
                   help="also write last.pt every this many steps (a run cut anywhere then loses at most that many)")
    prec = g.add_mutually_exclusive_group()
    prec.add_argument("--precision", choices=PRECISIONS,
                      help="auto (the config's default: bf16 autocast on a GPU that supports it, fp16 on an older "
                           "one, fp32 on the CPU), bf16, fp16 (autocast + GradScaler) or fp32")
    prec.add_argument("--no-amp", action="store_true", help="the same as --precision fp32")
    p.set_defaults(func=cmd_train)
    return p
