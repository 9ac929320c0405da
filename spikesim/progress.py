"""Progress bars, one definition for every long job: a rate and an ETA on a terminal, nothing
under `--quiet` or when stderr is not a terminal (logs, CI, pipes), so output files and logs stay
clean. Long jobs show one bar for the whole job and at most one nested bar for the current part
(a scene, a run); never one bar per epoch."""
from __future__ import annotations

import sys
from typing import Any, Iterable

# Rate and ETA in every bar: tqdm's default layout with the unit spelled out.
_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}, {rate_fmt}{postfix}]"


def shows_progress(quiet: bool = False, stream: Any = None) -> bool:
    """True when bars should be drawn: not quiet, and the stream is an interactive terminal."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return not quiet and bool(isatty and isatty())


def progress_bar(iterable: Iterable[Any] | None = None, *, total: int | None = None, desc: str = "",
                 unit: str = "it", quiet: bool = False, nested: bool = False, initial: int = 0,
                 position: int | None = None) -> Any:
    """A tqdm bar on stderr. `nested` bars sit below the job's bar and vanish when done."""
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, initial=initial, file=sys.stderr,
                disable=not shows_progress(quiet), leave=not nested,
                position=(1 if nested else 0) if position is None else position,
                bar_format=_FORMAT, mininterval=0.5, dynamic_ncols=True)
