"""Spike streams in memory (bit-packed) and on disk in the PKU `.dat` format.

The `.dat` layout (docs/design.md section 3): frames one after another; each frame row-scanned,
8 pixels per byte, least significant bit first; rows stored bottom-up (vertically flipped) by
real cameras and the readers of their recordings (Spk2ImgNet, WGSE, SSML, SpikeCV). The group's
simulators (SPCS, SCSim) and the LR-Rep authors' loader use top-down rows: pass `flip=False` for
those. Some real recordings are 416 columns wide: each stored row is the 400 image columns followed
by 16 extra ("header") columns, which readers drop (see `DatReader`).

In memory a stream is `packed`, uint8 (N, ceil(H*W/8)): each frame flattened row-major and
packed LSB first, top-down. With W a multiple of 8 (400 and 416 are) a flip is a byte reshuffle.
"""
from __future__ import annotations

import errno
import json
import math
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from . import outputs
from .config_io import SMALL_FILE_LIMIT, file_problem, read_json_object


def frame_bytes(height: int, width: int) -> int:
    return (height * width + 7) // 8


@dataclass
class SpikeStream:
    """A binary spike stream of N readouts of H x W pixels, bit-packed."""

    packed: np.ndarray
    height: int
    width: int

    def __post_init__(self) -> None:
        for name in ("height", "width"):  # height -1 or 2.5 was taken (round thirteen)
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"SpikeStream {name} must be a positive integer, got {v!r}")
            setattr(self, name, int(v))
        self.packed = np.asarray(self.packed)
        if self.packed.dtype != np.uint8 or self.packed.ndim != 2:
            raise ValueError(f"packed must be uint8 (N, bytes), got {self.packed.dtype} {self.packed.shape}")
        if self.packed.shape[1] != frame_bytes(self.height, self.width):
            raise ValueError(f"packed frames have {self.packed.shape[1]} bytes; {self.height}x{self.width} "
                             f"needs {frame_bytes(self.height, self.width)}")

    @property
    def num_steps(self) -> int:
        return int(self.packed.shape[0])

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.num_steps, self.height, self.width)

    def __len__(self) -> int:
        return self.num_steps

    def unpack(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Frames [start, stop) as bool (n, H, W)."""
        return unpack_frames(self.packed[start:stop], self.height, self.width)

    def slice(self, start: int = 0, stop: int | None = None) -> "SpikeStream":
        return SpikeStream(self.packed[start:stop], self.height, self.width)

    def counts(self, start: int = 0, stop: int | None = None, chunk: int = 4096) -> np.ndarray:
        """Spikes per pixel over [start, stop), int64 (H, W), without unpacking it all at once."""
        _check_chunk(chunk, "SpikeStream.counts")
        stop = self.num_steps if stop is None else stop
        for name, v in (("start", start), ("stop", stop)):  # a reversed or outside range counted nothing, silently
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise ValueError(f"SpikeStream.counts: {name} must be an integer, got {v!r}")
        if not 0 <= start <= stop <= self.num_steps:
            raise ValueError(f"SpikeStream.counts: steps [{start}, {stop}) are not within the stream's "
                             f"[0, {self.num_steps}) in order")
        total = np.zeros(self.height * self.width, dtype=np.int64)
        for a in range(start, stop, chunk):
            bits = np.unpackbits(self.packed[a:min(stop, a + chunk)], axis=1, bitorder="little",
                                 count=self.height * self.width)
            total += bits.sum(axis=0, dtype=np.int64)
        return total.reshape(self.height, self.width)

    @classmethod
    def from_bool(cls, frames: np.ndarray) -> "SpikeStream":
        """Pack (N, H, W) spike frames, row 0 at the top: bool, or numbers that are all 0 or 1 (0.3 and
        255 were taken as spikes, while model.reconstruct refuses them: round twelve)."""
        frames = np.asarray(frames)
        if frames.ndim != 3:
            raise ValueError(f"expected (N, H, W) spike frames, got shape {frames.shape}")
        if frames.dtype != np.bool_:
            if frames.dtype.kind not in "iuf":
                raise ValueError(f"spike frames are bool or hold only 0 and 1, got dtype {frames.dtype}")
            bad = ~((frames == 0) | (frames == 1))
            if bad.any():
                first = frames[bad][0].item()
                raise ValueError(f"spike frames hold only 0 and 1 (or are bool); these hold {first!r} "
                                 f"({int(bad.sum())} value(s) that are neither, dtype {frames.dtype})")
        n, h, w = frames.shape
        return cls(pack_frames(frames), h, w)

    @classmethod
    def concatenate(cls, parts: Iterable["SpikeStream"]) -> "SpikeStream":
        parts = list(parts)
        if not parts:
            raise ValueError("nothing to concatenate")
        h, w = parts[0].height, parts[0].width
        if any((p.height, p.width) != (h, w) for p in parts):
            raise ValueError("streams of different frame sizes cannot be concatenated")
        return cls(np.concatenate([p.packed for p in parts], axis=0), h, w)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, SpikeStream) and self.shape == other.shape
                and bool(np.array_equal(self.packed, other.packed)))


def _check_chunk(chunk: Any, who: str) -> None:
    """A chunk size is a positive integer: 0 raised "range() arg 3 must not be zero" and -1 gave
    no chunks at all (round twelve)."""
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"{who}: chunk must be a positive number of frames, got {chunk!r}")


def _check_stream_arg(stream: Any, who: str) -> None:
    """`stream` is a SpikeStream: an array failed with "'numpy.ndarray' object has no attribute
    'height'" (round twelve)."""
    if not isinstance(stream, SpikeStream):
        raise TypeError(f"{who}: expected a SpikeStream, got {type(stream).__module__}.{type(stream).__name__}"
                        + ("; SpikeStream.from_bool(frames) packs (N, H, W) 0/1 frames (row 0 at the top)"
                           if isinstance(stream, np.ndarray) or hasattr(stream, "__array__") else ""))


def pack_frames(frames: np.ndarray) -> np.ndarray:
    n = frames.shape[0]
    if n == 0:  # no frames: reshape(0, -1) raised NumPy's error instead of the writers' own (round thirteen)
        return np.zeros((0, frame_bytes(*frames.shape[1:3])), np.uint8)
    flat = np.ascontiguousarray(frames.reshape(n, -1)).astype(bool, copy=False)
    return np.packbits(flat, axis=1, bitorder="little")


def unpack_frames(packed: np.ndarray, height: int, width: int) -> np.ndarray:
    if packed.shape[0] == 0:  # no frames: reshape(-1, ...) of nothing raised NumPy's error (round nine)
        return np.zeros((0, height, width), bool)
    bits = np.unpackbits(packed, axis=1, bitorder="little", count=height * width)
    return bits.reshape(-1, height, width).view(bool)


def _flip_packed(packed: np.ndarray, height: int, width: int) -> np.ndarray:
    """Reverse the row order of packed frames (its own inverse)."""
    if packed.shape[0] == 0:  # no frames: reshape(0, -1) raised NumPy's error, as pack_frames did (round seventeen)
        return packed
    if width % 8 == 0:
        return np.ascontiguousarray(packed.reshape(-1, height, width // 8)[:, ::-1, :]).reshape(packed.shape[0], -1)
    return pack_frames(unpack_frames(packed, height, width)[:, ::-1, :])


# ---- writing ------------------------------------------------------------------------------------
def open_temp_beside(path: str | Path, suffix: str = ".part") -> tuple[Any, Path]:
    """A new file `.<name>.<random><suffix>` in `path`'s folder, opened for binary writing.

    Created with mode 0666 masked by the user's umask, like any file the user writes (mkstemp's
    0600 would make shared datasets unreadable to others); O_EXCL so it never reuses a file.
    """
    # it is replaced by a rename: a link, device, FIFO or socket there is refused (round twenty: the Python
    # writers replaced a character device with a regular file, where the CLI refused it)
    path = outputs.check_replaceable(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a directory; give a file name to write", str(path))
    parent = next((p for p in (path.parent, *path.parent.parents) if p.exists() or p.is_symlink()), None)
    if parent is not None and not parent.is_dir():  # "File exists" named no culprit (round twenty-one)
        what = (file_problem(parent) or "is a file").replace(", not a regular file", "")
        raise NotADirectoryError(errno.ENOTDIR, f"{what}, not a folder, where the folder of {path.name} would be",
                                 str(parent))
    with outputs.writing(path.parent):
        path.parent.mkdir(parents=True, exist_ok=True)
    tmp = outputs.new_temp_beside(path, suffix)
    return open(tmp, "wb"), tmp


def _check_geometry_args(height: Any, width: Any, flip: Any, who: str, optional: bool = False) -> None:
    """A stream's height and width are positive integers and flip a bool (None where `optional`:
    the recorded value): flip="false" was taken as True, height=0 as "not given", "12" as a
    TypeError from deep inside (round seven)."""
    for name, v in (("height", height), ("width", width)):
        if optional and v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{who}: {name} must be a positive integer{' or None' if optional else ''}, got {v!r}")
    if not (isinstance(flip, (bool, np.bool_)) or (optional and flip is None)):
        raise ValueError(f"{who}: flip must be True or False{' or None' if optional else ''}, got {flip!r}")


class DatWriter:
    """Append packed frames to a `.dat` file; it appears under its name only on `close()`.

    Writes go to a temporary file in the same folder, renamed on success, so an interrupted run
    never leaves a truncated stream that looks complete. A stream of no frames is an error, not
    an empty file, and any failure (including the final rename) removes the temporary file.
    """

    def __init__(self, path: str | Path, height: int, width: int, flip: bool = True):
        self.path = Path(path)
        _check_geometry_args(height, width, flip, "DatWriter")
        self.height, self.width, self.flip = height, width, flip
        self._file, self._tmp = open_temp_beside(self.path)
        self.num_steps = 0

    def write(self, stream: SpikeStream) -> None:
        _check_stream_arg(stream, "DatWriter.write")
        if (stream.height, stream.width) != (self.height, self.width):
            raise ValueError(f"stream is {stream.height}x{stream.width}, writer is {self.height}x{self.width}")
        data = _flip_packed(stream.packed, self.height, self.width) if self.flip else stream.packed
        with outputs.writing(self.path):  # a full disk names the stream, not its temporary file
            self._file.write(np.ascontiguousarray(data).tobytes())
        self.num_steps += stream.num_steps

    def close(self) -> Path:
        try:
            if self.num_steps == 0:
                raise ValueError(f"{self.path}: no frames were written; not creating an empty stream")
            with outputs.writing(self.path):
                self._file.flush()
                os.fsync(self._file.fileno())
                self._file.close()
                # a sidecar beside the file it replaces describes the old stream: readers took the new one
                # with the old geometry (round seven); a writer that records one writes it after this
                side = sidecar_path(self.path)
                # a file of that name that is not one is the user's (round twenty)
                if is_stream_sidecar(side, beside_stream=self.path.is_file()):
                    side.unlink()
                os.replace(self._tmp, outputs.check_replaceable(self.path))
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        self._file.close()
        self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> "DatWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_dat(path: str | Path, stream: SpikeStream, flip: bool = True) -> Path:
    """Write a stream as a PKU `.dat` file (atomically)."""
    _check_stream_arg(stream, "write_dat")
    with DatWriter(path, stream.height, stream.width, flip=flip) as w:
        w.write(stream)
    return Path(path)


# ---- reading ------------------------------------------------------------------------------------
class DatReader:
    """Memory-mapped `.dat` reader: any time range without loading the file.

    `header_columns` are extra columns stored at the END of each row by some real cameras
    (416-wide recordings: 400 image columns, then 16), dropped on read; `width` is the image width
    without them. This is the ecosystem's convention: SpikeCV's `SpikeStream` deletes column
    indices 400-415 of each 416-wide row (`get_row_index`), and Spike-Zoo's `load_vidar_dat` with
    `remove_head=True` keeps all but the last 16 columns; both do so after decoding each frame
    with its rows flipped, so the columns are the same whichever way the rows are stored.
    """

    def __init__(self, path: str | Path, height: int | None = None, width: int | None = None, flip: bool | None = None,
                 header_columns: int = 0, drop_partial: bool = False):
        """height, width, flip None: as recorded beside the stream (its `.dat.json` sidecar or a
        dataset's meta.json), else the PKU camera's 250 x 400 with rows bottom-up."""
        self.path = Path(path)
        _check_geometry_args(height, width, flip, "DatReader", optional=True)
        if isinstance(header_columns, bool) or not isinstance(header_columns, (int, np.integer)):
            raise ValueError(f"DatReader: header_columns must be an integer >= 0, got {header_columns!r}")
        height, width, flip = stream_geometry(self.path, height, width, flip)
        if height <= 0 or width <= 0 or header_columns < 0:
            raise ValueError(f"bad frame geometry height={height} width={width} header_columns={header_columns}")
        self.height, self.width, self.flip = height, width, flip
        self.header_columns = header_columns
        self.stored_width = width + header_columns
        self.frame_bytes = frame_bytes(height, self.stored_width)
        size = _stream_size(self.path)
        full, rest = divmod(size, self.frame_bytes)
        if rest and not drop_partial:
            raise ValueError(
                f"{self.path}: {size} bytes is not a whole number of {height}x{self.stored_width} frames "
                f"({self.frame_bytes} bytes each; {full} frames and {rest} bytes left over). The geometry is "
                "likely wrong: give height, width and header_columns as the recording has them (a sidecar or "
                "meta.json records them). Only for a file cut off mid-frame, drop_partial=True (the commands "
                "inspect, reconstruct and panel: --drop-partial) ignores the partial last frame.")
        self.num_steps = full
        self._mm = np.memmap(self.path, dtype=np.uint8, mode="r", shape=(full, self.frame_bytes)) if full else np.zeros((0, self.frame_bytes), np.uint8)

    def __len__(self) -> int:
        return self.num_steps

    def read(self, start: int = 0, stop: int | None = None) -> SpikeStream:
        stop = self.num_steps if stop is None else stop
        for name, v in (("start", start), ("stop", stop)):  # 2.5 and "0" raised Python's own TypeErrors (round seventeen)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise ValueError(f"DatReader.read: {name} must be an integer, got {v!r}")
        if not (0 <= start <= stop <= self.num_steps):
            raise IndexError(f"{self.path}: range [{start}, {stop}) is outside the stream's {self.num_steps} frames")
        raw = np.asarray(self._mm[start:stop])
        h, sw = self.height, self.stored_width
        if self.flip:
            raw = _flip_packed(raw, h, sw)
        if self.header_columns:
            raw = _drop_trailing_columns(raw, h, sw, self.width)
        return SpikeStream(raw, h, self.width)

    def iter_chunks(self, chunk: int = 1024) -> Iterator[SpikeStream]:
        _check_chunk(chunk, "DatReader.iter_chunks")
        return self._chunks(chunk)

    def _chunks(self, chunk: int) -> Iterator[SpikeStream]:
        for a in range(0, self.num_steps, chunk):
            yield self.read(a, min(self.num_steps, a + chunk))


def _stream_size(path: Path) -> int:
    """The size of a `.dat` file; a missing file, a directory or anything else that is not a regular
    file is an error naming it, before it is opened (round seventeen: a FIFO hung `inspect`, and
    `reconstruct` took it for a stream of 0 steps)."""
    try:
        st = path.stat()
    except FileNotFoundError:
        raise FileNotFoundError(errno.ENOENT, "spike stream does not exist", str(path)) from None
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(errno.EISDIR, "is a directory, expected a .dat spike stream", str(path))
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{path}: {file_problem(path)}; expected a .dat spike stream")
    return st.st_size


def _drop_trailing_columns(packed: np.ndarray, height: int, stored_width: int, width: int) -> np.ndarray:
    """Keep the first `width` of `stored_width` columns of every row (a byte slice when both are
    whole bytes, as 400 and 416 are)."""
    n = packed.shape[0]
    if n == 0:  # no frames: reshape(0, -1) of nothing raised NumPy's error (round seventeen)
        return np.zeros((0, frame_bytes(height, width)), np.uint8)
    if stored_width % 8 == 0 and width % 8 == 0:
        rows = packed.reshape(n, height, stored_width // 8)[:, :, : width // 8]
        return np.ascontiguousarray(rows).reshape(n, -1)
    return pack_frames(unpack_frames(packed, height, stored_width)[:, :, :width])


def read_dat(path: str | Path, height: int | None = None, width: int | None = None, start: int = 0,
             stop: int | None = None, flip: bool | None = None, header_columns: int = 0,
             drop_partial: bool = False) -> SpikeStream:
    """Read frames [start, stop) of a `.dat` file (memory-mapped: only that range is read).

    height, width, flip None: as recorded beside the stream (its sidecar or a dataset's meta.json),
    else the PKU camera's 250 x 400 with rows bottom-up, as `DatReader` takes them; what is given
    wins over the record (round seventeen: the default flip True read a `--no-flip` stream upside
    down; the defaults 250 x 400 refused or misread a recorded 64 x 100 stream that DatReader read)."""
    return DatReader(path, height, width, flip=flip, header_columns=header_columns,
                     drop_partial=drop_partial).read(start, stop)


# ---- sidecar ------------------------------------------------------------------------------------
def sidecar_path(dat_path: str | Path) -> Path:
    """`<name>.dat.json` beside a stream. A path that names no file ("." or "/", ".."), given where
    a stream goes, is refused by name: pathlib's "has an empty name" said nothing of the stream."""
    p = Path(dat_path)
    if p.name in ("", ".", ".."):
        raise ValueError(f"{dat_path}: names a folder, not a spike stream (a .dat file)")
    return p.with_suffix(p.suffix + ".json")


def is_stream_sidecar(path: str | Path, beside_stream: bool = False) -> bool:
    """Whether `path` is a stream's sidecar: a small regular JSON file (not a link) holding an object
    with an integer height and width, the geometry a reader takes from it, and, unless it stands
    `beside_stream` (a stream file of its name exists), an integer num_steps too, as every record
    spikesim writes has. A writer removes only such a file: beside the stream it replaces, a height
    and width are that stream's record (round seven: kept, they made the reader take the new stream
    with the old geometry); with no stream there, a path without a suffix (`cam`) has `cam.json` as
    its record's name, which may be the user's own file (a region of interest with a height and
    width was removed: round twenty-one)."""
    p = Path(path)
    try:
        if p.is_symlink() or not p.is_file() or p.stat().st_size > 1 << 20:
            return False
        info = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    need = ("height", "width") if beside_stream else ("height", "width", "num_steps")
    return isinstance(info, dict) and all(_is_int(info.get(k)) for k in need)


def check_sidecar_slot(dat_path: str | Path) -> Path:
    """The sidecar path of a stream about to be written with its record, if the record may go there:
    nothing, or an earlier stream's own record (is_stream_sidecar). A link, FIFO, device, socket or
    folder there, or a file of the user's, is refused naming it, before anything is simulated
    (round twenty-one: Simulator.run_to_dat replaced each of them; the CLI refused them)."""
    side = sidecar_path(dat_path)
    outputs.check_replaceable(side)
    if side.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a directory, where the stream's record goes", str(side))
    if side.exists() and not is_stream_sidecar(side, beside_stream=Path(dat_path).is_file()):
        raise ValueError(f"{side}: exists and is not a stream's record (a JSON object with an integer height, width "
                         f"and num_steps); the record of {Path(dat_path).name} is written there: move that file, or "
                         "write the stream elsewhere")
    return side


def write_sidecar(dat_path: str | Path, info: dict[str, Any]) -> Path:
    """A small JSON beside a simulated stream: camera parameters, seed, geometry, flip. Standard
    JSON: a NaN or infinite number (an extra field's, a scene's infinite illuminance) is written as
    null and named under "non_finite" (config_io.standard_json); the token NaN, which strict
    readers refuse, was written (round seven)."""
    from .config_io import standard_json
    path = sidecar_path(dat_path)
    return outputs.atomic_write_text(path, standard_json(info, sort_keys=True, indent=2) + "\n")


def read_sidecar(dat_path: str | Path) -> dict[str, Any] | None:
    """The sidecar beside a stream, its fields checked (`check_stream_record`); None when there is none."""
    path = sidecar_path(dat_path)
    if not path.exists() and not path.is_symlink():
        return None
    return check_stream_record(read_json_object(path, "sidecar", finite=False), path)


#: The largest height or width a recorded geometry may give (the PKU camera is 250 x 400; a
#: record of 10^6 rows is damaged, not a sensor).
MAX_SIDE = 1 << 16


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def check_stream_record(info: dict[str, Any], source: str | Path) -> dict[str, Any]:
    """`info` (a sidecar or a dataset meta.json) unchanged when every field a reader uses has the
    right type and range, else a ValueError naming `source` and the field: height and width
    integers in 1..MAX_SIDE (a JSON `true` is not an integer), header_columns and num_steps
    integers >= 0, flip a JSON true/false (the string "no" is not false), gt_steps a list of steps
    within num_steps, a readout period
    (top level or the camera's) a positive finite number of seconds, at most 1, and the camera a
    JSON object."""
    def bad(field: str, value: Any, expected: str) -> ValueError:
        shown = repr(value) if len(repr(value)) <= 40 else f"{type(value).__name__} {repr(value)[:20]}..."
        return ValueError(f"{source}: {field} must be {expected}, got {shown}")

    for key in ("height", "width"):
        if key in info and not (_is_int(info[key]) and 1 <= info[key] <= MAX_SIDE):
            raise bad(key, info[key], f"an integer in 1..{MAX_SIDE}")
    for key, top in (("header_columns", MAX_SIDE), ("num_steps", None)):
        if key in info and not (_is_int(info[key]) and 0 <= info[key] and (top is None or info[key] <= top)):
            raise bad(key, info[key], "an integer >= 0" + (f", at most {top}" if top else ""))
    if info.get("flip") is not None and not isinstance(info["flip"], bool):
        raise bad("flip", info["flip"], "true or false")
    if "gt_steps" in info:  # a dataset scene's: null was a TypeError deep in a reader, "20" a misleading centre error
        steps = info["gt_steps"]
        n = info.get("num_steps")
        if not (isinstance(steps, list) and all(_is_int(g) and g >= 0 for g in steps)
                and (not _is_int(n) or all(g < n for g in steps)) and len(set(steps)) == len(steps)):
            raise bad("gt_steps", steps, "a list of distinct step numbers (integers from 0"
                      + (f" to {n - 1}" if _is_int(n) else "") + ")")
    camera = info.get("camera")
    if camera is not None and not isinstance(camera, dict):
        raise bad("camera", camera, "an object")
    for field, holder in (("readout_period_s", info), ("camera.readout_period_s", camera or {})):
        v = holder.get(field.rsplit(".", 1)[-1])
        if v is None:
            continue
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 < v <= 1):
            raise bad(field, v, "a positive finite number of seconds, at most 1")
    return info


# ---- which geometry a file was recorded with ---------------------------------------------------
HEADER_COLUMNS = 16  # the extra columns of 416-wide recordings
DATASET_STREAM, DATASET_META = "spikes.dat", "meta.json"  # a dataset scene folder (spikesim.dataset)
#: A dataset scene's meta.json lists every ground-truth step (a few KiB for most scenes): it may be
#: larger than a sidecar, never this large.
META_LIMIT = 16 << 20


def recorded_geometry(dat_path: str | Path) -> dict[str, Any] | None:
    """The geometry written down for a stream: its sidecar `<name>.dat.json`, or for a dataset
    scene the `meta.json` beside its `spikes.dat`. None when there is neither.

    Returns height, width, flip (None if not recorded), header_columns (0 unless recorded: the
    project writes no header columns) and source (the JSON file), so callers trust what was
    recorded instead of guessing from the file size.
    """
    p = Path(dat_path)
    source = sidecar_path(p)
    if not source.exists() and not source.is_symlink():
        source = p.parent / DATASET_META
        if p.name != DATASET_STREAM or not (source.exists() or source.is_symlink()):
            return None
    limit = META_LIMIT if source.name == DATASET_META else SMALL_FILE_LIMIT
    info = check_stream_record(read_json_object(source, "stream description", finite=False, limit=limit), source)
    missing = [k for k in ("height", "width") if k not in info]
    if missing:
        raise ValueError(f"{source} does not record the stream's {' and '.join(missing)}")
    return {"height": info["height"], "width": info["width"], "header_columns": info.get("header_columns", 0),
            "flip": info.get("flip"), "num_steps": info.get("num_steps"), "source": source}


def stream_geometry(dat_path: str | Path, height: int | None = None, width: int | None = None,
                    flip: bool | None = None) -> tuple[int, int, bool]:
    """(height, width, flip) to read a stream with: what is given, else what is recorded beside it
    (`recorded_geometry`), else the PKU camera's 250 x 400 with rows bottom-up."""
    rec = recorded_geometry(dat_path) or {}
    height = height or rec.get("height") or 250
    width = width or rec.get("width") or 400
    if flip is None:
        flip = True if rec.get("flip") is None else rec["flip"]
    return height, width, flip


def detect_header_columns(path: str | Path, height: int, width: int, drop_partial: bool = False) -> int:
    """Header columns per row of a stream of `width`-column images: 0 or 16 (416-wide recordings).

    In order: what the sidecar or dataset meta.json records; the file size when only one reading
    gives whole frames; else (a 416-wide file whose frame count is a multiple of 25 is also whole
    400-wide frames) the content, or an error naming both readings when the content cannot tell.
    With `drop_partial` a partial last frame is allowed, so only the content can decide.
    """
    path = Path(path)
    rec = recorded_geometry(path)
    if rec is not None:
        if (rec["height"], rec["width"]) != (height, width):
            raise ValueError(f"{rec['source']} records {rec['width']}x{rec['height']} frames (width x height), "
                             f"not the {width}x{height} asked for; pass its --width/--height, or "
                             "--header-columns to read the file otherwise")
        return rec["header_columns"]
    size = _stream_size(path)
    plain, wide = frame_bytes(height, width), frame_bytes(height, width + HEADER_COLUMNS)
    fits_plain, fits_wide = size % plain == 0, size % wide == 0
    if drop_partial:
        fits_plain = fits_wide = True  # a partial last frame is ignored whichever the reading
    if not (fits_plain or fits_wide):
        raise ValueError(f"{path}: {size} bytes is not a whole number of {width}x{height} frames ({plain} bytes "
                         f"each), nor of {width + HEADER_COLUMNS}x{height} frames ({wide} bytes each): --height/--width "
                         "are wrong, or the file is cut off mid-frame (then drop_partial=True, in the commands "
                         "inspect, reconstruct and panel --drop-partial, ignores the partial last frame)")
    if size == 0 or not fits_wide:
        return 0
    if not fits_plain:
        return HEADER_COLUMNS
    decided = header_columns_from_content(path, height, width)
    if decided is None:
        verb = "holds" if drop_partial else "is"
        raise ValueError(f"{path}: {size} bytes {verb} either {size // plain} frames of {width}x{height} (no "
                         f"header columns) or {size // wide} frames of {width + HEADER_COLUMNS}x{height} "
                         f"({HEADER_COLUMNS} header columns per row), and its content does not tell which; "
                         f"pass --header-columns 0 or {HEADER_COLUMNS}")
    return decided


def check_recorded_layout(path: str | Path, height: int, width: int, header_columns: int) -> None:
    """Refuse a row layout (height, width, header columns) that contradicts the geometry recorded
    beside the stream (`recorded_geometry`), naming the record: a `--header-columns` given against
    a sidecar that says otherwise reads every row shifted, i.e. garbage. Callers skip the check
    when the user gave the whole geometry (height, width and header columns) to read the file
    otherwise on purpose."""
    rec = recorded_geometry(path)
    if rec is None:
        return
    if (rec["height"], rec["width"], rec["header_columns"]) != (height, width, header_columns):
        raise ValueError(
            f"{rec['source']} records {rec['width']}x{rec['height']} frames (width x height) with "
            f"{rec['header_columns']} header column(s) per row, not {width}x{height} with {header_columns}: "
            f"read that way every row of {path} would be misaligned; leave --header-columns to the record, or "
            "give --height, --width and --header-columns together to read the file otherwise")


def header_columns_from_content(path: str | Path, height: int, width: int, max_bytes: int = 32 << 20,
                                margin: float = 3.0) -> int | None:
    """0 or 16 when one reading of the file is clearly right, else None.

    Read with the right width, every position of a frame is the same physical pixel in every
    frame, so per-position spike counts keep the scene's (and the sensor's) spatial contrast.
    Read with the wrong width, frame starts drift by 16 columns per row against the true rows, and
    each position visits 25 or 26 physical pixels in turn, which averages the contrast away. The
    reading whose counts are `margin` times more over-dispersed (variance / mean), and at least
    `margin` in absolute terms, wins; a scene without structure (uniform light, pure noise) gives
    None. Only the first `max_bytes` (rounded to whole frames of both readings) are read.
    """
    path = Path(path)
    plain, wide = frame_bytes(height, width), frame_bytes(height, width + HEADER_COLUMNS)
    block = plain * wide // math.gcd(plain, wide)
    size = _stream_size(path)
    if size < block:
        return None
    nbytes = block * max(1, min(size // block, max_bytes // block))
    data = np.memmap(path, dtype=np.uint8, mode="r", shape=(nbytes,))
    flat = _dispersion(data.reshape(-1, plain), height * width)
    headed = _dispersion(data.reshape(-1, wide), height * (width + HEADER_COLUMNS))
    if headed >= margin * max(flat, 1.0):
        return HEADER_COLUMNS
    if flat >= margin * max(headed, 1.0):
        return 0
    return None


def _dispersion(frames: np.ndarray, pixels: int, chunk_bits: int = 1 << 22) -> float:
    """Variance / mean over positions of the spike counts of packed frames (0 with no spikes)."""
    counts = np.zeros(pixels, dtype=np.int64)
    step = max(1, chunk_bits // max(1, frames.shape[1] * 8))
    for a in range(0, frames.shape[0], step):
        counts += np.unpackbits(frames[a:a + step], axis=1, bitorder="little", count=pixels).sum(axis=0, dtype=np.int64)
    mean = counts.mean()
    return float(counts.var() / mean) if mean > 0 else 0.0


def open_stream(path: str | Path, height: int | None = None, width: int | None = None, flip: bool | None = None,
                header_columns: int | str | None = "auto", drop_partial: bool = False) -> tuple[DatReader, int]:
    """(reader, header columns) of a `.dat`, its size and row order from the arguments, else from
    the record beside it (spikesim.stream.stream_geometry); header_columns "auto" or None: detected.

    A record whose size does not fit the file is named in the error: a stale sidecar or meta.json,
    not a truncated stream, is then the likely cause, and --height/--width override it."""
    path = Path(path)
    if not (header_columns is None or (isinstance(header_columns, str) and header_columns == "auto")
            or (isinstance(header_columns, (int, np.integer)) and not isinstance(header_columns, (bool, np.bool_))
                and header_columns >= 0)):  # 2.7 was taken as 2, True as 1, "2" as 2 (round seventeen)
        raise ValueError(f"open_stream: header_columns must be \"auto\", None or an integer >= 0, got {header_columns!r}")
    h, w, flip = stream_geometry(path, height, width, flip)
    if header_columns in ("auto", None):
        header = detect_header_columns(path, h, w, drop_partial)
    else:
        header = int(header_columns)
        if not (height and width):  # part of the layout from the record: the rest must agree with it
            check_recorded_layout(path, h, w, header)
    try:
        reader = DatReader(path, h, w, flip=flip, header_columns=header, drop_partial=drop_partial)
    except ValueError as exc:
        rec = recorded_geometry(path)
        if rec is None or (height and width):
            raise
        raise ValueError(f"{exc} (height {h}, width {w} as recorded in {rec['source']}; "
                         "--height/--width override it)") from None
    rec = recorded_geometry(path) if not (height and width) else None
    recorded = None if rec is None else rec.get("num_steps")
    if isinstance(recorded, int) and not isinstance(recorded, bool) and recorded != reader.num_steps and not drop_partial:
        raise ValueError(f"{rec['source']} records {recorded} steps, {path} holds {reader.num_steps}: the record is "
                         "another stream's or the stream was cut; --height/--width read it without the record")
    return reader, header


__all__ = ["open_stream", "SpikeStream", "DatWriter", "DatReader", "write_dat", "read_dat", "pack_frames", "unpack_frames",
           "frame_bytes", "write_sidecar", "read_sidecar", "sidecar_path", "recorded_geometry",
           "stream_geometry", "detect_header_columns", "header_columns_from_content", "open_temp_beside",
           "HEADER_COLUMNS", "check_stream_record", "MAX_SIDE", "check_recorded_layout"]
