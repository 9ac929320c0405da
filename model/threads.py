"""How many torch CPU threads a command uses when the user does not say.

Measured on the 2-core VM (docs/performance.md, "Threads"; `python -m model.bench --config tiny
--train-steps 6 --thread-sweep 1,2 --load N`): on a quiet machine two threads train 1.5x faster
than one; with one other busy process on the machine two threads train 4.4x *slower* than one,
because OpenMP threads spin-wait at every barrier for the thread that shares its core. So the
default takes only the cores that are free now (cores minus the 1-minute load average), never
fewer than one. A user-given count is used as it is.
"""
from __future__ import annotations

import math
import os

import torch


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _load_1min() -> float:
    try:
        return os.getloadavg()[0]
    except (OSError, AttributeError):  # no load average on this platform: assume a quiet machine
        return 0.0


def free_cores(cores: int | None = None, load_1min: float | None = None) -> int:
    """Cores not busy with other work: `cores` minus the load average rounded to the nearest
    whole process, at least 1 (both read from the machine when not given)."""
    cores = _cores() if cores is None else cores
    load_1min = _load_1min() if load_1min is None else load_1min
    if not math.isfinite(load_1min) or load_1min < 0:
        load_1min = 0.0
    return max(1, cores - int(load_1min + 0.5))


_chosen: dict[str, object] = {}


#: More threads than any machine's cores; the command line's bound too (pipelines.argtypes).
MAX_THREADS = 1024


def set_cpu_threads(requested: int = 0) -> str:
    """Set torch's intra-op threads: `requested` if > 0, else `free_cores()`. Returns how the
    count was chosen (also what `describe_threads` says afterwards, for a command's log line)."""
    if requested < 0 or requested > MAX_THREADS:  # 99999 crashed the process (round nine)
        raise ValueError(f"threads must be 0 to {MAX_THREADS} (0: chosen from the free cores), got {requested}")
    if requested:
        n, reason = requested, f"{requested} thread(s), as asked"
    else:
        cores, load = _cores(), _load_1min()  # read once: the count and the message agree
        n = free_cores(cores, load)
        reason = (f"{n} thread(s) ({cores} cores, load average {load:.1f}: threads sharing a busy core "
                  "stall each other; --threads N to choose)")
    torch.set_num_threads(n)
    _chosen.update(threads=n, reason=reason)
    return reason


def describe_threads() -> str:
    """How many torch threads run, and why, if `set_cpu_threads` chose the count now in use."""
    n = torch.get_num_threads()
    return str(_chosen["reason"]) if _chosen.get("threads") == n else f"{n} thread(s)"
