"""Spike streams in memory (bit-packed) and on disk in the PKU `.dat` format.

The `.dat` layout (DESIGN.md section 3): frames one after another; each frame row-scanned,
8 pixels per byte, least significant bit first; rows stored bottom-up (vertically flipped) by
real cameras and the readers of their recordings (Spk2ImgNet, WGSE, SSML, SpikeCV). The group's
simulators (SPCS, SCSim) and the LR-Rep authors' loader use top-down rows: pass `flip=False` for
those. Some real recordings are 416 columns wide, of which 16 are a header to drop.

In memory a stream is `packed`, uint8 (N, ceil(H*W/8)): each frame flattened row-major and
packed LSB first, top-down. With W a multiple of 8 (400 and 416 are) a flip is a byte reshuffle.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np


def frame_bytes(height: int, width: int) -> int:
    return (height * width + 7) // 8


@dataclass
class SpikeStream:
    """A binary spike stream of N readouts of H x W pixels, bit-packed."""

    packed: np.ndarray
    height: int
    width: int

    def __post_init__(self) -> None:
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
        stop = self.num_steps if stop is None else stop
        total = np.zeros(self.height * self.width, dtype=np.int64)
        for a in range(start, stop, chunk):
            bits = np.unpackbits(self.packed[a:min(stop, a + chunk)], axis=1, bitorder="little",
                                 count=self.height * self.width)
            total += bits.sum(axis=0, dtype=np.int64)
        return total.reshape(self.height, self.width)

    @classmethod
    def from_bool(cls, frames: np.ndarray) -> "SpikeStream":
        frames = np.asarray(frames)
        if frames.ndim != 3:
            raise ValueError(f"expected (N, H, W) spike frames, got shape {frames.shape}")
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


def pack_frames(frames: np.ndarray) -> np.ndarray:
    n = frames.shape[0]
    flat = np.ascontiguousarray(frames.reshape(n, -1)).astype(bool, copy=False)
    return np.packbits(flat, axis=1, bitorder="little")


def unpack_frames(packed: np.ndarray, height: int, width: int) -> np.ndarray:
    bits = np.unpackbits(packed, axis=1, bitorder="little", count=height * width)
    return bits.reshape(-1, height, width).view(bool)


def _flip_packed(packed: np.ndarray, height: int, width: int) -> np.ndarray:
    """Reverse the row order of packed frames (its own inverse)."""
    if width % 8 == 0:
        return np.ascontiguousarray(packed.reshape(-1, height, width // 8)[:, ::-1, :]).reshape(packed.shape[0], -1)
    return pack_frames(unpack_frames(packed, height, width)[:, ::-1, :])


# ---- writing ------------------------------------------------------------------------------------
class DatWriter:
    """Append packed frames to a `.dat` file; it appears under its name only on `close()`.

    Writes go to a temporary file in the same folder, renamed on success, so an interrupted run
    never leaves a truncated stream that looks complete.
    """

    def __init__(self, path: str | Path, height: int, width: int, flip: bool = True):
        self.path = Path(path)
        self.height, self.width, self.flip = height, width, flip
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".part", dir=self.path.parent)
        self._tmp = Path(tmp)
        self._file = os.fdopen(fd, "wb")
        self.num_steps = 0

    def write(self, stream: SpikeStream) -> None:
        if (stream.height, stream.width) != (self.height, self.width):
            raise ValueError(f"stream is {stream.height}x{stream.width}, writer is {self.height}x{self.width}")
        data = _flip_packed(stream.packed, self.height, self.width) if self.flip else stream.packed
        self._file.write(np.ascontiguousarray(data).tobytes())
        self.num_steps += stream.num_steps

    def close(self) -> Path:
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self._tmp, self.path)
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
    with DatWriter(path, stream.height, stream.width, flip=flip) as w:
        w.write(stream)
    return Path(path)


# ---- reading ------------------------------------------------------------------------------------
class DatReader:
    """Memory-mapped `.dat` reader: any time range without loading the file.

    `header_columns` are extra columns stored at the start of each row by some real cameras (416-wide
    recordings carry 16), dropped on read; `width` is the image width without them.
    """

    def __init__(self, path: str | Path, height: int = 250, width: int = 400, flip: bool = True,
                 header_columns: int = 0, drop_partial: bool = False):
        self.path = Path(path)
        if height <= 0 or width <= 0 or header_columns < 0:
            raise ValueError(f"bad frame geometry height={height} width={width} header_columns={header_columns}")
        self.height, self.width, self.flip = height, width, flip
        self.header_columns = header_columns
        self.stored_width = width + header_columns
        self.frame_bytes = frame_bytes(height, self.stored_width)
        try:
            size = self.path.stat().st_size
        except FileNotFoundError:
            raise FileNotFoundError(f"spike stream {self.path} does not exist") from None
        full, rest = divmod(size, self.frame_bytes)
        if rest and not drop_partial:
            raise ValueError(
                f"{self.path}: {size} bytes is not a whole number of {height}x{self.stored_width} frames "
                f"({self.frame_bytes} bytes each; {full} frames and {rest} bytes left over). The file is "
                "truncated or the geometry is wrong; pass drop_partial=True (--drop-partial) to ignore the "
                "partial last frame.")
        self.num_steps = full
        self._mm = np.memmap(self.path, dtype=np.uint8, mode="r", shape=(full, self.frame_bytes)) if full else np.zeros((0, self.frame_bytes), np.uint8)

    def __len__(self) -> int:
        return self.num_steps

    def read(self, start: int = 0, stop: int | None = None) -> SpikeStream:
        stop = self.num_steps if stop is None else stop
        if not (0 <= start <= stop <= self.num_steps):
            raise IndexError(f"{self.path}: range [{start}, {stop}) is outside the stream's {self.num_steps} frames")
        raw = np.asarray(self._mm[start:stop])
        h, sw = self.height, self.stored_width
        if self.flip:
            raw = _flip_packed(raw, h, sw)
        if self.header_columns:
            frames = unpack_frames(raw, h, sw)[:, :, self.header_columns:]
            return SpikeStream.from_bool(frames)
        return SpikeStream(raw, h, self.width)

    def iter_chunks(self, chunk: int = 1024) -> Iterator[SpikeStream]:
        for a in range(0, self.num_steps, chunk):
            yield self.read(a, min(self.num_steps, a + chunk))


def read_dat(path: str | Path, height: int = 250, width: int = 400, start: int = 0, stop: int | None = None,
             flip: bool = True, header_columns: int = 0, drop_partial: bool = False) -> SpikeStream:
    """Read frames [start, stop) of a `.dat` file (memory-mapped: only that range is read)."""
    return DatReader(path, height, width, flip=flip, header_columns=header_columns,
                     drop_partial=drop_partial).read(start, stop)


# ---- sidecar ------------------------------------------------------------------------------------
def sidecar_path(dat_path: str | Path) -> Path:
    p = Path(dat_path)
    return p.with_suffix(p.suffix + ".json")


def write_sidecar(dat_path: str | Path, info: dict[str, Any]) -> Path:
    """A small JSON beside a simulated stream: camera parameters, seed, geometry, flip."""
    path = sidecar_path(dat_path)
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_text(json.dumps(info, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)
    return path


def read_sidecar(dat_path: str | Path) -> dict[str, Any] | None:
    path = sidecar_path(dat_path)
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"sidecar {path} is not valid JSON: {exc}") from exc


__all__ = ["SpikeStream", "DatWriter", "DatReader", "write_dat", "read_dat", "pack_frames", "unpack_frames",
           "frame_bytes", "write_sidecar", "read_sidecar", "sidecar_path"]
