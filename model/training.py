"""Training as a library: one run of a reconstruction network on scenes in the project's layout
(`run_training`), its resume, validation, logs and the device it runs on. `spikesim train`
(pipelines/train.py) only parses arguments and prints; a notebook calls `run_training` directly.

A run folder holds last.pt (atomic; at epoch ends, every ckpt_every_steps, and when stopped),
best.pt (best validation aligned PSNR), train_log.csv, val_log.csv, val_scenes.csv (each validation
scene's score), tb/, config.json and, with train.keep_validated, validated/ (a checkpoint per
validation, for model/selection.py); a resumed
run continues bit for bit, and a wall-clock budget is planned into steps once and kept
(`_BudgetPlan`). What each file and option means for a user: `spikesim train --help`.
"""
from __future__ import annotations

import csv
import dataclasses
import errno
import hashlib
import io
import json
import math
import os
import random
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader

from .arch import build_model, count_parameters, trainable_parameters
from .checkpoint import load_checkpoint, save_checkpoint, state_fingerprint
from .config import ExperimentConfig
from .data import Scene, SequenceDataset, TimeSlice, shared_scenes, stream_sha256
from .losses import SELF_SUPERVISED, SelfSupervisedObjective, build_loss
from .metrics import psnr, psnr_aligned, ssim
from .precision import autocast, grad_scaler, resolve_precision
from .representations import tfp_windows
from .threads import describe_threads
from spikesim._optional import require
from spikesim.config_io import file_problem, read_small_file
from spikesim.outputs import (append_text, atomic_write_json, atomic_write_text, make_dirs, output_folder, remove,
                              writable)


def seed_everything(seed: int) -> None:
    """Python, NumPy and torch (CPU and CUDA) generators from one seed."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def _worker_init(worker_id: int) -> None:
    s = torch.initial_seed() % 2**32
    random.seed(s)
    np.random.seed(s)


DEVICES = "auto, cpu, cuda, cuda:N or mps"


def resolve_device(name: str, what: str = "--device") -> torch.device:
    """The torch device for --device: auto (CUDA when torch sees one, else CPU), cpu, cuda,
    cuda:N or mps. A name torch does not know is a ValueError; a device this machine lacks is an
    UnavailableError, both naming `what`: the flag, or the Python argument (`device`)."""
    from spikesim.errors import UnavailableError

    flag = what.startswith("--")
    given = f"{what} {name}" if flag else f"{what}={name!r}"
    instead = f"use {what} cpu or auto" if flag else f"use {what}='cpu' or 'auto'"
    if isinstance(name, torch.device):
        name = str(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name) if isinstance(name, str) else None  # 0 was taken as CUDA device 0
    except (RuntimeError, ValueError, TypeError):
        dev = None
    if dev is None or dev.type not in ("cpu", "cuda", "mps") or (dev.type != "cuda" and dev.index not in (None, 0)):
        # "cpu:1" and the meta device reached the loader, which then blamed the weights (round seven)
        raise ValueError(f"{what} {name!r} is not a device; expected {DEVICES}" if flag else
                         f"{given} is not a device; expected {DEVICES}")
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "a CPU-only build"
            raise UnavailableError(f"{given} asked for, but torch sees no CUDA device (torch "
                                   f"{torch.__version__}, {build}); {instead}")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise UnavailableError(f"{given} asked for, but torch sees only "
                                   f"{torch.cuda.device_count()} CUDA device(s)")
    if dev.type == "mps" and not torch.backends.mps.is_available():
        raise UnavailableError(f"{given} asked for, but torch sees no MPS device; {instead}")
    return dev


class TrainingDiverged(ValueError):
    """The loss stopped being a finite number: bad input to the run (its learning rate, usually),
    reported in one line like any other, not a traceback."""


def _csv_text(rows: Sequence[Sequence[Any]]) -> str:
    buf = io.StringIO(newline="")
    csv.writer(buf).writerows(rows)
    return buf.getvalue()


#: A run's log is a row per step: 100 MiB is millions of steps; a larger "log" is not one.
RUN_LOG_LIMIT = 100 << 20


class _CsvLog:
    """Append-only CSV with a fixed header (kept across resumes); never written through a link,
    and a full disk names the file (spikesim.outputs)."""

    LIMIT = RUN_LOG_LIMIT

    def __init__(self, path: Path, fields: Sequence[str]) -> None:
        self.path, self.fields = path, list(fields)
        if not (path.exists() or path.is_symlink()):
            atomic_write_text(path, _csv_text([self.fields]))
        else:
            problem = file_problem(path)
            if problem is not None:  # a FIFO would block the first append forever
                raise ValueError(f"{path} {problem}; a run's log is a regular file: remove it to start a fresh log")

    def write(self, row: dict[str, Any]) -> None:
        append_text(self.path, _csv_text([[row.get(k, "") for k in self.fields]]))

    def keep_steps_up_to(self, step: int) -> None:
        """Drop rows a cut run wrote after its last checkpoint (the resumed run writes them again),
        replacing the file whole. A log that is not this run's CSV (another header, a row without
        a step number) is refused, naming it, rather than appended to."""
        text = read_small_file(self.path, "the run's log", limit=self.LIMIT)
        damaged = f"{self.path} is damaged"
        fix = "remove it (the checkpoints keep the run; a fresh log starts) or restore it"
        try:
            rows = list(csv.reader(io.StringIO(text, newline="")))
        except csv.Error as exc:  # a field past csv's limit, a NUL byte: not a ValueError
            raise ValueError(f"{damaged}: {exc}; {fix}") from None
        if not rows or rows[0] != self.fields:
            raise ValueError(f"{damaged}: its header is {rows[0] if rows else 'missing'}, expected {self.fields}; {fix}")
        at = self.fields.index("step")
        kept = rows[:1]
        for n, r in enumerate(rows[1:], start=2):
            try:
                if int(r[at]) <= step:
                    kept.append(r)
            except (IndexError, ValueError):
                raise ValueError(f"{damaged}: line {n} has no step number ({','.join(r)[:60]!r}); {fix}") from None
        atomic_write_text(self.path, _csv_text(kept))


class _StopOnSignal:
    """SIGTERM (a scheduler's time limit) or Ctrl-C finishes the current step, then the run writes
    last.pt and returns, so `--resume` loses nothing."""

    def __init__(self) -> None:
        self.signal: str | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> "_StopOnSignal":
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        import signal
        self.signal = signal.Signals(signum).name

    def __exit__(self, *exc: Any) -> None:
        import signal
        for sig, old in self._old.items():
            signal.signal(sig, old)


class _Tensorboard:
    """SummaryWriter when tensorboard imports; otherwise a no-op with one warning."""

    def __init__(self, log_dir: Path) -> None:
        try:
            require("tensorboard", "train", "TensorBoard logging")
            from torch.utils.tensorboard import SummaryWriter
            self.writer = SummaryWriter(str(log_dir))
        except Exception as e:  # tensorboard missing or broken: CSV logs still carry everything
            print(f"[train] TensorBoard disabled ({e}); CSV logs only", file=sys.stderr)
            self.writer = None

    def scalar(self, tag: str, value: float, step: int) -> None:
        if self.writer is not None:
            self.writer.add_scalar(tag, value, step)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


@torch.no_grad()
def validate(model: torch.nn.Module, dataset: SequenceDataset, device: torch.device
             ) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """Mean PSNR / SSIM / aligned PSNR over every frame of the validation samples, for the model
    and for TFP on the same windows (the yardstick the model has to beat), then each scene's own
    mean aligned PSNR (model and TFP). The aligned PSNR judges dark and bright frames on one scale
    (model/metrics.py), so its mean is what picks best.pt; the per-scene scores let another rule
    (the worst scene's, one set's) pick among kept checkpoints (`spikesim pick-checkpoint`): a
    mean over many scenes barely moves when one dark scene swings by 2-3 dB between checkpoints."""
    model.eval()
    scores: dict[str, list[float]] = {k: [] for k in VALIDATION_COLUMNS}
    by_scene: dict[str, dict[str, list[float]]] = {}
    for i in range(len(dataset)):
        item = dataset[i]
        spikes = item["spikes"].to(device)
        pred = model(spikes.unsqueeze(0))[0].float().cpu().numpy()
        base = tfp_windows(spikes).cpu().numpy()
        gt = item["gt"].numpy()
        scene = by_scene.setdefault(str(item["scene"]), {k: [] for k in SCENE_COLUMNS})
        for k in range(gt.shape[0]):
            for name, image in (("", pred[k]), ("_tfp", base[k])):
                scores["psnr" + name].append(psnr(image, gt[k]))
                scores["ssim" + name].append(ssim(image, gt[k]))
                scores["psnr_aligned" + name].append(psnr_aligned(image, gt[k]))
                scene["psnr_aligned" + name].append(scores["psnr_aligned" + name][-1])
    model.train()
    return ({k: float(np.mean(v)) for k, v in scores.items()},
            {name: {k: float(np.mean(v)) for k, v in cols.items()} for name, cols in by_scene.items()})


#: The validation log's metrics: the model's, then TFP's on the same windows.
VALIDATION_COLUMNS = ("psnr", "ssim", "psnr_aligned", "psnr_tfp", "ssim_tfp", "psnr_aligned_tfp")
#: The per-scene validation log's metrics (val_scenes.csv: a row per scene and validation).
SCENE_COLUMNS = ("psnr_aligned", "psnr_aligned_tfp")
#: The per-scene validation log's file name (model/selection.py reads it).
SCENE_LOG = "val_scenes.csv"
#: The folder of the checkpoints a run keeps at each validation (train.keep_validated), and their names.
VALIDATED_DIR = "validated"


def validated_name(step: int) -> str:
    """The file name of the checkpoint kept at validation `step` (sorts in step order)."""
    return f"step_{step:06d}.pt"


#: Above this many samples per epoch the order is not shuffled and batches are made as they are
#: used: each sample of a `samples_per_epoch` epoch draws its own random scene, start and crop
#: (model/data.py), so a permutation adds nothing, and one of 10^9 samples was a list the machine
#: could not hold (killed for memory). At or below it the order is the shuffled one, as always.
SHUFFLE_LIMIT = 1 << 20


def _epoch_order(n: int, seed: int, epoch: int) -> Sequence[int]:
    """The sample order of one epoch, a pure function of (seed, epoch) so a resumed run continues
    with exactly the batches it would have seen: shuffled up to SHUFFLE_LIMIT, else in index order
    (a range, no memory)."""
    if n > SHUFFLE_LIMIT:
        return range(n)
    g = torch.Generator().manual_seed((seed * 1_000_003 + epoch) % 2 ** 63)  # any seed up to 2**63 - 1
    return torch.randperm(n, generator=g).tolist()


def _epoch_batches(order: Sequence[int], batch_size: int, dist: "_Distributed", skip: int) -> Iterator[list[int]]:
    """This process's share of each batch of `order`, made lazily, after the first `skip` batches; a
    last batch too small to give every process a sample is skipped by all of them alike."""
    made = 0
    for i in range(0, len(order), batch_size):
        b = list(order[i:i + batch_size])
        if len(b) < dist.world:
            continue
        if made >= skip:
            yield dist.shard(b)
        made += 1


#: Training settings a resumed run must keep (the others: how long, how often to save or validate,
#: the loader's processes, may change between legs).
RESUME_FIXED = ("num_windows", "crop", "batch_size", "lr", "betas", "lr_milestones", "lr_gamma", "loss",
                "samples_per_epoch", "start_stride", "precision", "grad_clip", "seed", "lr_schedule",
                "lr_final_ratio", "channels_last", "calibration_steps", "set_shares")


def _resume(last_path: Path, dev: torch.device, mc: Any, tc: Any, model: torch.nn.Module, opt: Any, sched: Any,
            scaler: Any) -> tuple[int, int, int, float, dict[str, Any]]:
    """Restore a run from its last checkpoint; returns (epoch, batch in epoch, step, best aligned
    validation PSNR, the checkpoint's extra record).
    A checkpoint that does not fit this run is an error naming the file, never a traceback."""
    if not last_path.exists():
        raise FileNotFoundError(f"--resume: no checkpoint at {last_path}")
    state = load_checkpoint(last_path, dev)
    try:
        saved = ExperimentConfig.from_dict(state["experiment"])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--resume: {last_path}: its config is not valid: {exc}") from None
    if saved.model != mc:
        raise ValueError(f"--resume: {last_path} holds a different model config: {saved.model} vs {mc}")
    changed = {k: (getattr(saved.train, k), getattr(tc, k)) for k in RESUME_FIXED
               if getattr(saved.train, k) != getattr(tc, k)}
    if changed:
        what = ", ".join(f"{k} {a!r} -> {b!r}" for k, (a, b) in changed.items())
        raise ValueError(f"--resume: {last_path} was trained with other settings ({what}); a resumed run continues "
                         "the same run: drop those overrides, or start a new run (--overwrite or another --out)")
    try:
        model.load_state_dict(state["model_state"])
        opt.load_state_dict(state["optimizer_state"])
        sched.load_state_dict(state["scheduler_state"])
        if state.get("scaler_state"):
            scaler.load_state_dict(state["scaler_state"])
        torch.set_rng_state(state["rng"]["torch"].cpu())
        extra = state["extra"]
        return (int(state["epoch"]), int(extra.get("batch_in_epoch", 0)), int(state["step"]),
                float(extra.get("best_val_psnr", -math.inf)), dict(extra))
    except (KeyError, TypeError, ValueError, AttributeError, RuntimeError) as exc:
        text = str(exc).strip().splitlines()
        raise ValueError(f"--resume: {last_path} cannot continue this run: "
                         f"{text[0] if text else type(exc).__name__}") from None


@dataclasses.dataclass
class _Distributed:
    """This process's place in a `torchrun` job (rank 0 of 1 without one). Every rank computes the
    same global batches (a pure function of seed and epoch) and takes every world-th sample of
    each, so the run equals one process with the same global batch size, within float rounding."""

    rank: int = 0
    world: int = 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @classmethod
    def from_env(cls, dev: torch.device) -> tuple["_Distributed", torch.device]:
        world = int(os.environ.get("WORLD_SIZE", "1"))
        if world == 1:
            return cls(), dev
        import torch.distributed as tdist

        if dev.type == "cuda":
            dev = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
            torch.cuda.set_device(dev)
        if not tdist.is_initialized():
            tdist.init_process_group("nccl" if dev.type == "cuda" else "gloo")
        return cls(tdist.get_rank(), tdist.get_world_size()), dev

    def shard(self, batch: list[int]) -> list[int]:
        return batch[self.rank::self.world]

    def slowest(self, seconds: float) -> float:
        """The largest of every rank's value (the value itself in one process)."""
        if self.world == 1:
            return seconds
        import torch.distributed as tdist
        t = torch.tensor([float(seconds)], dtype=torch.float64)
        tdist.all_reduce(t, op=tdist.ReduceOp.MAX)
        return float(t.item())


@dataclasses.dataclass
class _Run:
    """What one training run holds: the model (and its DDP wrapper), optimiser, schedule, scaler."""

    model: torch.nn.Module
    forward: torch.nn.Module
    opt: Any
    sched: Any
    scaler: Any
    loss_fn: Any
    precision: str
    self_supervised: bool = False
    """`forward` returns the model's own loss from spikes alone (train.loss "self_supervised")."""


def initial_weights(spec: str, experiment: ExperimentConfig) -> tuple[dict[str, Any], dict[str, str]]:
    """The weights a fine-tuning run starts from: a shipped network by name (model.pretrained,
    its file checked against the registry) or a checkpoint of this project. Its model section
    must equal the run's (the same network); returns the state and a record of where it came from."""
    from .pretrained import PRETRAINED, pretrained_path

    path = pretrained_path(spec) if spec in PRETRAINED else Path(spec)
    state = load_checkpoint(path)
    source = ExperimentConfig.from_dict(state["experiment"], where=f"{path} experiment").model
    weights = state["model_state"]
    target = experiment.model
    if target.output == "refine" and dataclasses.replace(source, output="refine", refine_span=target.refine_span) == target:
        from .arch import head_channels, widen_head_state  # the same network, its head widened: start as it was
        if head_channels(source) < head_channels(target):
            weights = widen_head_state(weights, target)
            source = target
    if source != experiment.model:
        differ = [f"{k} {getattr(source, k)!r} -> {getattr(experiment.model, k)!r}"
                  for k in source.to_dict() if getattr(source, k) != getattr(experiment.model, k)]
        raise ValueError(f"--init {spec}: its network is not the config's ({', '.join(differ)}); fine-tuning needs "
                         "the same model section")
    return weights, {"spec": spec, "path": str(path), "weights_sha256": state_fingerprint(state["model_state"])}


def _build_run(experiment: ExperimentConfig, dev: torch.device, dist: _Distributed,
               init: dict[str, Any] | None = None) -> _Run:
    tc, mc = experiment.train, experiment.model
    seed_everything(tc.seed)
    model = build_model(mc)
    if init is not None:  # every rank loads the same weights, so DDP's first broadcast changes nothing
        model.load_state_dict(init)
    model = model.to(dev)
    if tc.channels_last:
        model = model.to(memory_format=torch.channels_last)
    # before DDP wraps it: DDP reduces the gradients of the parameters that require them
    params = trainable_parameters(model, tc.trainable)
    self_supervised = tc.loss == SELF_SUPERVISED
    forward = SelfSupervisedObjective(model) if self_supervised else model
    if dist.world > 1:
        from torch.nn.parallel import DistributedDataParallel
        forward = DistributedDataParallel(forward, device_ids=[dev.index] if dev.type == "cuda" else None)
    opt = torch.optim.Adam(params, lr=tc.lr, betas=tuple(tc.betas))
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=list(tc.lr_milestones), gamma=tc.lr_gamma)
    precision = resolve_precision(tc.precision, dev)
    return _Run(model, forward, opt, sched, grad_scaler(precision, dev), build_loss(tc.loss), precision,
                self_supervised)


def _datasets(experiment: ExperimentConfig, train_scenes: Sequence[Scene],
              val_scenes: Sequence[Scene]) -> tuple[SequenceDataset, SequenceDataset | None]:
    tc, mc = experiment.train, experiment.model
    train_ds = SequenceDataset(train_scenes, mc.window, tc.num_windows, tc.crop, random_crop=True,
                               seed=tc.seed, start_stride=tc.start_stride, samples_per_epoch=tc.samples_per_epoch,
                               set_shares=tc.set_shares)
    val_ds = None
    if val_scenes:
        per_scene = max(1, tc.val_max_samples // len(val_scenes))
        val_ds = SequenceDataset(val_scenes, mc.window, tc.num_windows, tc.val_crop, random_crop=False,
                                 seed=tc.seed, max_per_scene=per_scene)
    return train_ds, val_ds


#: What a run folder holds; a new run refuses a folder holding any of it unless told to overwrite.
RUN_FILES = ("last.pt", "best.pt", "train_log.csv", "val_log.csv", SCENE_LOG, "config.json", "tb",
             VALIDATED_DIR)
#: TensorBoard's event files, the run's own part of tb/ (SummaryWriter names them so).
TB_EVENT_PREFIX = "events.out.tfevents."


def _run_event_files(out: Path) -> list[str]:
    """The names of the TensorBoard event files in out/tb: what a run wrote there. A user's own
    files in tb/ are not the run's (round eight: --overwrite deleted a tb/analysis/ of the user's,
    and a bare tb/ was called a run)."""
    tb = out / "tb"
    if tb.is_symlink() or not tb.is_dir():
        return []
    return sorted(p.name for p in tb.iterdir() if p.name.startswith(TB_EVENT_PREFIX) and not p.is_symlink()
                  and p.is_file())


def _run_files_present(out: Path) -> list[str]:
    return [name for name in RUN_FILES if (name != "tb" and (out / name).exists())
            or (name == "tb" and _run_event_files(out))]


def _start_or_resume(out: Path, resume: bool, experiment: ExperimentConfig, run: _Run, dev: torch.device,
                     dist: _Distributed, overwrite: bool = False) -> tuple[int, int, int, float, dict[str, Any]]:
    """(epoch, batch in epoch, step, best validation PSNR, the checkpoint's extra record) to start from."""
    last_path = out / "last.pt"
    for name in RUN_FILES:  # a link where the run writes is refused, naming it, before anything is written
        writable(out, name)
    if resume:
        # config.json is put right by the caller once the run goes on (round twenty: a resume refused for its
        # data had already rewritten the record of a run that never went on)
        return _resume(last_path, dev, experiment.model, experiment.train, run.model, run.opt, run.sched, run.scaler)
    existing = _run_files_present(out)
    if existing and not overwrite:
        raise FileExistsError(f"{out} holds a run ({', '.join(existing)}): pass --resume (resume=True) to continue "
                              "it, --overwrite (overwrite=True) to replace it, or choose another --out (out_dir)")
    if dist.world > 1:  # every rank has looked before rank 0 writes
        import torch.distributed as tdist
        tdist.barrier()
    if dist.is_main:
        for stale in RUN_FILES:
            if stale != "tb":
                remove(out, stale)
        for events in _run_event_files(out):  # only the run's own logs: the rest of tb/ is the user's
            remove(out, "tb", events)
        atomic_write_json(writable(out, "config.json"), experiment.to_dict())
    return 0, 0, 0, -math.inf, {}


def _restore_config_record(out: Path, experiment: ExperimentConfig) -> None:
    """On resume, config.json says the config the run goes on with (its last.pt's): one damaged or
    edited since was kept as it was, so the folder's record and its checkpoints disagreed (round
    fourteen). Rewritten, with a warning naming it; an equal one is left untouched."""
    path = out / "config.json"
    if path.is_dir():  # refused before any word of rewriting it (round fifteen)
        raise IsADirectoryError(errno.EISDIR, "is a directory, expected a file name", str(path))
    if path.exists() and not path.is_file():  # a FIFO, socket or device was called "missing" and replaced (round seventeen)
        raise FileExistsError(errno.EEXIST, f"{file_problem(path)}, where a run keeps its config record; remove it",
                              str(path))
    want = json.loads(json.dumps(experiment.to_dict()))  # as JSON reads it back (lists, not tuples)
    try:
        have = json.loads(path.read_text()) if path.is_file() else None
    except (OSError, ValueError):
        have = "unreadable"
    if have != want:
        why = "missing" if have is None else "unreadable" if have == "unreadable" else "not the config the run goes on with"
        print(f"[train] {path}: {why}; rewritten", file=sys.stderr)
        atomic_write_json(writable(out, "config.json"), want)


def data_identity(train_scenes: Sequence[Scene], val_scenes: Sequence[Scene]) -> str:
    """What a run trains and validates on, as a digest: each scene's name, size, length and
    ground-truth steps, and the job digest its dataset recorded where there is one (the content).
    Recorded in every checkpoint; a resume on other data is refused (its best.pt would compare
    scores of different validation sets)."""
    def one(sc: Scene) -> list[Any]:
        meta = getattr(sc, "meta", None)
        digest = meta.get("job_digest") if isinstance(meta, dict) else None
        return [sc.name, int(sc.num_steps), int(sc.height), int(sc.width), [int(g) for g in sc.gt_steps], digest]
    doc = {"train": [one(s) for s in train_scenes], "val": [one(s) for s in val_scenes]}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def data_content(train_scenes: Sequence[Scene], val_scenes: Sequence[Scene]) -> str:
    """What the scenes hold, as a digest of each scene's checksum record (the sha256 of every file
    its dataset wrote); a scene without one (made in memory) counts by its name. `data_identity`
    sees names, sizes and job digests only, so a stream swapped between two scenes and the records
    remade kept it, and a resume trained and validated on other data (issue 40, round 5). Kept
    apart from `data_identity` so that checkpoints written before it still resume."""
    def one(sc: Scene) -> list[Any]:
        path = getattr(getattr(sc, "scene", sc), "path", None)  # a TimeSlice's scene's
        files = None
        if isinstance(path, Path) and (path / "checksums.json").is_file():
            try:
                files = json.loads((path / "checksums.json").read_text()).get("files")
            except (OSError, ValueError, AttributeError):
                files = "unreadable"
        return [sc.name, files]
    doc = {"train": [one(s) for s in train_scenes], "val": [one(s) for s in val_scenes]}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _total_steps(tc: Any, batches_per_epoch: int) -> int:
    total = tc.epochs * batches_per_epoch
    return min(total, tc.max_steps) if tc.max_steps is not None else total


def cosine_lr(tc: Any, step: int, total: int) -> float:
    """The cosine schedule's rate for the step about to be taken (0-based): lr at step 0, then down
    half a cosine to lr * lr_final_ratio at the run's last step (SGDR, Loshchilov and Hutter 2017,
    without restarts)."""
    low = tc.lr * tc.lr_final_ratio
    frac = min(step, total) / max(total, 1)
    return low + (tc.lr - low) * 0.5 * (1.0 + math.cos(math.pi * frac))


@dataclasses.dataclass
class _BudgetPlan:
    """A wall-clock budget turned into a number of steps, once, from the measured step rate; kept
    in every checkpoint so that a resumed run follows the same schedule to the same last step."""

    budget_s: float
    calibration_steps: int
    planned_steps: int | None = None
    elapsed_s: float = 0.0
    """Training time spent before this process started (earlier legs of a resumed run)."""

    def plan(self, step: int, seconds_so_far: float, cap: int | None, seconds_per_step: float) -> int:
        """The run's last step: the steps taken plus those the rest of the budget allows at the
        measured time per step (validation included: it is measured too), at most `cap`."""
        left = max(self.budget_s - seconds_so_far, 0.0)
        planned = step + int(left / max(seconds_per_step, 1e-9))
        self.allowed_steps = planned  # what the budget alone allows (a cap may stop the run before)
        self.planned_steps = max(step, min(planned, cap) if cap is not None else planned)
        return self.planned_steps

    def record(self) -> dict[str, Any]:
        return {"budget_planned_steps": self.planned_steps, "budget_elapsed_s": self.elapsed_s}


class _Timer:
    """Where the time goes: waiting for the next batch versus the step itself (samples/s and the
    data-wait share tell whether the loader or the model bounds training)."""

    def __init__(self) -> None:
        self.wait = self.busy = 0.0
        self.samples = 0
        self.step_times: list[float] = []
        """Wall seconds of the first steps (waiting for the batch included), for the budget's plan."""
        self._mark = time.perf_counter()
        self._waited = 0.0

    def batch_arrived(self) -> float:
        now = time.perf_counter()
        waited, self._mark = now - self._mark, now
        self.wait += waited
        self._waited = waited
        return waited

    def step_done(self, samples: int) -> float:
        now = time.perf_counter()
        took, self._mark = now - self._mark, now
        self.busy += took
        self.samples += samples
        if len(self.step_times) < 1000:
            self.step_times.append(self._waited + took)
        return took

    def summary(self) -> dict[str, float]:
        total = self.wait + self.busy
        return {"samples_per_s": self.samples / total if total > 0 else math.nan,
                "data_wait_share": self.wait / total if total > 0 else math.nan}


def _train_step(run: _Run, batch: dict, dev: torch.device, tc: Any, step: int, dist: _Distributed) -> float:
    """One optimiser step; returns the loss of the whole (global) batch."""
    spikes = batch["spikes"].to(dev, non_blocking=True)
    gt = batch["gt"].to(dev, non_blocking=True)
    with autocast(run.precision, dev):
        out = run.forward(spikes)
    loss = out.float() if run.self_supervised else run.loss_fn(out.float(), gt)
    if not torch.isfinite(loss):
        raise TrainingDiverged(f"the loss became {loss.item()} at step {step} (learning rate "
                               f"{run.opt.param_groups[0]['lr']:g}): lower --lr; last.pt holds the last good state")
    run.opt.zero_grad(set_to_none=True)
    run.scaler.scale(loss).backward()
    if tc.grad_clip is not None:
        run.scaler.unscale_(run.opt)
        torch.nn.utils.clip_grad_norm_(run.model.parameters(), tc.grad_clip)
    run.scaler.step(run.opt)
    run.scaler.update()
    if dist.world > 1:  # each rank saw its share: log the mean over the global batch
        import torch.distributed as tdist
        loss = loss.detach().clone()
        tdist.all_reduce(loss)
        loss /= dist.world
    return float(loss.item())


def run_training(experiment: ExperimentConfig, train_scenes: Sequence[Scene], val_scenes: Sequence[Scene],
                 out_dir: str | Path, device: str = "auto", resume: bool = False,
                 progress: bool = True, overwrite: bool = False, init: str | None = None) -> dict[str, Any]:
    """Train; returns a summary (steps, last loss, best validation PSNR, samples/s, data-wait share).
    Under `torchrun` each process trains its share of every batch (DDP); rank 0 writes. Every file
    is written inside `out_dir`, never through a link there; a run that fails before writing
    anything leaves no new empty folder (spikesim.outputs). `init` (a shipped network's name or a
    checkpoint) starts a new run from those weights instead of a random draw: fine-tuning."""
    if init is not None and resume:
        raise ValueError("--init starts a run from other weights; --resume continues one from its own last.pt")
    if both := shared_scenes(train_scenes, val_scenes):  # best.pt chosen by training-set scores (round six)
        raise ValueError(f"validation scenes: {len(both)} are also training scenes ({', '.join(both[:3])}"
                         f"{' ...' if len(both) > 3 else ''}): validation on training scenes measures nothing "
                         "held out; give other scenes, or split one dataset by scene (model.data.split_scenes)")
    from spikesim.dataset import check_outside_datasets
    check_outside_datasets(out_dir, [], "out_dir")  # `train -o` refused it; the API wrote a run there (round eleven)
    with output_folder(out_dir):
        if int(os.environ.get("RANK", "0")) != 0:  # under torchrun rank 0 holds the folder for every rank
            return _train(experiment, train_scenes, val_scenes, out_dir, device, resume, progress, overwrite, init)
        from spikesim.generation.lock import output_lock
        # two runs in one folder logged steps twice and left whichever last.pt was written last
        with output_lock(out_dir, f"train {experiment.name}", what="train run"):
            return _train(experiment, train_scenes, val_scenes, out_dir, device, resume, progress, overwrite, init)


def _train(experiment: ExperimentConfig, train_scenes: Sequence[Scene], val_scenes: Sequence[Scene],
           out_dir: str | Path, device: str, resume: bool, progress: bool, overwrite: bool,
           init: str | None = None) -> dict[str, Any]:
    from spikesim.progress import progress_bar

    out = Path(out_dir)
    dist, dev = _Distributed.from_env(resolve_device(device, "device"))
    tc = experiment.train
    if tc.batch_size % dist.world:
        raise ValueError(f"batch size {tc.batch_size} does not split over {dist.world} processes")
    out.mkdir(parents=True, exist_ok=True)
    init_state, init_record = initial_weights(init, experiment) if init is not None else (None, None)
    run = _build_run(experiment, dev, dist, init_state)
    train_ds, val_ds = _datasets(experiment, train_scenes, val_scenes)
    epoch, batch_in_epoch, step, best, saved = _start_or_resume(out, resume, experiment, run, dev, dist, overwrite)
    identity, content = data_identity(train_scenes, val_scenes), data_content(train_scenes, val_scenes)
    if resume and (saved.get("data_identity") not in (None, identity) or saved.get("data_content") not in (None, content)):
        # best.pt would compare scores from other validation data, and the schedule continue on other samples
        now = f"{len(train_scenes)} training + {len(val_scenes)} validation"
        order = [[s.name for s in train_scenes], [s.name for s in val_scenes]]
        was = saved.get("data_order")
        if isinstance(was, list) and was != order and [sorted(x) for x in was] == [sorted(x) for x in order]:
            # the same scenes in another order: the run's samples follow the order, so it is refused, but
            # "other content (regenerated in place?)" sent users looking for damage (round six)
            what = ("the same scenes in another order (the samples follow it): give --data and --val-data in the "
                    "order the run began with")
        elif saved.get("data_scenes") == now:
            what = f"the same number of scenes ({now}) with other content or frames (a dataset regenerated in place?)"
        else:
            what = f"{saved.get('data_scenes', '?')} scenes, not the {now} given now"
        raise ValueError(f"--resume: {out / 'last.pt'} trained on other data: {what}; resume "
                         "with the same --data and --val-data, or start a new run from its weights (--init "
                         f"{out / 'last.pt'})")
    init_record = init_record or saved.get("init_weights")  # a resumed fine-tuning run keeps saying where it began
    if init_record and dist.is_main and not resume:
        print(f"[train] starting from the weights of {init_record['spec']} ({init_record['weights_sha256'][:16]}...)",
              file=sys.stderr)
    budget = None
    if tc.budget_minutes is not None:
        budget = _BudgetPlan(60.0 * tc.budget_minutes, tc.calibration_steps,
                             saved.get("budget_planned_steps"), float(saved.get("budget_elapsed_s", 0.0)))
    logs = _Logs(out, enabled=dist.is_main, resumed_at=step if resume else None)
    # whole batches, and a last short one if it gives every process a sample (batch_size splits over them)
    batches_per_epoch = len(train_ds) // tc.batch_size + int(len(train_ds) % tc.batch_size >= dist.world)
    if batches_per_epoch == 0:
        raise ValueError(f"{len(train_ds)} training sample(s) per epoch give no batch that {dist.world} processes can "
                         "share: more scenes or steps, or fewer processes")
    if dist.is_main:
        print(f"[train] {experiment.name}: {count_parameters(run.model):,} parameters"
              f"{'' if tc.trainable == 'all' else f' to train (train.trainable {tc.trainable!r})'}, device {dev}"
              f"{f', {describe_threads()}' if dev.type == 'cpu' else ''}"
              f"{f' x {dist.world} processes' if dist.world > 1 else ''}, {run.precision}, {len(train_ds)} "
              f"samples/epoch from {len(train_scenes)} scenes, {len(val_ds) if val_ds else 0} validation samples",
              file=sys.stderr)
        if train_ds.set_probs is not None:
            print("[train] samples drawn by set (train.set_shares): "
                  + ", ".join(f"{name} {100 * p:.1f} %" for name, p in train_ds.set_probs.items()), file=sys.stderr)
        if tc.batch_size > len(train_ds):
            print(f"[train] the batch size {tc.batch_size} is more than the {len(train_ds)} samples of an epoch: each step "
                  f"takes those {len(train_ds)} (more samples per epoch with --samples-per-epoch)", file=sys.stderr)
        if val_ds is None:
            print(f"[train] no validation scenes (a scene is never both trained on and validated on, and one scene "
                  f"too short to split in time gives none: give more scenes, longer ones or --val-data): best.pt will "
                  f"not be written; {out / 'last.pt'} is the trained model", file=sys.stderr)
        elif any(isinstance(s, TimeSlice) for s in val_scenes):
            print(f"[train] one scene, split in time: training on {', '.join(s.name for s in train_scenes)}, "
                  f"validating on {', '.join(s.name for s in val_scenes)} (no step is in both; the objects and "
                  "motion are, so this checks less than held-out scenes would)", file=sys.stderr)

    # each scene's stream sha256 (or None), beside its name: `evaluate` says which scored scenes the run
    # trained on by these, since names repeat across datasets (model.evaluation.training_scene_notes)
    streams = [[stream_sha256(s) for s in train_scenes], [stream_sha256(s) for s in val_scenes]]

    def checkpoint(path: Path) -> None:
        if dist.is_main:
            record = {} if budget is None else {**budget.record(),
                                                "budget_elapsed_s": budget.elapsed_s + time.perf_counter() - started}
            save_checkpoint(path, run.model, experiment, run.opt, run.sched, run.scaler, epoch, step,
                            extra={"batch_in_epoch": batch_in_epoch, "best_val_psnr": best, **record,
                                   "data_identity": identity, "data_content": content,
                                   "data_scenes": f"{len(train_scenes)} training + {len(val_scenes)} validation",
                                   "data_order": [[s.name for s in train_scenes], [s.name for s in val_scenes]],
                                   "data_streams": streams,
                                   **({"init_weights": init_record} if init_record else {})})

    def last_step() -> int:
        """The step the run ends at: the budget's plan (until it is made, the cap), else max_steps or
        every epoch's batches."""
        total = _total_steps(tc, batches_per_epoch)
        if budget is not None and budget.planned_steps is not None:
            return min(budget.planned_steps, total)
        return total

    def validation_every() -> int:
        """Epochs between validations: val_every, or fewer where the run is too short to validate
        min_validations times at that cadence."""
        run_epochs = math.ceil(last_step() / batches_per_epoch)
        return min(tc.val_every, max(1, run_epochs // tc.min_validations))

    if resume and (step >= last_step() or epoch >= tc.epochs):
        # a finished run: one more step would change last.pt past its plan ("step 21 of 20")
        if dist.is_main:
            # the record says last.pt's own config, not the one asked for now (the run did not go on with it:
            # round twenty-one); a damaged or missing record is still put right (round fourteen)
            stored = load_checkpoint(out / "last.pt").get("experiment")
            _restore_config_record(out, ExperimentConfig.from_dict(stored, where=f"{out / 'last.pt'} experiment"))
            print(f"[train] nothing to do: {out / 'last.pt'} is at step {step} of {last_step()} (epoch {epoch} of "
                  f"{tc.epochs}); raise --max-steps, --epochs or --budget-minutes to train further", file=sys.stderr)
        logs.close()
        return {"steps": step, "weights_sha256": state_fingerprint(run.model.state_dict()), "stopped_by": None,
                "epoch": epoch, "last_loss": None, "best_val_psnr_aligned": best if math.isfinite(best) else None,
                "precision": run.precision, "processes": dist.world, "rank": dist.rank, "train_seconds": 0.0,
                "budget_minutes": tc.budget_minutes, "planned_steps": None if budget is None else budget.planned_steps,
                "out": str(out), "nothing_to_do": True}

    if resume and dist.is_main:
        # config.json put right only now that the run goes on: a resume refused for its data, or with nothing
        # to do, left a record of a run that never went on (rounds twenty and twenty-one)
        _restore_config_record(out, experiment)
        print(f"[train] resuming {out / 'last.pt'} at step {step} of {last_step()}", file=sys.stderr)
    bar = progress_bar(total=_total_steps(tc, batches_per_epoch), initial=step, desc=f"train {experiment.name}",
                       unit="step", quiet=not (progress and dist.is_main))
    timer, last_loss, stopped = _Timer(), math.nan, False
    started, first_step = time.perf_counter(), step
    stop = _StopOnSignal().__enter__()
    try:
        run.model.train()
        while epoch < tc.epochs and not stopped:
            train_ds.set_epoch(epoch)
            order = _epoch_order(len(train_ds), tc.seed, epoch)
            loader = DataLoader(train_ds, batch_sampler=_epoch_batches(order, tc.batch_size, dist, batch_in_epoch),
                                num_workers=tc.num_workers, worker_init_fn=_worker_init, pin_memory=dev.type == "cuda")
            for batch in loader:
                waited = timer.batch_arrived()
                if tc.lr_schedule == "cosine":
                    for group in run.opt.param_groups:
                        group["lr"] = cosine_lr(tc, step, last_step())
                last_loss = _train_step(run, batch, dev, tc, step, dist)
                took = timer.step_done(batch["spikes"].shape[0] * dist.world)
                step += 1
                batch_in_epoch += 1
                logs.train_step(epoch, step, last_loss, run.opt.param_groups[0]["lr"],
                                batch["spikes"].shape[0] * dist.world / max(waited + took, 1e-9), waited)
                bar.update(1)
                bar.set_postfix(loss=f"{last_loss:.4f}", refresh=False)
                if budget is not None and budget.planned_steps is None and step - first_step >= budget.calibration_steps:
                    spent = time.perf_counter() - started
                    # the first step is slower (allocations): the rate comes from the steps after it;
                    # under torchrun every rank plans with the slowest rank's time, so all stop together
                    per_step = dist.slowest(_budget_seconds_per_step(timer, step - first_step, spent))
                    budget.plan(step, budget.elapsed_s + dist.slowest(spent), tc.max_steps, per_step)
                    bar.total = last_step()
                    if dist.is_main:  # every rank plans alike; one says so
                        allowed = getattr(budget, "allowed_steps", last_step())
                        capped = (f"; capped at {last_step()} by the config's max_steps or epochs, so the run ends "
                                  f"after about {last_step() * per_step / 60:.1f} of the {tc.budget_minutes:g} minutes "
                                  f"(--max-steps or --epochs to use them all)" if last_step() < allowed else "")
                        bar.write(f"[train] budget {tc.budget_minutes:g} min: {budget.planned_steps} steps planned "
                                  f"({per_step:.3f} s per step measured){capped}", file=sys.stderr)
                if tc.ckpt_every_steps is not None and step % tc.ckpt_every_steps == 0:
                    checkpoint(out / "last.pt")
                if step >= last_step() or _signalled(stop, dist):
                    stopped = True
                    break
            if not stopped:
                epoch, batch_in_epoch = epoch + 1, 0
                with warnings.catch_warnings():  # a run resumed exactly at an epoch's end steps no batch first
                    warnings.filterwarnings("ignore", message="Detected call of `lr_scheduler.step")
                    run.sched.step()
            if dist.is_main and val_ds is not None and (stopped or epoch % validation_every() == 0):
                scores, scene_scores = validate(run.model, val_ds, dev)
                logs.validation(epoch, step, scores, scene_scores)
                if tc.keep_validated:  # every validated state, for a choice by another rule afterwards
                    make_dirs(out, VALIDATED_DIR)
                    checkpoint(writable(out, VALIDATED_DIR, validated_name(step)))
                bar.write(f"[train] step {step} of {last_step()} (epoch {epoch}, {batches_per_epoch} step(s) each): "
                          + (f"loss {last_loss:.4f}, " if math.isfinite(last_loss) else "no step since the resume, ")
                          + "val aligned PSNR "
                          f"{scores['psnr_aligned']:.2f} dB (TFP {scores['psnr_aligned_tfp']:.2f}), PSNR "
                          f"{scores['psnr']:.2f} dB (TFP {scores['psnr_tfp']:.2f}), SSIM {scores['ssim']:.4f}",
                          file=sys.stderr)
                if scores["psnr_aligned"] > best:
                    best = scores["psnr_aligned"]
                    checkpoint(out / "best.pt")
            if stopped or epoch % tc.ckpt_every == 0 or epoch >= tc.epochs:
                checkpoint(out / "last.pt")
    finally:
        stop.__exit__()  # the usual signal handling is back, whatever ended the loop
    bar.close()
    logs.close()
    if stop.signal is not None and dist.is_main:
        print(f"[train] stopped by {stop.signal} at step {step} of {last_step()}; {out / 'last.pt'} is written: "
              f"continue with `spikesim train --resume -o {out}` and the same --data (and --val-data)", file=sys.stderr)
    fingerprint = state_fingerprint(run.model.state_dict())
    if dist.world > 1:
        import torch.distributed as tdist
        seen = [None] * dist.world
        tdist.all_gather_object(seen, fingerprint)  # also: no rank leaves while rank 0 still writes
        if len(set(seen)) != 1:
            raise RuntimeError(f"DDP ranks ended with different weights (fingerprints {seen}): a bug")
    wall = time.perf_counter() - started + (budget.elapsed_s if budget is not None else 0.0)
    return {"steps": step, "weights_sha256": fingerprint, "stopped_by": stop.signal, "epoch": epoch,
            "last_loss": last_loss, "best_val_psnr_aligned": best if math.isfinite(best) else None,
            "precision": run.precision,
            "processes": dist.world, "rank": dist.rank, **timer.summary(), "train_seconds": wall,
            "budget_minutes": tc.budget_minutes, "planned_steps": None if budget is None else budget.planned_steps,
            "out": str(out)}


def _budget_seconds_per_step(timer: "_Timer", steps: int, spent: float) -> float:
    """Wall seconds per step (loading included) from the calibration steps: their median, the first
    left out. The first few steps build oneDNN's kernels and read the data cold, 1.5-2.5x slower
    than the rest (measured on the shipped run: 0.74, 0.87, 0.79, 0.53, 0.51 s, then 0.34-0.36 s),
    and a mean over ten steps planned 25 % too few steps; the median of the ten is the steady rate."""
    times = timer.step_times[1:steps] if steps > 1 else timer.step_times[:steps]
    if times:
        return float(np.median(times))
    return spent / max(steps, 1)


def _signalled(stop: _StopOnSignal, dist: _Distributed) -> bool:
    """Whether any process was asked to stop (they all stop at the same step)."""
    if dist.world == 1:
        return stop.signal is not None
    import torch.distributed as tdist
    flag = torch.tensor([1.0 if stop.signal else 0.0])
    tdist.all_reduce(flag)
    return bool(flag.item() > 0)


class _Logs:
    """train_log.csv, val_log.csv and TensorBoard, written by one process only. A resumed run first
    drops rows written after its checkpoint, so the logs read as one uninterrupted run."""

    def __init__(self, out: Path, enabled: bool, resumed_at: int | None = None) -> None:
        self.enabled = enabled
        if enabled:
            self.train = _CsvLog(out / "train_log.csv",
                                 ["time", "epoch", "step", "loss", "lr", "samples_per_s", "data_wait_s"])
            self.val = _CsvLog(out / "val_log.csv", ["time", "epoch", "step", *VALIDATION_COLUMNS])
            self.scenes = _CsvLog(out / SCENE_LOG, ["time", "epoch", "step", "scene", *SCENE_COLUMNS])
            if resumed_at is not None:
                self.train.keep_steps_up_to(resumed_at)
                self.val.keep_steps_up_to(resumed_at)
                self.scenes.keep_steps_up_to(resumed_at)
            self.tb = _Tensorboard(make_dirs(out, "tb"))

    def train_step(self, epoch: int, step: int, loss: float, lr: float, rate: float, waited: float) -> None:
        if self.enabled:
            self.train.write({"time": time.time(), "epoch": epoch, "step": step, "loss": loss, "lr": lr,
                              "samples_per_s": rate, "data_wait_s": waited})
            self.tb.scalar("train/loss", loss, step)

    def validation(self, epoch: int, step: int, scores: dict[str, float],
                   scene_scores: dict[str, dict[str, float]] | None = None) -> None:
        if self.enabled:
            now = time.time()
            self.val.write({"time": now, "epoch": epoch, "step": step, **scores})
            for scene, cols in (scene_scores or {}).items():
                self.scenes.write({"time": now, "epoch": epoch, "step": step, "scene": scene, **cols})
            for k, v in scores.items():
                self.tb.scalar(f"val/{k}", v, step)

    def close(self) -> None:
        if self.enabled:
            self.tb.close()
