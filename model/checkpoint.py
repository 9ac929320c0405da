"""Checkpoints: atomic writes (temp file in the same folder, then rename, with the user's umask)
and self-describing contents (the configs travel with the weights, as plain JSON-like types, so a
checkpoint alone rebuilds its network).

Loading is weights-only (`torch.load(weights_only=True)`): a checkpoint is data, and unpickling
anything beyond tensors, numbers, strings and containers (the allow-list of torch's weights-only
unpickler) is refused instead of run. Everything `save_checkpoint` stores is on that list, also in
checkpoints written before loading became weights-only, so those still load.
"""
from __future__ import annotations

import errno
import os
import pickle
import re
import warnings
from pathlib import Path
from typing import Any, BinaryIO

import torch

from spikesim.outputs import atomic_write_file, writing

from .arch import build_model
from .config import ExperimentConfig

FORMAT_VERSION = 1
_STATE_KEYS = ("experiment", "model_state")
#: The parts of a checkpoint whose content hash is stored with it and checked on every load: one
#: flipped bit in a tensor gives frames of 1e33 or a resume from damaged weights, with no error.
_HASHED = {"model_state": "weights_sha256", "optimizer_state": "optimizer_sha256"}


def state_fingerprint(obj: Any) -> str:
    """sha256 over a state's content: tensors' dtype, shape and bytes, and every other value's repr,
    in key order. Equal for equal states whatever device they sit on; one flipped bit changes it."""
    import hashlib

    h = hashlib.sha256()

    def walk(x: Any) -> None:
        if isinstance(x, torch.Tensor):
            t = x.detach().cpu().contiguous()
            h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
            h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
        elif isinstance(x, dict):
            h.update(b"{")
            for k in sorted(x, key=repr):
                h.update(repr(k).encode())
                walk(x[k])
            h.update(b"}")
        elif isinstance(x, (list, tuple)):
            h.update(b"[")
            for v in x:
                walk(v)
            h.update(b"]")
        else:
            h.update(repr(x).encode())
    walk(obj)
    return h.hexdigest()


def atomic_torch_save(obj: Any, path: str | Path) -> None:
    """torch.save to a temp file beside `path`, fsync, then os.replace: a crash mid-write never
    leaves a truncated checkpoint under the final name, a link at `path` is refused, and a full
    disk is an OSError naming `path` (spikesim.outputs)."""
    path = Path(path)
    with writing(path.parent):
        path.parent.mkdir(parents=True, exist_ok=True)

    def write(f: BinaryIO) -> None:
        try:
            torch.save(obj, f)
        except RuntimeError as exc:  # torch's zip writer reports a short write (a full disk) as a RuntimeError
            raise OSError(_write_errno(path.parent), f"writing the checkpoint failed ({_first_line(exc)})",
                          str(path)) from exc
        f.flush()
        os.fsync(f.fileno())

    atomic_write_file(path, write)


def _write_errno(folder: Path) -> int:
    """ENOSPC where the folder's file system has (next to) no room left, else EIO."""
    import errno
    try:
        st = os.statvfs(folder)
        if st.f_bavail * st.f_frsize < (1 << 20):
            return errno.ENOSPC
    except OSError:
        pass
    return errno.EIO


def save_checkpoint(path: str | Path, model: torch.nn.Module, experiment: ExperimentConfig,
                    optimizer: torch.optim.Optimizer | None = None, scheduler: Any = None,
                    scaler: Any = None, epoch: int = 0, step: int = 0,
                    extra: dict[str, Any] | None = None) -> None:
    state = {
        "format_version": FORMAT_VERSION,
        "experiment": experiment.to_dict(),
        "model_state": model.state_dict(),
        "optimizer_state": optimizer.state_dict() if optimizer is not None else None,
        "scheduler_state": scheduler.state_dict() if scheduler is not None else None,
        "scaler_state": scaler.state_dict() if scaler is not None else None,
        "epoch": epoch,
        "step": step,
        "rng": {"torch": torch.get_rng_state(),
                "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None},
        "extra": extra or {},
    }
    state.update({key: state_fingerprint(state[part]) for part, key in _HASHED.items() if state[part] is not None})
    atomic_torch_save(state, path)


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """The contents of a checkpoint written by `save_checkpoint`, loaded weights-only.

    A file that is missing, a directory, empty, corrupt, needs code to unpickle, or is not one of
    this project's checkpoints is an error naming the file (ValueError or OSError).
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a directory, expected a checkpoint file", str(path))
    if not path.is_file():
        if path.exists():  # a FIFO, device or socket: there is a file, not a checkpoint one
            raise ValueError(f"{path}: not a regular file (a FIFO, device or socket), so not a checkpoint")
        raise FileNotFoundError(errno.ENOENT, "checkpoint not found", str(path))
    device = torch.device(map_location) if isinstance(map_location, (str, torch.device)) else None
    if device is not None and device.type == "cuda" and not torch.cuda.is_available():  # the machine, not the file
        raise ValueError(f"device {map_location}: this machine has no CUDA device (torch {torch.__version__}); "
                         "use cpu")
    try:
        with warnings.catch_warnings():  # a foreign pickle protocol: the refusal below says all there is
            warnings.filterwarnings("ignore", message="Detected pickle protocol")
            state = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        raise ValueError(f"{path}: not a checkpoint of this project: {_refusal(exc, path)}") from None
    except (RuntimeError, EOFError, ValueError, TypeError, AttributeError, KeyError, IndexError, OSError) as exc:
        # OSError: a zip archive cut short at some sizes fails in torch's reader as "[Errno 22] Invalid
        # argument", naming no file (issue 40, round 5)
        reason = ("the file is empty" if path.stat().st_size == 0 else
                  f"unreadable, cut short or corrupt ({_first_line(exc)})")
        raise ValueError(f"{path}: not a checkpoint of this project: {reason}") from None
    return _checked_state(path, state)


def _checked_state(path: Path, state: Any) -> dict[str, Any]:
    """`state` when it has this project's layout, else an error naming the file."""
    version = state.get("format_version") if isinstance(state, dict) else None
    if version != FORMAT_VERSION:
        raise ValueError(f"{path}: not a checkpoint of this project (format_version {version!r}, "
                         f"expected {FORMAT_VERSION})")
    missing = [k for k in _STATE_KEYS if not isinstance(state.get(k), dict)]
    if missing:
        raise ValueError(f"{path}: not a checkpoint of this project (no {' or '.join(missing)} mapping)")
    for part, key in _HASHED.items():  # checkpoints written before the hashes were stored have none
        if key in state and state.get(part) is not None and state_fingerprint(state[part]) != state[key]:
            what = "weights" if part == "model_state" else "optimiser state"
            raise ValueError(f"{path}: its {what} do not match the content hash stored with them: the file is "
                             "damaged (restore it, or train again)")
    _check_finite_weights(path, state["model_state"])
    return state


def _check_finite_weights(path: Path, weights: dict[str, Any]) -> None:
    """Refuse weights holding NaN or infinity, naming the first tensor: such a network gives black
    or NaN frames (a run that diverged, or an edited file), never a reconstruction."""
    for name, t in weights.items():
        if isinstance(t, torch.Tensor) and (t.is_floating_point() or t.is_complex()):
            bad = int((~torch.isfinite(t)).sum())
            if bad:
                raise ValueError(f"{path}: its weights hold NaN or infinite values ({bad} of {t.numel()} in "
                                 f"{name!r}): not a usable network (the run that wrote it diverged, or the file "
                                 "was edited)")


def _refusal(exc: pickle.UnpicklingError, path: Path | None = None) -> str:
    """What the weights-only unpickler refused, in one line, naming the global the file imports
    (e.g. "Unsupported global: GLOBAL posix.system"): the file holds code or objects that only full
    unpickling would build. torch names the global for some refusals ("unsupported GLOBAL x whose
    module is blocked") and not for others ("Unsupported operand 149"); then the pickle's opcodes
    are read (decoded, never run) to find it. "not a torch checkpoint file" only when neither the
    refusal nor the bytes name one."""
    text = str(exc)
    m = re.search(r"WeightsUnpickler error:\s*(.*?)(?: was not an allowed|\n|$)", text.strip())
    reason = m.group(1).strip() if m else ""
    found = re.search(r"GLOBAL\s+([\w.]+)", text)
    name = found.group(1) if found else (_pickle_global(path) if path is not None else None)
    if name is None:
        return f"weights-only loading refused it ({reason})" if reason else "not a torch checkpoint file"
    what = reason if reason and name in reason else (f"{reason}: " if reason else "") + f"global {name}"
    return f"weights-only loading refused it ({what}); nothing in it was run"


def _pickle_global(path: Path) -> str | None:
    """The first global (module.name) a pickle, bare or in a torch zip's data.pkl, would import;
    found by decoding its opcodes with pickletools (nothing is executed), None when there is none."""
    import pickletools
    import zipfile

    try:
        if zipfile.is_zipfile(path):
            with zipfile.ZipFile(path) as z:
                member = next((n for n in z.namelist() if n.endswith("data.pkl")), None)
                data = z.read(member) if member else b""
        else:
            data = path.read_bytes()[: 1 << 24]
    except (OSError, zipfile.BadZipFile, KeyError, RuntimeError, ValueError):
        return None
    strings: list[str] = []
    try:
        for op, arg, _ in pickletools.genops(data):
            if op.name in ("GLOBAL", "INST") and isinstance(arg, str):
                return arg.replace(" ", ".")
            if op.name == "STACK_GLOBAL" and len(strings) >= 2:
                return f"{strings[-2]}.{strings[-1]}"
            if isinstance(arg, str):
                strings.append(arg)
    except (ValueError, EOFError, UnicodeDecodeError, TypeError, KeyError):
        pass
    return None


def _first_line(exc: BaseException, limit: int = 160) -> str:
    """The gist of a library error: its first sentence or two lines, cut to `limit` characters."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    text = " ".join(lines[:2]) if lines else type(exc).__name__
    text = text.split(". ")[0]
    return text if len(text) <= limit else text[: limit - 3] + "..."


def for_inference(model: torch.nn.Module, experiment: ExperimentConfig) -> torch.nn.Module:
    """The network in eval mode with GISI clipped at its training horizon, K*T + 1 steps: on a
    stream longer than its training sequences the "never fired" distance would otherwise grow with
    the stream's length, to values the network never saw (ReconNet.max_interval)."""
    if hasattr(model, "max_interval"):
        model.max_interval = float(experiment.train.num_windows * experiment.model.window + 1)
    return model.eval()


def model_from_checkpoint(path: str | Path, map_location: str | torch.device = "cpu"
                          ) -> tuple[torch.nn.Module, ExperimentConfig]:
    """Rebuild the network a checkpoint describes and load its weights (strict)."""
    state = load_checkpoint(path, map_location)
    try:
        experiment = ExperimentConfig.from_dict(state["experiment"], where=f"{path} experiment")
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: its config is not valid: {_first_line(exc)}") from None
    try:
        model = build_model(experiment.model)  # its size is checked first: terabytes are refused, not allocated
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    try:
        model.load_state_dict(state["model_state"])
    except (RuntimeError, TypeError, KeyError) as exc:
        raise ValueError(f"{path}: its weights do not fit the network its config describes "
                         f"({_first_line(exc)})") from None
    return model.to(map_location), experiment
