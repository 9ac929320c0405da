"""One run per output folder: `generate`, and `train` in its run folder.

Two runs writing the same folder would rebuild the same scenes and rename over each other's work.
The first run holds an exclusive `flock` on a file inside the output root and records its pid and
command there; a second run fails at once naming that holder. The kernel releases a flock when its
holder dies, however it dies, so a lock file left by a killed run never blocks the next one (the
stale record in it is simply overwritten). A run that ends removes the file (while still holding
it), so the file exists only while a run writes, and always names that run; a run that locked the
file just as it was removed finds it gone (or another file in its place) and locks the new one. On
NFS, Linux maps flock to the server's POSIX locks.
"""
from __future__ import annotations

import fcntl
import os
import stat
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from spikesim.dataset import LOCK_FILE, inside_root
from spikesim.outputs import in_place_fd, naming


class OutputLockedError(OSError):
    """The output folder is being written by another `generate` run."""


def _holder(fd: int) -> str:
    """The pid and command the holder recorded (it may not have written them yet)."""
    text = os.pread(fd, 4096, 0).decode("utf-8", "replace").strip()
    return text.splitlines()[0] if text else "a process that has not recorded its pid yet"


#: The words before the command's own name in a recorded command line (`spikesim generate ...`,
#: `python -m pipelines.cli sweep ...`).
_LAUNCHERS = {"spikesim", "-m", "pipelines.cli", "spikesim.cli"}


def _holder_kind(holder: str, what: str) -> str:
    """What the holder is, from the command it recorded ("pid N: sweep ..." -> "sweep run"), so a
    `tradeoff` blocked by a sweep names the sweep (it said "another tradeoff run ... (pid N: sweep)",
    round twelve); `what` (the blocked command's own kind) when the record does not tell."""
    _, sep, command = holder.partition(": ")
    if not holder.startswith("pid ") or not sep:
        return "run" if what.endswith(" run") else what
    for word in command.split():
        name = os.path.basename(word)
        if name in _LAUNCHERS or name.startswith("python"):
            continue
        if name.replace("-", "").replace("_", "").isalnum() and not name.startswith("-"):
            return f"{name} run"
        break
    return what


@contextmanager
def output_lock(root: str | Path, command: str, what: str = "generate run") -> Iterator[Path]:
    """Hold the output root's lock for the duration of the block, or raise `OutputLockedError`
    (one line: the folder and the holder's pid and command) if another process holds it."""
    root = Path(root)
    path = inside_root(root, LOCK_FILE, follow=False)
    fd = _lock(root, path, what)
    try:
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()}: {' '.join(command.split())}\n".encode(), 0)
        except OSError as exc:  # a full disk said "[Errno 28] No space left on device", naming no file, and
            # left the empty lock file, so the output folder made for the run stayed behind (round twelve)
            path.unlink(missing_ok=True)  # removed while held, as at the end of a run
            raise naming(exc, path) from exc
        try:
            yield path
        finally:
            path.unlink(missing_ok=True)  # removed while held: a run waiting on it locks a new one
    finally:
        os.close(fd)  # closing the descriptor releases the flock


def _lock(root: Path, path: Path, what: str = "generate run") -> int:
    """A descriptor of the lock file at `path`, flocked, that is still the file at `path`."""
    while True:
        # no symlink and no second name (a hard link planted at the lock's name would be truncated
        # below: spikesim.outputs.in_place_fd); the umask applies
        fd = in_place_fd(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NONBLOCK", 0))
        if not stat.S_ISREG(os.fstat(fd).st_mode):  # a FIFO there failed later as "[Errno 22]", naming nothing (round nine)
            os.close(fd)
            raise ValueError(f"{path}: is not a regular file, where a {what} keeps its lock; remove it")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise OutputLockedError(f"{root}: another {_holder_kind(holder, what)} is writing here ({holder}); "
                                    "wait for it to finish or stop it") from None
        try:
            same = os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # its holder removed it as we locked it: lock the file there now


__all__ = ["output_lock", "OutputLockedError"]
