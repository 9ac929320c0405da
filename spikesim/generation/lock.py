"""One `generate` run per output folder.

Two runs writing the same folder would rebuild the same scenes and rename over each other's work.
The first run holds an exclusive `flock` on a file inside the output root and records its pid and
command there; a second run fails at once naming that holder. The kernel releases a flock when its
holder dies, however it dies, so a lock file left by a killed run never blocks the next one (the
stale record in it is simply overwritten). On NFS, Linux maps flock to the server's POSIX locks.
"""
from __future__ import annotations

import fcntl
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from spikesim.dataset import LOCK_FILE, inside_root


class OutputLockedError(OSError):
    """The output folder is being written by another `generate` run."""


def _holder(fd: int) -> str:
    """The pid and command the holder recorded (it may not have written them yet)."""
    text = os.pread(fd, 4096, 0).decode("utf-8", "replace").strip()
    return text.splitlines()[0] if text else "a process that has not recorded its pid yet"


@contextmanager
def output_lock(root: str | Path, command: str) -> Iterator[Path]:
    """Hold the output root's lock for the duration of the block, or raise `OutputLockedError`
    (one line: the folder and the holder's pid and command) if another process holds it."""
    root = Path(root)
    path = inside_root(root, LOCK_FILE, follow=False)
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)  # the umask applies
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OutputLockedError(f"{root}: another generate run is writing here ({_holder(fd)}); "
                                    "wait for it to finish or stop it") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()}: {' '.join(command.split())}\n".encode(), 0)
        try:
            yield path
        finally:
            os.ftruncate(fd, 0)  # released: no holder to name
    finally:
        os.close(fd)  # closing the descriptor releases the flock


__all__ = ["output_lock", "OutputLockedError"]
