"""Ground-truth images: linear float EXR for data, tone-mapped PNG for people.

EXR keeps y (expected spikes per step) as float32, unclipped, so metrics are computed on exactly
what the renderer produced; PNGs are previews only and are never read back for metrics.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np

from .outputs import atomic_write_with

CHANNEL = "Y"


def write_exr(path: str | Path, y: np.ndarray) -> Path:
    """Write a (H, W) image as single-channel float32 EXR ("Y", ZIP compression), atomically."""
    import OpenEXR

    path = Path(path)
    y = np.ascontiguousarray(np.asarray(y, dtype=np.float32))
    if y.ndim != 2:
        raise ValueError(f"{path}: expected a (H, W) image, got shape {y.shape}")
    path.parent.mkdir(parents=True, exist_ok=True)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    def write(tmp: Path) -> None:
        try:
            OpenEXR.File(header, {CHANNEL: y}).write(str(tmp))
        except RuntimeError as exc:  # OpenEXR reports I/O failures (a full disk) as RuntimeError
            text = str(exc)
            code = errno.ENOSPC if "No space left" in text else errno.EIO
            raise OSError(code, os.strerror(code) if code == errno.ENOSPC else text.splitlines()[0], str(path)) from None

    return atomic_write_with(path, write)


def read_exr(path: str | Path) -> np.ndarray:
    """Read a single-channel EXR written by `write_exr` (or the luminance of an RGB one)."""
    import OpenEXR

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"ground-truth image {path} does not exist")
    try:
        with OpenEXR.File(str(path)) as f:
            channels = f.channels()
            if CHANNEL in channels:
                return np.asarray(channels[CHANNEL].pixels, dtype=np.float32)
            colour = next((c for c in ("RGB", "RGBA") if c in channels), None)
            if colour is not None:  # alpha, if any, is coverage, not light: dropped
                rgb = np.asarray(channels[colour].pixels, dtype=np.float32)[..., :3]
                # Rec. 709 luminance weights.
                return rgb @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
            raise ValueError(f"{path}: no 'Y' or 'RGB' channel (has {sorted(channels)})")
    except (OSError, RuntimeError) as exc:
        raise ValueError(f"{path} is not a readable EXR image: {exc}") from exc


def read_image_y(path: str | Path, scale: float = 1.0) -> np.ndarray:
    """A ground-truth image of someone else's data as y (spikes per step): an EXR or .npy is taken
    as y times `scale`; an 8- or 16-bit image (PNG, JPEG, TIFF) as `scale` x value / full scale,
    e.g. scale 0.6 for Spk2ImgNet, whose simulator fires at 0.6 of the image intensity. Colour
    images become their luminance (Rec. 709 weights, on the stored values)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ground-truth image {path} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".exr":
        y = read_exr(path)
    elif suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False, mmap_mode="r")
        except (ValueError, EOFError, OSError) as exc:
            raise ValueError(f"{path} is not a readable .npy array: {exc}") from None
        if arr.dtype.kind not in "fiu":  # bool, complex, strings, records: not an image of y
            raise ValueError(f"{path}: {arr.dtype} values; expected real numbers (float or integer), the image's y")
        y = np.asarray(arr, dtype=np.float32)
    else:
        y = _read_picture(path)
    if y.ndim != 2:
        raise ValueError(f"{path}: expected a single (H, W) image, got shape {y.shape}")
    bad = int(y.size - np.count_nonzero(np.isfinite(y)))
    if bad:
        raise ValueError(f"{path} has {bad} NaN or infinite pixel(s) of {y.size}; the image's y must be finite")
    negative = int(np.count_nonzero(y < 0))
    if negative:
        raise ValueError(f"{path} has {negative} negative pixel(s) (min {float(y.min()):.3g}) of {y.size}; the image's "
                         "y (light, in spikes per step) must be >= 0")
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = (y * np.float32(scale)).astype(np.float32) if np.isfinite(np.float32(scale)) else None
    if scaled is None or not np.isfinite(scaled).all():  # the image was finite: the scale overflowed (round eleven)
        raise ValueError(f"scale {scale:g} (--gt-scale): {path}'s y times it overflows float32 (max 3.4e38); "
                         "give a smaller scale")
    return scaled


#: PIL image modes read as grey or colour (an alpha channel, coverage and not light, is dropped).
_PICTURE_MODES = ("L", "LA", "RGB", "RGBA", "I;16", "I;16B", "I;16L", "1", "P", "PA")


def _read_picture(path: Path) -> np.ndarray:
    """An 8- or 16-bit picture (PNG, JPEG, TIFF) as value / full scale, colour as its luminance."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            if im.mode not in _PICTURE_MODES:
                raise ValueError(f"{path}: {im.mode} pixels; expected a grey or RGB image (8 or 16 bits, alpha allowed)")
            if im.mode in ("P", "PA"):  # palette indices are not light: the colours they stand for
                im = im.convert("RGBA")
            elif im.mode == "1":
                im = im.convert("L")
            arr = np.asarray(im)
    except (UnidentifiedImageError, OSError) as exc:
        raise ValueError(f"{path} is not a readable image: {exc}") from None
    full = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(arr.dtype.newbyteorder("="))
    if full is None:
        raise ValueError(f"{path}: {arr.dtype} pixels; expected an 8- or 16-bit image")
    arr = arr.astype(np.float32) / full
    if arr.ndim == 3:
        channels = arr.shape[2]
        if channels in (1, 2):  # grey, grey + alpha
            arr = arr[..., 0]
        elif channels in (3, 4):  # RGB, RGB + alpha
            arr = arr[..., :3] @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
        else:
            raise ValueError(f"{path}: {channels} channels per pixel; expected grey or RGB (alpha allowed)")
    return arr


def to_display(y: np.ndarray, gamma: float = 2.2, scale: float | None = None, percentile: float | None = None) -> np.ndarray:
    """Linear y -> 8-bit display values: y * scale, clipped to [0, 1], encoded with 1/gamma.

    `scale` defaults to 1 (y = 1 is white: one spike per step); `percentile` instead maps that
    percentile of the image to white, the display enhancement used for very dark results.
    """
    if not (np.isfinite(gamma) and gamma > 0):
        raise ValueError(f"gamma must be a finite number > 0, got {gamma}")
    if scale is not None and not (np.isfinite(scale) and scale >= 0):
        raise ValueError(f"scale must be a finite number >= 0, got {scale}")
    if percentile is not None and not 0 <= percentile <= 100:
        raise ValueError(f"percentile must be in [0, 100], got {percentile}")
    y = np.asarray(y, dtype=np.float64)
    if percentile is not None:
        ref = np.percentile(y, percentile)
        scale = 1.0 / ref if ref > 0 else 1.0
    v = np.clip(y * (1.0 if scale is None else scale), 0.0, 1.0) ** (1.0 / gamma)
    return np.round(v * 255.0).astype(np.uint8)


#: A preview whose 99.5th percentile of y (times its scale) is below this is stretched by default:
#: gamma encoded it would reach at most about half of white (0.25^(1/2.2) = 0.53), and a low-light
#: frame (y ~ 0.01) came out near black (maximum 30/255).
DARK_PREVIEW_Y = 0.25
PREVIEW_PERCENTILE = 99.5


def auto_percentile(y: np.ndarray, scale: float | None = None, percentile: float | None = None) -> float | None:
    """The percentile a preview maps to white: the one asked for; else PREVIEW_PERCENTILE when no
    scale was asked either and the image is dark (DARK_PREVIEW_Y); else None (y = 1 is white)."""
    if percentile is not None or scale is not None:
        return percentile
    dark = float(np.percentile(np.asarray(y, dtype=np.float64), PREVIEW_PERCENTILE)) < DARK_PREVIEW_Y
    return PREVIEW_PERCENTILE if dark else None


def write_png(path: str | Path, y: np.ndarray, gamma: float = 2.2, scale: float | None = None,
              percentile: float | None = None) -> Path:
    """A tone-mapped preview PNG of a linear image (see `to_display`)."""
    from PIL import Image

    path = Path(path)
    if path.suffix.lower() != ".png":  # PNG bytes under "x.jpg" were written, which viewers then refuse (round seven)
        raise ValueError(f"{path}: write_png writes PNG data; name the file *.png")
    path.parent.mkdir(parents=True, exist_ok=True)
    img = to_display(y, gamma=gamma, scale=scale, percentile=percentile)
    # written whole (temporary file, then rename), never through a link; a failure names `path`
    return atomic_write_with(path, lambda tmp: Image.fromarray(img).save(tmp, format="PNG"))


__all__ = ["write_exr", "read_exr", "write_png", "to_display", "auto_percentile", "DARK_PREVIEW_Y", "PREVIEW_PERCENTILE"]
