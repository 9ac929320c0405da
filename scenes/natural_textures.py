"""Textures with natural image statistics for RLLR's `natural` content, made from a seed, nothing
downloaded.

- `dead_leaves`: the dead-leaves model (Lee, Mumford and Huang 2001, "Occlusion models for natural
  images"): opaque shapes dropped one over another, radii drawn from a power law p(r) ~ r^-3
  between r_min and r_max. That law makes the image statistically scale invariant, so its power
  spectrum falls as a power of frequency, as photographs' do; it is used to train restoration
  networks in place of photographs. Each leaf has its own colour (grey or colour) and, unlike the
  plain model, a texture inside it (a gradient, stripes or noise), so edges are not the only
  structure.
- `package_photo`: a random crop of a photograph or texture that ships inside an installed package
  (scikit-image's wheel), with its licence (PHOTOS).

Images are linear reflectances in [0, 1], (H, W, 3) float64; `save_srgb` writes them as the 8-bit
sRGB PNG that Mitsuba's bitmap texture decodes back to linear.
"""
from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Exponent of the leaves' radius density p(r) ~ r^-alpha (Lee, Mumford and Huang 2001: alpha = 3
#: is the scale-invariant case).
LEAF_RADIUS_EXPONENT = 3.0
#: Reflectance range of a leaf's mean colour: from dark cloth (2 %) to white paper (90 %).
LEAF_REFLECTANCE = (0.02, 0.9)
_MAX_LEAVES = 60000


@dataclass(frozen=True)
class Photo:
    """A picture inside scikit-image's wheel (skimage/data), with the licence its docs state."""

    filename: str
    licence: str
    source: str


#: The package pictures a natural scene may use: the photographs and surface textures of
#: scikit-image's `data` folder whose licence is public domain or CC0 (skimage.data docstrings).
PHOTOS: dict[str, Photo] = {
    "astronaut": Photo("astronaut.png", "public domain (NASA)", "skimage.data.astronaut"),
    "camera": Photo("camera.png", "CC0 (Lav Varshney)", "skimage.data.camera"),
    "chelsea": Photo("chelsea.png", "CC0 (Stefan van der Walt)", "skimage.data.chelsea"),
    "coffee": Photo("coffee.png", "CC0 (Rachel Michetti)", "skimage.data.coffee"),
    "coins": Photo("coins.png", "no known copyright restrictions (Brooklyn Museum)", "skimage.data.coins"),
    "rocket": Photo("rocket.jpg", "public domain (SpaceX)", "skimage.data.rocket"),
    "brick": Photo("brick.png", "CC0 (CC0Textures)", "skimage.data.brick"),
    "grass": Photo("grass.png", "CC0 (DeviantArt, linolafett)", "skimage.data.grass"),
    "gravel": Photo("gravel.png", "CC0 (CC0Textures)", "skimage.data.gravel"),
    "text": Photo("text.png", "public domain (Wikipedia)", "skimage.data.text"),
    "clock": Photo("clock_motion.png", "public domain (Stefan van der Walt)", "skimage.data.clock"),
    "hubble": Photo("hubble_deep_field.jpg", "public domain (NASA)", "skimage.data.hubble_deep_field"),
}


def photo_folder() -> Path:
    """Where the installed scikit-image keeps its bundled pictures."""
    import skimage

    return Path(skimage.__file__).parent / "data"


def photo_version() -> str:
    """The installed scikit-image's version: part of a natural scene's identity (its pictures)."""
    import skimage

    return str(skimage.__version__)


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 decoding of sRGB values in [0, 1]."""
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    v = np.clip(v, 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)


def save_srgb(img: np.ndarray, path: Path) -> Path:
    """Write a linear reflectance image as an 8-bit sRGB PNG."""
    from PIL import Image

    rgb = img if img.ndim == 3 else np.repeat(img[..., None], 3, axis=2)
    Image.fromarray(np.round(linear_to_srgb(rgb) * 255).astype(np.uint8)).save(path)
    return path


def power_law_radii(rng: np.random.Generator, n: int, r_min: float, r_max: float,
                    alpha: float = LEAF_RADIUS_EXPONENT) -> np.ndarray:
    """n radii with density ~ r^-alpha on [r_min, r_max], by inverting the CDF (alpha != 1)."""
    if not 0 < r_min < r_max:
        raise ValueError(f"radii: expected 0 < r_min < r_max, got {r_min}, {r_max}")
    a = 1.0 - alpha
    u = rng.random(n)
    return (r_min ** a + u * (r_max ** a - r_min ** a)) ** (1.0 / a)


def _leaf_colour(rng: np.random.Generator, colour: bool) -> np.ndarray:
    lo, hi = LEAF_REFLECTANCE
    value = math.exp(rng.uniform(math.log(lo), math.log(hi)))  # reflectances spread per decade
    if not colour:
        return np.full(3, value)
    r, g, b = colorsys.hsv_to_rgb(rng.random(), rng.uniform(0.0, 0.85), 1.0)
    rgb = np.array([r, g, b])
    return rgb * value / max(float(rgb @ np.array([0.2126, 0.7152, 0.0722])), 1e-3)  # luminance = value


def dead_leaves(rng: np.random.Generator, size: int = 512, colour: bool = True, r_min: float = 1.5,
                r_max: float | None = None, textured: bool = True) -> np.ndarray:
    """A dead-leaves image (module docstring), (size, size, 3) linear reflectance in [0, 1].

    Leaves are drawn front to back: each one fills only the pixels no earlier leaf covers, which
    is the same image as dropping them back to front, and stops once every pixel is covered."""
    if size < 8:
        raise ValueError(f"size={size}: a dead-leaves texture needs at least 8 pixels a side")
    r_max = size / 2.5 if r_max is None else r_max
    img = np.zeros((size, size, 3))
    free = np.ones((size, size), dtype=bool)
    noise = rng.standard_normal((size // 4 + 2, size // 4 + 2))  # coarse noise for textured leaves
    batch = 2048
    drawn = 0
    while free.any() and drawn < _MAX_LEAVES:
        radii = power_law_radii(rng, batch, r_min, r_max)
        centres = rng.uniform(-r_max * 0.5, size + r_max * 0.5, (batch, 2))
        for r, (cy, cx) in zip(radii, centres):
            drawn += 1
            y0, y1 = max(int(cy - r * 1.5), 0), min(int(cy + r * 1.5) + 1, size)
            x0, x1 = max(int(cx - r * 1.5), 0), min(int(cx + r * 1.5) + 1, size)
            if y0 >= y1 or x0 >= x1:
                continue
            sub = free[y0:y1, x0:x1]
            if not sub.any():
                continue
            yy, xx = np.mgrid[y0:y1, x0:x1]
            dy, dx = yy - cy, xx - cx
            shape = rng.integers(3)
            if shape == 0:  # disc
                inside = dy * dy + dx * dx <= r * r
            else:  # an ellipse or a rectangle at a random angle, same area scale
                t = rng.uniform(0, math.pi)
                u, v = dx * math.cos(t) + dy * math.sin(t), -dx * math.sin(t) + dy * math.cos(t)
                e = rng.uniform(0.4, 1.0)
                inside = ((u / r) ** 2 + (v / (r * e)) ** 2 <= 1) if shape == 1 else ((np.abs(u) <= r) & (np.abs(v) <= r * e))
            mask = inside & sub
            if not mask.any():
                continue
            base = _leaf_colour(rng, colour)
            shade = np.ones(mask.shape)
            if textured and r > 3:
                kind = rng.integers(4)
                if kind == 1:  # a linear gradient across the leaf
                    g = rng.normal(size=2)
                    shade = 1 + rng.uniform(0.1, 0.5) * (dx * g[0] + dy * g[1]) / (r * np.linalg.norm(g) + 1e-9)
                elif kind == 2:  # stripes
                    t, f = rng.uniform(0, math.pi), rng.uniform(0.5, 4.0) / r
                    shade = 1 + rng.uniform(0.1, 0.4) * np.sin(2 * math.pi * f * (dx * math.cos(t) + dy * math.sin(t)))
                elif kind == 3:  # noise (the coarse field, bilinear)
                    ny, nx = yy / 4.0, xx / 4.0
                    iy, ix = ny.astype(int), nx.astype(int)
                    fy, fx = ny - iy, nx - ix
                    n = (noise[iy, ix] * (1 - fx) * (1 - fy) + noise[iy, ix + 1] * fx * (1 - fy)
                         + noise[iy + 1, ix] * (1 - fx) * fy + noise[iy + 1, ix + 1] * fx * fy)
                    shade = 1 + rng.uniform(0.1, 0.35) * n
            img[y0:y1, x0:x1][mask] = base[None, :] * np.clip(shade[mask], 0.2, 2.0)[:, None]
            free[y0:y1, x0:x1][mask] = False
            if not free.any():
                break
    if free.any():  # the last uncovered pixels (a handful at most): the mean colour
        img[free] = img[~free].mean(axis=0)
    return np.clip(img, 0.0, 1.0)


def package_photo(rng: np.random.Generator, size: int = 512, name: str | None = None) -> tuple[np.ndarray, dict]:
    """A random square crop (random scale, random flip) of one of PHOTOS, resized to `size`, as a
    linear reflectance, and its record {name, file, licence, source, crop}."""
    from PIL import Image

    if name is None:
        name = str(rng.choice(sorted(PHOTOS)))
    if name not in PHOTOS:
        raise ValueError(f"unknown package photo {name!r}; known: {sorted(PHOTOS)}")
    photo = PHOTOS[name]
    path = photo_folder() / photo.filename
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the installed scikit-image has no {photo.filename} (needed by natural scenes)")
    with Image.open(path) as im:
        pil = im.convert("RGB")
    w, h = pil.size
    side = int(min(h, w) * rng.uniform(0.45, 1.0))
    x0, y0 = int(rng.integers(0, w - side + 1)), int(rng.integers(0, h - side + 1))
    crop = pil.crop((x0, y0, x0 + side, y0 + side)).resize((size, size), Image.Resampling.BILINEAR)
    img = srgb_to_linear(np.asarray(crop, dtype=np.float64) / 255.0)
    if rng.random() < 0.5:
        img = img[:, ::-1]
    return img, {"name": name, "package_file": photo.filename, "licence": photo.licence, "source": photo.source,
                 "crop": [x0, y0, side], "package": f"scikit-image {photo_version()}"}


def power_spectrum_slope(img: np.ndarray, f_lo: float = 0.02, f_hi: float = 0.25) -> float:
    """Slope of the radially averaged power spectrum of an image's luminance, log-log, fitted between
    f_lo and f_hi cycles per pixel (natural images: about -2)."""
    grey = img @ np.array([0.2126, 0.7152, 0.0722]) if img.ndim == 3 else np.asarray(img, dtype=np.float64)
    grey = grey - grey.mean()
    h, w = grey.shape
    win = np.outer(np.hanning(h), np.hanning(w))  # no edge leakage from the non-periodic borders
    p = np.abs(np.fft.fft2(grey * win)) ** 2
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(h), np.fft.fftfreq(w), indexing="ij"))
    edges = np.geomspace(f_lo, f_hi, 16)
    which = np.digitize(f, edges)
    fs, ps = [], []
    for k in range(1, len(edges)):
        sel = which == k
        if sel.any():
            fs.append(f[sel].mean())
            ps.append(p[sel].mean())
    return float(np.polyfit(np.log(fs), np.log(ps), 1)[0])


__all__ = ["dead_leaves", "package_photo", "power_law_radii", "power_spectrum_slope", "save_srgb", "PHOTOS",
           "Photo", "photo_folder", "photo_version", "LEAF_RADIUS_EXPONENT", "srgb_to_linear", "linear_to_srgb"]
