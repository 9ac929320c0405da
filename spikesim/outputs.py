"""Where a command may write: every output path stays inside the output root the user named.

Every command that writes (`generate`, `simulate`, `render`, `reconstruct`, `train`, `evaluate`,
`compare`, `panel`, `tradeoff`, `demo`, `golden --write`, `inspect --preview`) goes through these
functions, so that no name, `..`, absolute part or symlink found in an output folder can make it
write, replace or delete a file outside that folder:

- `inside` resolves a path under a root and refuses one that leaves it; for writes and deletes
  (`follow=False`) it also refuses a symlink at the path or at any folder between the root and the
  path, naming it. A link inside an output folder is never followed and never silently replaced:
  the user (or another program) put it there, and it may be the only way to that file; the message
  says to remove it or choose another folder. The root itself may be a link: the user named it.
- `atomic_write*` write a temporary file beside the target (created exclusively, so a planted
  file or link of that name is never opened) and rename it over the target: the target is whole
  or untouched, a failure removes the temporary file, and an OS error (a full disk, a read-only
  folder) names the target the user asked for, not the temporary file.
- `output_folder` makes the folder a command writes in and, if the command fails, removes the
  folders it made again when they are still empty, so a failed run leaves no new empty folder.
- `remove` deletes a file or folder inside the root, never through a link.
- `open_in_place` (and `in_place_fd`) open a file written in place (a log, a lock, an appended
  CSV) never through a symlink and never when the file has another name: writing through a hard
  link planted at its name would change a file outside the output (docs/CONTRACTS.md).
- `check_results_owned` / `results_writing` keep a record of the results a command wrote in a
  folder it shares with the user, so a rerun replaces its own and refuses to replace theirs; each
  result is recorded (under a lock) before it is renamed into place, so an interrupted or failed
  run never leaves a result its own rerun refuses.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import re
import secrets
import shutil
import stat
import sys
import threading
from pathlib import Path
from typing import Any, BinaryIO, Callable, Iterator, Sequence

from .signals import sigterm_raises  # the toolkit's one SIGTERM rule

_log = logging.getLogger(__name__)

LINK_REFUSED = ("is a symlink; files are not written or deleted through links (remove the link, or choose "
                "another output folder)")


def inside(root: str | Path, *parts: str | Path, follow: bool = True, what: str = "output root") -> Path:
    """`root` joined with `parts` and resolved, if that lies strictly inside the resolved root; a
    ValueError naming both otherwise (`..`, an absolute part, a symlink that leads out, or the
    root itself).

    `follow=False` (every write and delete): no component from the root down to the path may be
    a symlink either, even one that stays inside, so a link planted in the output cannot redirect
    a write or a delete to another file; the error names the link."""
    base = Path(os.path.realpath(root))
    given = Path(root).joinpath(*parts)
    path = Path(os.path.realpath(given))
    shown = Path(*parts) if parts else Path(".")
    if path == base:
        raise ValueError(f"{shown}: is the root itself ({base}), not a path inside it")
    if not path.is_relative_to(base):
        raise ValueError(f"{shown}: resolves to {path}, outside the {what} {base}")
    if not follow:
        step = Path(root)
        for part in Path(*parts).parts:
            step = step / part
            if step.is_symlink():
                raise ValueError(f"{step}: {LINK_REFUSED}")
    return path


def writable(root: str | Path, *parts: str | Path) -> Path:
    """The path to write or delete `parts` under `root`: `inside(..., follow=False)`."""
    return inside(root, *parts, follow=False)


def check_not_link(path: str | Path) -> Path:
    """`path`, if it is not a symlink (a ValueError naming it otherwise): the last check before a
    file is replaced, for writers handed a path rather than a root and a name."""
    path = Path(path)
    if path.is_symlink():
        raise ValueError(f"{path}: {LINK_REFUSED}")
    return path


#: What stands at an output path and is never replaced, not even with --overwrite: a rename over a
#: device node or FIFO replaced it (round eighteen: `simulate -o /dev/null --overwrite` as root).
_NOT_REPLACED = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                 (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"))


def check_replaceable(path: str | Path) -> Path:
    """`path`, if nothing stands there that a command must never replace (a link, a device, a FIFO,
    a socket); a ValueError naming it otherwise. Folders are each writer's own question."""
    path = check_not_link(path)
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return path
    kind = next((name for test, name in _NOT_REPLACED if test(mode)), None)
    if kind:
        raise ValueError(f"{path}: is {kind}, not a regular file; spikesim writes only regular files and replaces "
                         "nothing else: choose another output")
    return path


def naming(exc: OSError, path: str | Path) -> OSError:
    """`exc` as an OSError of the same errno that names `path` (the file the user asked for),
    whatever file, temporary or none, the failing call named. The CLI prints it in one line."""
    return OSError(exc.errno, exc.strerror or str(exc) or type(exc).__name__, str(path))


@contextlib.contextmanager
def writing(path: str | Path, stage: str | Path | None = None) -> Iterator[None]:
    """Inside the block, an OSError (a full disk, a read-only folder) is raised again naming
    `path`: for writes that go to a staging folder the user never sees. With `stage` (a hidden
    folder whose content will move to `path`'s folder), an error naming a file in the stage
    names that file's place beside `path` instead."""
    try:
        yield
    except OSError as exc:
        shown = Path(path)
        if stage is not None and exc.filename is not None:
            with contextlib.suppress(ValueError):
                shown = shown.parent / Path(os.fspath(exc.filename)).relative_to(stage)
        raise naming(exc, shown) from exc


def _temp_stem(path: Path, suffix: str) -> str:
    """The part of `path`'s name its temporary file keeps: a legal name of up to 255 bytes must
    leave room for the dot, the random part and the suffix."""
    room = 255 - 1 - 9 - len(suffix.encode())
    return path.name.encode()[:room].decode(errors="ignore")


def new_temp_beside(path: str | Path, suffix: str = ".part") -> Path:
    """Create an empty `.<name>.<random><suffix>` beside `path` and return it: created
    exclusively (O_EXCL, no link followed), mode 0666 masked by the user's umask like any file
    the user writes. An OSError names `path`."""
    path = Path(path)
    stem = _temp_stem(path, suffix)
    while True:
        tmp = path.with_name(f".{stem}.{secrets.token_hex(4)}{suffix}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise naming(exc, path) from exc
        os.close(fd)
        return tmp


def atomic_write_with(path: str | Path, write: Callable[[Path], Any], suffix: str = ".part") -> Path:
    """Call `write(tmp)`, which fills the temporary file `tmp` beside `path`, then rename it to
    `path`. A symlink, a device, a FIFO, a socket (check_replaceable) or a folder at `path` is
    refused; on any failure the temporary file is removed and `path` is as it was; an OSError names
    `path`."""
    path = check_replaceable(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a directory, expected a file name", str(path))
    tmp = new_temp_beside(path, suffix)
    try:
        try:
            write(tmp)
        except OSError as exc:
            raise naming(exc, path) from exc
        _put(tmp, path)  # an OSError names `path`, or the results record where that failed
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def atomic_write_file(path: str | Path, write: Callable[[BinaryIO], Any]) -> Path:
    """`atomic_write_with` for writers that take an open binary file (np.savez, torch.save,
    PIL, csv over a buffer): `write(f)` fills the temporary file, which is then renamed."""
    def fill(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            write(f)

    return atomic_write_with(path, fill)


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write `data` to `path` whole (see `atomic_write_with`)."""
    return atomic_write_with(path, lambda tmp: tmp.write_bytes(data))


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write `text` (UTF-8) to `path` whole (see `atomic_write_with`)."""
    return atomic_write_bytes(path, text.encode())


def atomic_write_json(path: str | Path, data: Any, **dumps: Any) -> Path:
    """Write `data` as JSON (indent 2 unless given, a final newline) to `path` whole."""
    dumps.setdefault("indent", 2)
    return atomic_write_text(path, json.dumps(data, **dumps) + "\n")


HARD_LINK_REFUSED = ("names a file that has {n} names (hard links); writing it in place would change the file "
                     "under its other names too, which may be outside the output: remove it, or choose another "
                     "output folder")


def in_place_fd(path: str | Path, flags: int) -> int:
    """A descriptor of `path` opened with `flags` (os.O_CREAT creates it), for writing in place:
    never through a symlink (O_NOFOLLOW) and never a file with more than one name (a hard link
    planted at a log's or lock's name), each refused with a ValueError naming `path`; an OSError
    names `path`. Call it before truncating or writing anything."""
    path = check_not_link(path)
    try:
        fd = os.open(path, flags | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0), 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP:  # a link made after the check above
            raise ValueError(f"{path}: {LINK_REFUSED}") from None
        raise naming(exc, path) from exc
    links = os.fstat(fd).st_nlink
    if links > 1:
        os.close(fd)
        raise ValueError(f"{path}: {HARD_LINK_REFUSED.format(n=links)}")
    return fd


def open_in_place(path: str | Path, mode: str) -> BinaryIO:
    """`path` opened for writing in place, as in_place_fd checks it: "ab" appends, "wb" truncates
    (after the checks, so a refused file is untouched); binary."""
    flags = {"ab": os.O_WRONLY | os.O_APPEND | os.O_CREAT, "wb": os.O_WRONLY | os.O_CREAT}
    if mode not in flags:
        raise ValueError(f"open_in_place: mode {mode!r}; expected 'ab' or 'wb'")
    fd = in_place_fd(path, flags[mode])
    if mode == "wb":
        os.ftruncate(fd, 0)
    return os.fdopen(fd, mode)


def append_text(path: str | Path, text: str) -> None:
    """Append `text` to `path` (created if missing), as open_in_place checks it (no symlink, no
    second name); an OSError names `path`."""
    with open_in_place(path, "ab") as f:
        try:
            f.write(text.encode())
        except OSError as exc:
            raise naming(exc, path) from exc


def make_dirs(root: str | Path, *parts: str | Path) -> Path:
    """Make the folder `root/parts` (and those between), refusing a symlink or a file at any of
    them; returns it. The root itself must exist (see `output_folder`)."""
    target = writable(root, *parts)
    step = Path(root)
    for part in Path(*parts).parts:
        step = step / part
        try:
            step.mkdir(exist_ok=True)
        except OSError as exc:
            raise naming(exc, step) from exc
        if not step.is_dir() or step.is_symlink():
            raise NotADirectoryError(errno.ENOTDIR, "exists and is not a folder", str(step))
    return target


_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0)


@contextlib.contextmanager
def parent_fd(root: str | Path, *parts: str | Path) -> Iterator[tuple[int, str]]:
    """(a descriptor of the folder that holds `root/parts`, the last part's name), the folder
    reached from the root one component at a time with openat and O_NOFOLLOW: a folder swapped
    for a link between a check and the use (a race) makes the open fail instead of following it,
    so a delete or a move by name in that descriptor can only touch the folder that was checked.
    The root itself may be a link the user named. Refusals name the part, as `inside` does."""
    with _open_parent(root, writable(root, *parts), Path(*parts).parts) as opened:
        yield opened


@contextlib.contextmanager
def _open_parent(root: str | Path, path: Path, rel: tuple[str, ...]) -> Iterator[tuple[int, str]]:
    """parent_fd's walk, for callers that have checked `path` (= writable(root, *rel)) already."""
    fd = os.open(root, _DIR_FLAGS)
    try:
        for i, part in enumerate(rel[:-1]):
            try:
                nxt = os.open(part, _DIR_FLAGS | getattr(os, "O_NOFOLLOW", 0), dir_fd=fd)
            except OSError as exc:
                if exc.errno in (errno.ELOOP, errno.ENOTDIR):  # swapped for a link or a file since the check
                    raise ValueError(f"{Path(root).joinpath(*rel[:i + 1])}: {LINK_REFUSED}") from None
                raise naming(exc, path) from exc
            os.close(fd)
            fd = nxt
        yield fd, rel[-1]
    finally:
        os.close(fd)


def remove(root: str | Path, *parts: str | Path) -> None:
    """Delete `root/parts` (a file or a whole folder) if it exists, guarded by `inside`: never
    outside the root, never through a link; a link at the name is refused, not deleted (it is
    not this command's to remove). The delete works on the folder's descriptor (`parent_fd`;
    shutil.rmtree with dir_fd), so a folder swapped for a link during it cannot redirect it."""
    path = writable(root, *parts)
    try:
        with _open_parent(root, path, Path(*parts).parts) as (fd, name):
            try:
                st = os.stat(name, dir_fd=fd, follow_symlinks=False)
            except FileNotFoundError:
                return
            if stat.S_ISLNK(st.st_mode):
                raise ValueError(f"{path}: {LINK_REFUSED}")
            if stat.S_ISDIR(st.st_mode):
                shutil.rmtree(name, dir_fd=fd)  # avoids symlink attacks where the platform has *at calls
            else:
                os.unlink(name, dir_fd=fd)
    except FileNotFoundError:
        return  # the root or a folder on the way does not exist: nothing to delete
    except OSError as exc:
        raise naming(exc, path) from exc


def move_into(src: str | Path, root: str | Path, *parts: str | Path) -> Path:
    """Move the file `src` (one this command made, in its own staging folder) to `root/parts`,
    replacing a file there: renamed into the folder's descriptor (`parent_fd`), so a folder
    swapped for a link cannot redirect it; a link or a folder at the name is refused."""
    path = writable(root, *parts)
    try:
        with _open_parent(root, path, Path(*parts).parts) as (fd, name):
            try:
                st = os.stat(name, dir_fd=fd, follow_symlinks=False)
                if stat.S_ISLNK(st.st_mode):
                    raise ValueError(f"{path}: {LINK_REFUSED}")
                if stat.S_ISDIR(st.st_mode):
                    raise IsADirectoryError(errno.EISDIR, "is a directory, expected a file name", str(path))
            except FileNotFoundError:
                pass
            os.rename(src, name, dst_dir_fd=fd)
    except OSError as exc:
        raise naming(exc, path) from exc
    return path


def missing_folders(path: str | Path) -> list[Path]:
    """`path` and its ancestors that do not exist yet, outermost first."""
    path = Path(path).absolute()
    missing = []
    for p in (path, *path.parents):
        if p.exists() or p.is_symlink():
            break
        missing.append(p)
    return missing[::-1]


@contextlib.contextmanager
def output_folder(path: str | Path) -> Iterator[Path]:
    """Make the output folder `path` (and missing parents) for the block; if the block fails,
    remove again the folders made here that are still empty, so a failed run leaves no new empty
    folder behind (a folder that existed before is never removed). An existing file at `path`
    is an error naming it."""
    path = Path(path)
    made = missing_folders(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise NotADirectoryError(errno.ENOTDIR, "exists and is not a folder", str(path)) from None
    except OSError as exc:
        raise naming(exc, path) from exc
    try:
        yield path
    except BaseException:
        discard_empty(made)
        raise


@contextlib.contextmanager
def output_file(path: str | Path) -> Iterator[Path]:
    """For a command whose output is one file (`simulate -o`, `panel -o`, `golden --write -o`):
    its folder made as `output_folder` does, and `path` itself refused if it is a symlink or a
    folder. Write it with `atomic_write_*` inside the block."""
    path = check_replaceable(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a directory, expected a file name", str(path))
    with output_folder(path.parent):
        yield path


def discard_empty(folders: list[Path]) -> None:
    """Remove each of `folders` (made by this run, outermost first) that is empty, innermost first."""
    for folder in reversed(folders):
        try:
            folder.rmdir()
        except OSError:
            break  # not empty (or gone): nor are the folders above it


__all__ = ["parent_fd", "move_into", "in_place_fd", "open_in_place", "HARD_LINK_REFUSED", "LINK_REFUSED", "inside", "writable", "check_not_link", "check_replaceable", "naming", "writing", "new_temp_beside",
           "atomic_write_with", "atomic_write_file", "atomic_write_bytes", "atomic_write_text", "atomic_write_json", "append_text",
           "make_dirs", "remove", "missing_folders", "output_folder", "output_file", "discard_empty",
           "output_file_lock", "stale_temporaries", "remove_temporaries"]


#: The record a command keeps in a results folder it shares with the user (evaluate's and sweep's
#: -o): which files it wrote there, by name and sha256, so that a rerun replaces its own results
#: and never a user's file of the same name (round eight: a user's metrics.md and sweep.md were
#: replaced, "replacing an earlier evaluation's").
RESULTS_RECORD = ".spikesim-results.json"

#: The lock beside the record, held (an exclusive flock) for each read-modify-write of the record,
#: so two commands writing one folder at once never lose each other's entries (round twelve: of 12
#: `inspect --preview` runs into one folder, as few as 3 were recorded). It exists only while a
#: command updates the record (removed while held, as spikesim.generation.lock removes its own);
#: one left by a killed command is the toolkit's, reused, never refused as the user's.
RESULTS_LOCK = ".spikesim-results.lock"

#: The names a command keeps in a results folder for itself: never a result's name.
RESULTS_OWN_FILES = (RESULTS_RECORD, RESULTS_LOCK)


#: Bytes a results record may hold: far above what a folder of results needs (about 180 bytes an
#: entry: 1 MiB held only about 5,800 long names, round thirteen), still bounded against a link to
#: a device.
RESULTS_RECORD_LIMIT = 64 * 2**20


def _results_record(out: Path) -> dict[str, Any]:
    """The folder's results record, read as every small file is (a FIFO there hung the command, a
    link to /dev/zero grew without bound: round nine). One that cannot be read is refused, naming
    it: read as empty, the next result rewrote it with one entry, so every earlier result was
    refused on its rerun, and a user's file of that name was replaced (round thirteen)."""
    from .config_io import read_json_object
    path = Path(out) / RESULTS_RECORD
    if not path.exists() and not path.is_symlink():
        return {}
    try:
        doc = read_json_object(path, "results record", finite=False, limit=RESULTS_RECORD_LIMIT)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot be read as spikesim's record of the results in {out} "
                         f"({' '.join(str(exc).split())[:200]}); move it away (the results it listed are then "
                         "treated as yours and kept), or choose another output folder") from None
    files = doc.get("files")
    if not isinstance(files, dict):
        raise ValueError(f"{path}: is not spikesim's record of the results in {out} (no \"files\" object); move "
                         "it away, or choose another output folder")
    return files


def _write_record(out: Path, files: dict[str, Any]) -> None:
    """The record written whole; an OSError (a full disk) names the record."""
    atomic_write_json(writable(out, RESULTS_RECORD), {"files": files}, indent=1)


#: The record locks this process holds, by (folder, thread): a results_writing block holds its
#: folder's lock for the whole block, and the per-file updates inside it take it again.
_HELD_RECORD_LOCKS: dict[tuple[str, int], int] = {}


@contextlib.contextmanager
def _record_lock(out: Path) -> Iterator[None]:
    """Hold the folder's record lock (RESULTS_LOCK, an exclusive flock, waiting for another command
    that holds it) for one read-modify-write of the record, or for a whole results_writing block;
    reentrant in one thread. The lock file is never opened through a link or a second name
    (in_place_fd) and must be a regular file; it is removed while held, and a command that locked
    it just as it was removed locks the new one (as generation.lock does)."""
    with _flock(Path(out), RESULTS_LOCK, "finish writing its results there", "the lock of the folder's results record"):
        yield


#: The suffix of an output file's lock (`output_file_lock`): `.<name>.spikesim-lock` beside it.
FILE_LOCK_SUFFIX = ".spikesim-lock"


@contextlib.contextmanager
def output_file_lock(path: str | Path) -> Iterator[bool]:
    """Hold the lock of the one output file `path` (`.<name>.spikesim-lock` beside it, an exclusive
    flock, waiting for another command that holds it, as the results record's lock does) while a
    command writes it: a command that holds it knows that no other writer of `path` is at work, so
    the temporary files of `path` it finds (`stale_temporaries`) are a killed run's (round
    seventeen: `simulate` left a partial stream of GBs beside -o for good). The folder must exist.
    Yields whether a killed writer of `path` left the lock (its pid and command were still in it):
    only then are temporaries of `path`'s form a writer's and not a user's (round eighteen)."""
    path = Path(path)
    with _flock(path.parent, f".{_temp_stem(path, FILE_LOCK_SUFFIX)}{FILE_LOCK_SUFFIX}", "finish writing it",
                f"the lock of {path.name}", shown=path) as left:
        yield left


@contextlib.contextmanager
def _flock(out: Path, name: str, waits: str, what: str, shown: Path | None = None) -> Iterator[bool]:
    """Hold an exclusive flock on the file `name` in the folder `out` (see `_record_lock`); `waits`
    and `what` word the warning of a wait and the refusal of a file that is not regular. Yields
    whether the lock held a holder's record when taken: a holder that ends removes it while it
    holds it, so one found with a record was left by a killed holder."""
    key = (os.path.realpath(out / name), threading.get_ident())
    if _HELD_RECORD_LOCKS.get(key):
        _HELD_RECORD_LOCKS[key] += 1
        try:
            yield False
        finally:
            _HELD_RECORD_LOCKS[key] -= 1
        return
    path = writable(out, name)
    gone = 0
    while True:
        try:
            fd = in_place_fd(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NONBLOCK", 0))
        except IsADirectoryError:  # a bare "Is a directory" (round eighteen)
            raise FileExistsError(f"{path}: is a folder, not a regular file, where spikesim keeps {what}; "
                                  "remove it") from None
        except FileNotFoundError:
            # the folder itself went: the writer this one waited for failed and removed the folder it
            # had made, now empty; make it again and lock there (round fifteen: the waiting writer
            # went on without the lock). Bounded, should something keep removing it.
            gone += 1
            if gone > 20:
                raise
            Path(out).mkdir(parents=True, exist_ok=True)
            continue
        except OSError as exc:  # a socket there: a bare "No such device or address" (round nineteen)
            if exc.errno != errno.ENXIO:
                raise
            raise FileExistsError(f"{path}: is a socket, not a regular file, where spikesim keeps {what}; "
                                  "remove it") from None
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise FileExistsError(f"{path}: is not a regular file, where spikesim keeps {what}; remove it")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:  # say whom it waits for: it hung silently behind a suspended sweep
                _log.warning("%s: waiting for %s to %s", shown or out, _record_holder(fd), waits)  # (round fourteen)
                fcntl.flock(fd, fcntl.LOCK_EX)
            try:
                now = os.stat(path, follow_symlinks=False)
                mine = os.fstat(fd)
                same = (now.st_ino, now.st_dev) == (mine.st_ino, mine.st_dev)
            except FileNotFoundError:
                same = False
        except BaseException:
            os.close(fd)
            raise
        if same:
            break
        os.close(fd)  # its holder removed it as we locked it: lock the file there now
    _HELD_RECORD_LOCKS[key] = 1
    try:  # only a holder's own record counts: "hello" or NULs a user left there are no killed writer's (round nineteen)
        left = re.match(rb"pid [0-9]+: ", os.pread(fd, 64, 0)) is not None
    except OSError:
        left = False
    with contextlib.suppress(OSError):  # who holds it, for a command that waits (a full disk: unnamed)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()}: {_command_line()}\n".encode(), 0)
    try:
        yield left
    finally:
        _HELD_RECORD_LOCKS.pop(key, None)
        with contextlib.suppress(OSError):
            path.unlink()  # removed while held: a command waiting on it locks a new one
        os.close(fd)  # closing the descriptor releases the flock


def _command_line() -> str:
    """This process's command, shortened, as a lock records its holder."""
    words = [Path(sys.argv[0]).name, *sys.argv[1:]] if sys.argv and sys.argv[0] else ["python"]
    text = " ".join(" ".join(words).split())
    return text if len(text) <= 200 else text[:199] + "…"


def _record_holder(fd: int) -> str:
    """The pid and command the record lock's holder wrote there (it may not have written them yet)."""
    try:
        text = os.pread(fd, 400, 0).decode("utf-8", "replace").strip()
    except OSError:
        text = ""
    return text.splitlines()[0] if text else "another command"


def _stale_temporaries(out: Path, names: Sequence[str]) -> list[Path]:
    """The temporary files of `names` in `out`, and of its results record, that a killed command
    left (`stale_temporaries`). Called under the folder's record lock, when no other results block
    of this folder is writing."""
    return stale_temporaries(out, [*names, RESULTS_RECORD])


def stale_temporaries(out: str | Path, names: Sequence[str | Path], suffix: str = ".part") -> list[Path]:
    """The temporary files (`new_temp_beside`'s `.<name>.<8 hex><suffix>`) of `names` (paths inside
    `out`) that a killed command left: regular files only, no link. Only where no live writer of
    those names can be at work: under the lock every writer of them holds."""
    out = Path(out)
    wanted: dict[Path, set[str]] = {}
    for name in names:
        target = out / name
        wanted.setdefault(target.parent, set()).add(_temp_stem(target, suffix))
    pattern = re.compile(r"\.(.+)\.[0-9a-f]{8}" + re.escape(suffix))
    found = []
    for folder, stems in wanted.items():
        try:
            entries = list(os.scandir(folder))
        except OSError:
            continue
        for entry in entries:
            match = pattern.fullmatch(entry.name)
            if match and match.group(1) in stems and entry.is_file(follow_symlinks=False):
                found.append(Path(entry.path))
    return found


def remove_temporaries(out: str | Path, temporaries: Sequence[Path], command: str,
                       say: Callable[[str], None] | None = None) -> None:
    """Remove each of `temporaries` (`stale_temporaries`' answer for `out`), saying so in a line
    each (`say`, by default this module's log); one that cannot be removed is left."""
    out = Path(out)
    for temporary in temporaries:
        with contextlib.suppress(OSError, ValueError):
            remove(out, temporary.relative_to(out))
            (say or _log.info)(f"{out}: removed {temporary.relative_to(out)}, a temporary file an interrupted "
                               f"{command} left")


def _check_record_path(out: Path, names: Sequence[str], command: str, flag: str) -> None:
    """The record's own name (and its lock's) is no result, and what stands at the record's and the
    lock's paths is a regular file or nothing: a folder, link or FIFO there failed only after the
    results were written, leaving them unrecorded, so every rerun refused them; a golden reference
    named like the record was overwritten by the record (round ten). Refused before any work."""
    for name in names:
        if Path(name).name in RESULTS_OWN_FILES:
            own = Path(name).name
            raise ValueError(f"{out / own}: {own} is where spikesim records which results in a folder are its own, "
                             f"so no {command} result may take that name; choose another {flag}")
    for own in RESULTS_OWN_FILES:
        path = out / own
        if path.is_symlink() or (path.exists() and not path.is_file()):
            raise FileExistsError(f"{path}: is not a regular file (a folder, link or FIFO), where {command} records "
                                  f"which results it wrote there; remove it, or choose another {flag}")


def _is_own(entry: Any, path: Path, command: str) -> bool:
    """Whether the file at `path` is one `command` wrote, as its record `entry` says: a regular file
    whose sha256 is the one recorded, or the one it had before (`previous`: a result recorded just
    before it replaced its own earlier one, whose rename an interruption may have stopped)."""
    from .dataset import sha256_file  # imported here: spikesim.dataset imports this module
    if not (isinstance(entry, dict) and entry.get("command") == command):
        return False
    # only strings count: a hash edited into a list or object crashed the set (round fourteen)
    known = {value for value in (entry.get("sha256"), entry.get("previous")) if isinstance(value, str)}
    try:
        return path.is_file() and not path.is_symlink() and sha256_file(path) in known
    except OSError:
        return False


def _refusal(out: Path, theirs: Sequence[str], command: str, flag: str) -> FileExistsError:
    return FileExistsError(f"{out}: holds {', '.join(theirs)}, which no earlier {command} run wrote there (or it "
                           f"was changed since); {command} would replace {'it' if len(theirs) == 1 else 'them'}: "
                           f"choose another {flag}, or move them")


def check_results_owned(out: str | Path, names: Sequence[str], command: str, flag: str = "-o") -> list[str]:
    """The names of `names` in `out` that an earlier `command` run wrote (as its record there
    says, with the same content): a rerun replaces those. Any other existing file of those names
    is the user's: refused, named, before any work. `results_writing` checks again just before
    the writing, which refuses a file the user put there while the command ran (round ten: golden
    and panel replaced one)."""
    out = Path(out)
    _check_record_path(out, names, command, flag)
    listed = _results_record(out)
    ours, theirs = [], []
    for name in names:
        path = out / name
        if not path.exists() and not path.is_symlink():
            continue
        (ours if _is_own(listed.get(name), path, command) else theirs).append(name)
    if theirs:
        raise _refusal(out, theirs, command, flag)
    return ours


def recorded_results(out: str | Path, command: str) -> list[str]:
    """The names the folder's results record lists as `command`'s (as stale candidates: a rerun
    that writes fewer results, such as a demo of other scenes, drops the rest)."""
    return [name for name, entry in _results_record(Path(out)).items()
            if isinstance(entry, dict) and entry.get("command") == command]


def _drop_own(out: Path, files: dict[str, Any], names: Sequence[str], command: str) -> bool:
    """Remove each of `names` that `files` lists as `command`'s and is unchanged, and drop every such
    entry (a changed file is the user's now: kept, no longer listed). Whether `files` changed."""
    changed = False
    for name in dict.fromkeys(names):
        entry = files.get(name)
        if not isinstance(entry, dict) or entry.get("command") != command:
            continue
        path = out / name
        try:
            if _is_own(entry, path, command):
                remove(out, name)
        except (OSError, ValueError):
            continue  # not removed: still listed, so a rerun removes it
        del files[name]
        changed = True
    return changed


def record_results_owned(out: str | Path, names: Sequence[str], command: str, stale: Sequence[str] = ()) -> None:
    """Add the files `names` (already written in `out` by `command`) to the folder's results record,
    with their content now. `stale`: earlier results of this command (check_results_owned's answer)
    that this run did not write again, removed if still unchanged (round ten). Commands write their
    results inside `results_writing`, which records each before it is renamed into place; this is
    for files written some other way."""
    from .dataset import sha256_file
    out = Path(out)
    with _record_lock(out):
        files = _results_record(out)
        _drop_own(out, files, [name for name in stale if name not in names], command)
        for name in names:
            if (out / name).is_file() and not (out / name).is_symlink():
                files[name] = {"command": command, "sha256": sha256_file(out / name)}
        _write_record(out, files)


class _ResultsWriting:
    """One `results_writing` block: the folder, the result names and the command."""

    def __init__(self, out: Path, names: Sequence[str], command: str, flag: str):
        self.out, self.command, self.flag = out, command, flag
        self.base = os.path.realpath(out)
        self.names = {os.path.normpath(name): name for name in names}

    def name_of(self, path: Path) -> str | None:
        """The result name `path` is in this block's folder, or None."""
        rel = os.path.relpath(os.path.realpath(path), self.base)
        return self.names.get(os.path.normpath(rel))

    def put(self, tmp: Path, path: Path, name: str) -> None:
        """Rename the written `tmp` to the result `path`, recording its sha256 first, both under the
        record lock: a failure to record (a full disk) leaves `path` as it was, and an interruption
        between the two leaves `path` as it was, whose content the record still accepts (`previous`)."""
        from .dataset import sha256_file
        new = sha256_file(tmp)
        with _record_lock(self.out):
            files = _results_record(self.out)
            entry = files.get(name)
            target = self.out / name
            previous = None
            if target.exists() or target.is_symlink():
                # again, right before the rename: a file the user put there while the command ran
                if not _is_own(entry, target, self.command):
                    raise _refusal(self.out, [name], self.command, self.flag)
                previous = sha256_file(target)
            files[name] = {"command": self.command, "sha256": new,
                           **({"previous": previous} if previous not in (None, new) else {})}
            _write_record(self.out, files)
            try:
                os.replace(tmp, path)
            except OSError as exc:
                raise naming(exc, path) from exc


_WRITING: list[_ResultsWriting] = []
_WRITING_GUARD = threading.Lock()


def _put(tmp: Path, path: Path) -> None:
    """atomic_write_with's rename: through the record of a `results_writing` block whose result
    `path` is, else a plain rename (an OSError names `path`)."""
    with _WRITING_GUARD:
        blocks = list(_WRITING)
    for block in reversed(blocks):
        name = block.name_of(path)
        if name is not None:
            block.put(tmp, path, name)
            return
    try:
        os.replace(tmp, check_replaceable(path))  # again: a FIFO or device put there while it was written
    except OSError as exc:
        raise naming(exc, path) from exc


@contextlib.contextmanager
def results_writing(out: str | Path, names: Sequence[str], command: str, flag: str = "-o",
                    stale: Sequence[str] = ()) -> Iterator[list[str]]:
    """Write the results `names` of `command` in `out` inside this block, each with `atomic_write_*`
    (directly or through any writer built on them). The block

    - checks `names` again (check_results_owned): a file the user put there while the command
      ran is refused before anything is written;
    - removes this command's own earlier results among `names` and `stale` (an earlier run's
      results this run does not write again, such as a plot a `--no-plot` rerun does not draw:
      round ten) if unchanged, so the folder never holds a mix of two runs' results (round twelve:
      a sweep stopped while drawing left its new tables beside the last run's plot); a changed one
      is the user's now, kept and no longer listed;
    - records each result's sha256 before renaming it into place, under the record lock: an
      interrupted or failed run (SIGTERM while plotting, a full disk at the record) leaves only
      results its record lists, which the rerun replaces as its own (round twelve: every rerun was
      refused), and concurrent commands never lose each other's entries.

    The whole block holds the folder's record lock, so a second command writing results there
    waits for the first to finish: two `evaluate -o X` at once left one run's metrics.csv beside the
    other's metrics.md (round thirteen). SIGTERM inside it stops the command as Ctrl-C does
    (`sigterm_raises`), so no temporary file or lock is left behind (round thirteen).

    Yields the names that an earlier run wrote (check_results_owned's answer)."""

    out = Path(out)
    ours = check_results_owned(out, names, command, flag)  # a user's file: refused before the lock
    with contextlib.ExitStack() as held:
        held.enter_context(sigterm_raises())
        # the folder made first (and removed again if the block fails and leaves it empty): a lock
        # cannot be taken in a folder that does not exist yet, so two first runs into a new -o
        # wrote without it and mixed their csv and md (round fourteen)
        held.enter_context(output_folder(out))
        try:
            held.enter_context(_record_lock(out))
        except FileExistsError:
            raise  # a folder, link or FIFO at the lock's name: refused, named
        except OSError:
            pass  # a folder no file can be made in: the first result's write fails, naming that result
        ours = check_results_owned(out, names, command, flag)
        # a killed run's temporaries (round fourteen), where a record shows that spikesim wrote results
        # here: a user's file of that form in a folder spikesim never wrote is kept (round fifteen)
        if (out / RESULTS_RECORD).is_file():
            remove_temporaries(out, _stale_temporaries(out, [*names, *stale]), command)
        files = _results_record(out)
        if _drop_own(out, files, [*names, *stale], command):
            _write_record(out, files)
        block = _ResultsWriting(out, names, command, flag)
        with _WRITING_GUARD:
            _WRITING.append(block)
        try:
            yield ours
        finally:
            with _WRITING_GUARD:
                _WRITING.remove(block)
