"""The toolkit's one rule for SIGTERM: a long command asked to stop by SIGTERM (a scheduler's time
limit, `kill`) stops as Ctrl-C does, so the same clean-up runs.

It lives at the bottom of the package, below the dataset writers and the generation pipeline, so
that every layer that writes output (`spikesim.outputs`, the generators, the pipelines) can use it
without reaching upstream.
"""
from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Any, Iterator

__all__ = ["Terminated", "sigterm_raises", "stop_pool_workers", "TERMINATED_STATUS"]

#: The shell's status of a process ended by SIGTERM (128 + 15), which a command stopped by it returns.
TERMINATED_STATUS = 128 + 15


class Terminated(KeyboardInterrupt):
    """The run was asked to stop by SIGTERM. A KeyboardInterrupt, like Ctrl-C, so that the same
    clean-up runs (work folders removed, workers stopped) and no `except Exception` swallows it."""


#: The `sigterm_raises` blocks open in the main thread, and whether a SIGTERM has been turned into
#: `Terminated` in them: from then on every SIGTERM is ignored until the outermost block exits. An
#: inner block (the CLI's around `results_writing`) restored the outer one's handler as it exited,
#: so a second SIGTERM raised again in the outer block's clean-up (round seventeen).
_blocks = {"depth": 0, "terminating": False}


@contextmanager
def sigterm_raises() -> Iterator[None]:
    """Turn SIGTERM into `Terminated` in this (main) thread while the block runs; by default it
    would end the process at once, leaving the scenes in progress as `.work` debris and saying
    nothing. A second SIGTERM during the clean-up is ignored (SIGKILL still ends it), in this block
    and in every block around it, until the outermost one exits."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    stopped: list[str] = []

    def handler(signum: int, frame: Any) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if _blocks["terminating"]:
            return  # a later SIGTERM, during the clean-up of the first
        _blocks["terminating"] = True
        stopped.append(f"terminated ({signal.Signals(signum).name})")
        raise Terminated(stopped[-1])

    previous = signal.signal(signal.SIGTERM, signal.SIG_IGN if _blocks["terminating"] else handler)
    _blocks["depth"] += 1
    try:
        yield
    except Terminated:
        raise
    except BaseException as exc:
        if stopped:  # raised inside a library call, the signal's exception comes back wrapped (Dr.Jit's frozen
            raise Terminated(stopped[-1]) from exc  # functions re-raise it as a RuntimeError): still a SIGTERM
        raise
    finally:
        _blocks["depth"] -= 1
        if not _blocks["depth"]:
            _blocks["terminating"] = False
        signal.signal(signal.SIGTERM, signal.SIG_IGN if _blocks["terminating"] else previous)


def stop_pool_workers(pool: Any) -> None:
    """End a ProcessPoolExecutor's worker processes now (SIGTERM), rather than waiting for their
    jobs, after Ctrl-C or SIGTERM: leaving the pool's `with` block would otherwise wait for every
    running job (a scene, a training run) to finish. Each worker's own SIGTERM rule applies: a
    generation worker stops, a training worker finishes its step and writes last.pt."""
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        try:
            process.terminate()
        except (OSError, ValueError, AttributeError):
            pass
