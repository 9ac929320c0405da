"""Running scene jobs in parallel: a local process pool, or one Ray task per scene.

Local workers die with the process that started them, however it ends (SIGKILL included): an
orphaned worker would keep writing into the output folder after its run released the folder's
lock, and race the next run there.
"""
from __future__ import annotations

import atexit
import ctypes
import logging
import os
import signal
import sys
import threading
import time
from concurrent.futures.process import BrokenProcessPool
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Optional

from spikesim.generation.job import run_job
from spikesim.errors import UnavailableError
from spikesim.progress import progress_bar
from spikesim.signals import TERMINATED_STATUS, stop_pool_workers

if TYPE_CHECKING:
    from spikesim.generation.plan import SceneJob

log = logging.getLogger("spikesim.generate")

PR_SET_PDEATHSIG = 1  # linux/prctl.h
PARENT_POLL_S = 1.0

OnDone = Optional[Callable[[dict[str, Any]], None]]
"""Called with each job's result (run_job's report) as it finishes, in the calling process."""

_progress: Any = None
"""The worker's queue for (scene, steps done, steps total), set by `_worker_init`."""


# ---- worker lifetime --------------------------------------------------------------------------------
def _watch_parent(parent_pid: int, poll_s: float) -> None:
    """Exit this process once its parent is gone (it is then re-parented, so getppid changes)."""
    while os.getppid() == parent_pid:
        time.sleep(poll_s)
    os._exit(1)


def die_with_parent(parent_pid: int, poll_s: float = PARENT_POLL_S) -> None:
    """Make the calling process end when `parent_pid` ends. On Linux the kernel sends SIGKILL at
    the parent's death (prctl PR_SET_PDEATHSIG, tied to the thread that started this process: the
    pool is created and used by one thread, which outlives it). Everywhere, and as a fallback, a
    daemon thread polls the parent's pid."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # no usable libc: the watchdog alone
    if os.getppid() != parent_pid:  # the parent died before the prctl took effect
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid, poll_s), daemon=True, name="watch-parent").start()


def _end_on_sigterm(signum: int, frame: Any) -> None:
    """A worker stopped by SIGTERM (the parent's Ctrl-C or SIGTERM: stop_pool_workers) runs its exit
    handlers, which remove its temporary folders, then ends: by default it ended at once and left
    an empty /tmp/spikesim-mono-* per worker (round fifteen). The parent removes the scene it was on."""
    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    if run_exit_handlers is not None:
        run_exit_handlers()
    os._exit(TERMINATED_STATUS)


def _worker_init(threads: int, progress: Any, parent_pid: int) -> None:
    die_with_parent(parent_pid)
    signal.signal(signal.SIGTERM, _end_on_sigterm)
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    global _progress
    _progress = progress


def _run_in_worker(job: SceneJob, root: str, threads: int, device: str) -> dict[str, Any]:
    def progress(name: str, done: int, total: int) -> None:
        _progress.put((name, done, total))
    return run_job(job, root, progress=progress, threads=threads, device=device)


# ---- local ------------------------------------------------------------------------------------------
def generate_local(todo: list[SceneJob], root: Path, workers: int, show_progress: bool,
                   device: str = "auto", on_done: OnDone = None) -> list[dict[str, Any]]:
    """Run the jobs here: in this process with `workers` <= 1, else in a spawned process pool;
    `on_done(result)` as each job finishes."""
    if workers <= 1:
        return _generate_in_process(todo, root, show_progress, device, on_done)
    import multiprocessing as mp
    ctx = mp.get_context("spawn")  # Dr.Jit / Mitsuba state must not be forked
    threads = max(1, (os.cpu_count() or 1) // workers)
    queue = ctx.Queue()  # handed over at spawn: no manager process that could outlive us
    results = []
    bars: dict[str, Any] = {}
    overall = progress_bar(total=len(todo), desc="scenes", unit="scene", quiet=not show_progress)
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                             initargs=(threads, queue, os.getpid())) as pool:
        pending = {pool.submit(_run_in_worker, job, str(root), threads, device): job for job in todo}
        try:
            while pending:
                done, _ = wait(list(pending), timeout=0.5, return_when=FIRST_COMPLETED)
                while not queue.empty():
                    name, n, total = queue.get()
                    if name not in bars:
                        bars[name] = progress_bar(total=total, desc=name, unit="render", quiet=not show_progress,
                                                  nested=True, position=1 + len(bars) % max(1, workers))
                    bars[name].n = n
                    bars[name].refresh()
                for fut in done:
                    job = pending.pop(fut)
                    results.append(fut.result())  # re-raises a worker's error
                    if on_done is not None:
                        on_done(results[-1])
                    if job.name in bars:
                        bars.pop(job.name).close()
                    overall.update(1)
        except BaseException as exc:
            for fut in pending:  # jobs not started yet are not started after a failure
                fut.cancel()
            if isinstance(exc, KeyboardInterrupt):  # Ctrl-C or SIGTERM: the scenes in progress stop too
                stop_pool_workers(pool)
            if isinstance(exc, BrokenProcessPool):  # a worker killed from outside: most often for memory
                running = [job.name for job in pending.values()][:4]
                raise MemoryError(f"a worker process was killed while on {', '.join(running) or 'a scene'} (out of "
                                  f"memory?); every finished scene in {root} is kept: run the same command again to "
                                  "go on, with --workers 1 if it happens again") from None
            raise
    overall.close()
    queue.close()
    return results


def _generate_in_process(todo: list[SceneJob], root: Path, show_progress: bool, device: str,
                         on_done: OnDone = None) -> list[dict[str, Any]]:
    results = []
    overall = progress_bar(total=len(todo), desc="scenes", unit="scene", quiet=not show_progress)
    for job in todo:
        bar = progress_bar(total=None, desc=job.name, unit="render", quiet=not show_progress, nested=True)

        def progress(name: str, done: int, total: int, bar: Any = bar) -> None:
            bar.total, bar.n = total, done  # renders, ground truth included (spikesim.generation.job)
            bar.refresh()
        results.append(run_job(job, root, progress=progress, device=device))
        bar.close()
        if on_done is not None:
            on_done(results[-1])
        overall.update(1)
    overall.close()
    return results


# ---- Ray --------------------------------------------------------------------------------------------
def _ray_unreachable(address: str) -> str:
    """What `--ray ADDRESS` tried, for the one-line error when no cluster answered."""
    env = os.environ.get("RAY_ADDRESS") or ""
    if env:
        return f"cannot connect to the Ray cluster at {env} (from the RAY_ADDRESS variable, which overrides {address!r})"
    if address == "auto":
        return ("no Ray cluster found (tried: the RAY_ADDRESS variable (unset), the address file that "
                "`ray start` leaves in Ray's temporary folder, and running Ray processes)")
    return f"cannot connect to a Ray cluster at {address} (tried that address; RAY_ADDRESS is unset)"


def connect_ray(address: str) -> Any:
    """The `ray` module, connected to `address` ('auto', 'host:port', or 'local' for a fresh
    one-machine instance); UnavailableError (one line) when Ray or the cluster is not there."""
    from spikesim._optional import require
    ray = require("ray", "cluster", "--ray (leave it out to use local processes)")
    if not ray.is_initialized():
        try:
            ray.init(address=None if address == "local" else address, log_to_driver=False,
                     runtime_env={"env_vars": {"PYTHONPATH": str(Path(__file__).resolve().parents[2])}})
        except ValueError as exc:  # a malformed address
            raise ValueError(f"--ray {address}: {exc}") from None
        except ConnectionError:
            raise UnavailableError(f"--ray {address}: {_ray_unreachable(address)}; start one with `ray start --head`, "
                                   "give its address, use --ray local for a one-machine instance, or leave out "
                                   "--ray to use local processes") from None
    return ray


def generate_ray(todo: list[SceneJob], root: Path, address: str, show_progress: bool,
                 device: str = "auto", on_done: OnDone = None) -> list[dict[str, Any]]:
    """One Ray task per scene; `root` must be a path every node can write (a shared filesystem)."""
    ray = connect_ray(address)
    remote = ray.remote(num_cpus=1)(run_job)
    refs = {remote.remote(job, str(root), None, "auto", 1, device): job for job in todo}
    results = []
    with progress_bar(total=len(todo), desc="scenes (ray)", unit="scene", quiet=not show_progress) as bar:
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1)
            for r in ready:
                refs.pop(r)
                results.append(ray.get(r))
                bar.update(1)
                if on_done is not None:
                    on_done(results[-1])
    return results


__all__ = ["generate_local", "generate_ray", "connect_ray", "die_with_parent"]
