"""Procedural textures for the bundled scenes (deterministic given a seed).

Images are sRGB uint8 arrays, row 0 at the top; Mitsuba maps texture coordinate (u, v) = (0, 0)
to the top-left pixel (checked by rendering: scenes.md). Periodic noise comes from filtered white
noise in the Fourier domain, so textures that repeat across a floor or road tile without seams.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont


def periodic_noise(rng: np.random.Generator, h: int, w: int, scale: float, octaves: int = 4) -> np.ndarray:
    """Fractal noise in [0, 1], periodic in both axes; `scale` is the largest feature in pixels."""
    out = np.zeros((h, w))
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    f = np.sqrt(fx ** 2 + fy ** 2)
    for o in range(octaves):
        s = scale / 2 ** o
        spectrum = np.fft.fft2(rng.standard_normal((h, w))) * np.exp(-(f * s) ** 2)
        layer = np.real(np.fft.ifft2(spectrum))
        out += layer / (layer.std() + 1e-12) * 0.5 ** o
    out -= out.min()
    return out / (out.max() + 1e-12)


def mix(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Blend colours a -> b by t (..., broadcasting a trailing RGB axis)."""
    t = np.asarray(t)[..., None]
    return np.asarray(a, dtype=np.float64) * (1 - t) + np.asarray(b, dtype=np.float64) * t


def to_uint8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def font(size: int) -> ImageFont.ImageFont:
    """Pillow's bundled font (FreeType), so text renders the same on every machine."""
    return ImageFont.load_default(size=size)


def draw_text(img: np.ndarray, xy: tuple[int, int], text: str, size: int, fill: tuple[int, ...],
              anchor: str = "mm") -> np.ndarray:
    pil = Image.fromarray(to_uint8(img))
    ImageDraw.Draw(pil).text(xy, text, fill=fill, font=font(size), anchor=anchor)
    return np.asarray(pil).astype(np.float64)


def save(img: np.ndarray, path: Path) -> Path:
    """PNG for flat artwork (compresses well), JPEG (quality 90) for noisy surfaces."""
    path.parent.mkdir(parents=True, exist_ok=True)
    pil = Image.fromarray(to_uint8(img))
    if path.suffix == ".jpg":
        pil.save(path, quality=90, optimize=True)
    else:
        pil.save(path, optimize=True)
    return path


# ---- surfaces ------------------------------------------------------------------------------------
def wood_planks(rng: np.random.Generator, size: int, planks: int, base: tuple, dark: tuple) -> np.ndarray:
    """Floor/desk wood: `planks` boards along u, each with its own tone and stretched grain."""
    h = w = size
    grain = periodic_noise(rng, h, w * 8, scale=6, octaves=3)[:, ::8]  # stretched along u
    grain = 0.5 + 0.5 * np.sin(grain * 40.0)
    board = (np.arange(h) * planks // h)
    tone = rng.uniform(-0.12, 0.12, planks)[board][:, None]
    t = np.clip(0.35 * grain + 0.5 + tone, 0, 1)
    img = mix(base, dark, t)
    gaps = (np.arange(h) % (h // planks)) < max(1, size // 256)
    img[gaps] = np.asarray(dark) * 0.55
    # staggered board ends
    for b in range(planks):
        x = int(rng.integers(0, w))
        rows = slice(b * h // planks, (b + 1) * h // planks)
        img[rows, x:x + max(1, size // 256)] = np.asarray(dark) * 0.55
    return img


def asphalt(rng: np.random.Generator, size: int) -> np.ndarray:
    n = periodic_noise(rng, size, size, scale=3, octaves=2)
    coarse = periodic_noise(rng, size, size, scale=40, octaves=2)
    v = 55 + 45 * n + 25 * coarse
    speck = rng.random((size, size)) > 0.985
    v[speck] += 60
    return np.repeat(v[..., None], 3, axis=2) * np.array([1.0, 1.0, 1.03])


def tiles(rng: np.random.Generator, size: int, n: int, colour: tuple, grout: tuple) -> np.ndarray:
    """Square wall tiles with grout lines and a slight per-tile tone."""
    idx = np.arange(size) * n // size
    tone = rng.uniform(-10, 10, (n, n))[idx[:, None], idx[None, :]]
    img = np.ones((size, size, 3)) * np.asarray(colour, dtype=np.float64) + tone[..., None]
    line = (np.arange(size) % (size // n)) < max(2, size // 128)
    img[line, :] = grout
    img[:, line] = grout
    return img


def stone(rng: np.random.Generator, size: int, base: tuple, vein: tuple) -> np.ndarray:
    n = periodic_noise(rng, size, size, scale=20, octaves=5)
    speck = periodic_noise(rng, size, size, scale=1.5, octaves=1)
    return mix(base, vein, np.clip(0.8 * n + 0.4 * (speck > 0.75), 0, 1))


def brick_facade(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """Building front: brick rows with windows and a shop sign."""
    img = np.zeros((h, w, 3))
    bh, bw = 8, 24
    n = periodic_noise(rng, h, w, scale=2, octaves=1)
    for r in range(h // bh + 1):
        off = (bw // 2) * (r % 2)
        for c in range(-1, w // bw + 1):
            col = np.array([150, 70, 50]) + rng.uniform(-25, 25) + np.array([0, rng.uniform(-8, 8), 0])
            y0, x0 = r * bh, c * bw + off
            img[y0:y0 + bh - 1, max(0, x0):max(0, x0 + bw - 1)] = col
    img += (n[..., None] - 0.5) * 30
    mortar = np.all(img < 40, axis=2)
    img[mortar] = [175, 170, 160]
    for wx in range(40, w - 60, 150):  # windows: two storeys
        for wy in (40, h // 2 + 20):
            img[wy:wy + 110, wx:wx + 80] = [205, 205, 200]
            img[wy + 6:wy + 104, wx + 6:wx + 74] = [40, 55, 70]
            img[wy + 6:wy + 104, wx + 38:wx + 42] = [205, 205, 200]
            img[wy + 52:wy + 56, wx + 6:wx + 74] = [205, 205, 200]
    img[h - 70:h - 20, 60:420] = [30, 60, 110]
    return draw_text(img, (240, h - 45), "BAKERY  ·  OPEN", 34, (240, 230, 200))


def painted_wall(rng: np.random.Generator, w: int, h: int, lower: tuple, upper: tuple, label: str) -> np.ndarray:
    """A gym wall: two-tone paint, a stripe and a painted label."""
    n = periodic_noise(rng, h, w, scale=30, octaves=3)
    img = np.where((np.arange(h) > h * 0.55)[:, None, None], np.asarray(lower, float), np.asarray(upper, float))
    img = img * (0.95 + 0.1 * n[..., None])
    img[int(h * 0.53):int(h * 0.56)] = [230, 190, 40]
    img = draw_text(img, (int(w * 0.3), int(h * 0.33)), label, h // 7, (40, 60, 120))
    # a poster
    px, py, pw, ph = int(w * 0.68), int(h * 0.12), int(w * 0.12), int(h * 0.32)
    img[py:py + ph, px:px + pw] = [235, 235, 230]
    img[py + 8:py + ph // 2, px + 8:px + pw - 8] = [200, 60, 50]
    return draw_text(img, (px + pw // 2, py + int(ph * 0.75)), "TEAM", h // 16, (20, 20, 20))


def wallpaper(rng: np.random.Generator, size: int) -> np.ndarray:
    """A repeating leaf-and-stripe wallpaper."""
    y, x = np.mgrid[0:size, 0:size] / size
    base = np.array([222, 214, 190], float)
    img = np.ones((size, size, 3)) * base
    stripe = (np.sin(2 * np.pi * x * 8) > 0.85)
    img[stripe] = [180, 150, 110]
    for cy in np.arange(0.125, 1.0, 0.25):
        for cx in np.arange(0.0625, 1.0, 0.125):
            if int(cx * 8) % 2 == 0:
                continue
            d = ((x - cx) / 0.03) ** 2 + ((y - cy) / 0.06) ** 2
            img[d < 1] = [90, 130, 80]
    n = periodic_noise(rng, size, size, scale=4, octaves=1)
    return img * (0.93 + 0.1 * n[..., None])


# ---- objects -------------------------------------------------------------------------------------
def basketball(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """Sphere texture (u = longitude, v = colatitude): orange pebbled leather, black seams."""
    u = (np.arange(w) + 0.5) / w * 2 * np.pi
    v = (np.arange(h) + 0.5) / h * np.pi
    uu, vv = np.meshgrid(u, v)
    pebble = periodic_noise(rng, h, w, scale=1.2, octaves=1)
    img = mix([205, 95, 30], [160, 65, 20], pebble)
    x, y, z = np.sin(vv) * np.cos(uu), np.sin(vv) * np.sin(uu), np.cos(vv)
    seams = (np.abs(z) < 0.03) | (np.abs(x) < 0.03)
    # the two curved seams: circles where |y| ~ 0.7
    seams |= np.abs(np.abs(y) - 0.72) < 0.035
    img[seams] = [25, 20, 18]
    return img


def volleyball(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)
    band = (np.floor(uu * 6) + np.floor(vv * 3)) % 3
    cols = np.array([[240, 240, 235], [30, 80, 170], [240, 200, 40]], float)
    img = cols[band.astype(int)]
    edge = (np.abs((uu * 6) % 1 - 0.5) > 0.47) | (np.abs((vv * 3) % 1 - 0.5) > 0.47)
    img[edge] *= 0.6
    return img * (0.95 + 0.05 * periodic_noise(rng, h, w, 2, 1)[..., None])


def solid_noise(rng: np.random.Generator, size: int, a: tuple, b: tuple, scale: float = 4.0) -> np.ndarray:
    return mix(a, b, periodic_noise(rng, size, size, scale=scale, octaves=3))


def car_side(w: int, h: int) -> np.ndarray:
    """Side artwork of the car body (u along the car, rear at u = 0; v = 0 at the top)."""
    img = np.ones((h, w, 3)) * np.array([170, 25, 30], float)  # red paint
    img[: int(h * 0.08)] *= 0.8
    img[int(h * 0.45):int(h * 0.48)] = [120, 15, 20]           # swage line
    for x0 in (0.30, 0.55):                                     # door gaps
        img[:, int(w * x0):int(w * x0) + 2] = [60, 8, 10]
    for x0 in (0.47, 0.72):                                     # handles
        img[int(h * 0.30):int(h * 0.36), int(w * x0):int(w * x0) + 18] = [200, 200, 205]
    img[int(h * 0.15):int(h * 0.35), w - 26:w - 4] = [250, 240, 200]  # head lamp
    img[int(h * 0.15):int(h * 0.35), 4:22] = [200, 20, 10]            # tail lamp
    img[int(h * 0.80):] = [30, 30, 32]                                  # sill / bumper
    return draw_text(img, (int(w * 0.62), int(h * 0.62)), "TAXI 2024", h // 7, (250, 230, 60))


def car_glass(w: int, h: int) -> np.ndarray:
    """Cabin side: dark glass with pillars (u along the car, v = 0 at the roof)."""
    img = np.ones((h, w, 3)) * np.array([35, 45, 55], float)
    img[: int(h * 0.12)] = [170, 25, 30]
    for x0, x1 in ((0.0, 0.06), (0.47, 0.53), (0.94, 1.0)):
        img[:, int(w * x0):int(w * x1)] = [170, 25, 30]
    y = np.arange(h)[:, None] / h
    x = np.arange(w)[None, :] / w
    img += (30 * np.clip(1 - np.abs(x - y * 0.7 - 0.2) * 6, 0, 1))[..., None]  # sky reflection
    return img


def wheel(size: int) -> np.ndarray:
    """Wheel face seen along its axle: tyre, rim, five spokes, a valve mark (u, v planar)."""
    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size * 2 - 1
    r = np.hypot(x, y)
    a = np.arctan2(y, x)
    img = np.ones((size, size, 3)) * 25.0
    rim = r < 0.68
    img[rim] = [165, 168, 172]
    spokes = rim & (r > 0.16) & (np.cos(5 * a) < 0.55)
    img[spokes] = [45, 45, 48]
    img[r < 0.12] = [200, 200, 205]
    img[(np.abs(r - 0.64) < 0.02)] = [110, 110, 115]
    img[(np.hypot(x - 0.58, y) < 0.04)] = [230, 200, 40]  # valve cap: shows the rotation
    return img


def disc_polar(rng: np.random.Generator, size: int) -> np.ndarray:
    """A printed disc, drawn in Cartesian space and resampled to Mitsuba's disk parametrisation
    (u = radius / R, v = angle / 2 pi from +x)."""
    n = 2 * size
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n * 2 - 1
    r, a = np.hypot(x, y), np.arctan2(y, x)
    art = np.ones((n, n, 3)) * 235.0
    sectors = (np.floor((a + np.pi) / (2 * np.pi) * 12) % 2 == 0) & (r > 0.55) & (r < 0.85)
    art[sectors] = [20, 20, 25]
    art[(np.abs(r - 0.5) < 0.02) | (np.abs(r - 0.9) < 0.015)] = [200, 40, 40]
    art[r < 0.08] = [60, 60, 60]
    pil_scale = n // 2
    art = draw_text(art, (pil_scale, int(pil_scale * 0.62)), "SPIKE", n // 9, (30, 60, 160))
    art = draw_text(art, (pil_scale, int(pil_scale * 1.38)), "40 kHz", n // 12, (180, 30, 30))
    # resample: texture row = angle, column = radius
    rr = (np.arange(size) + 0.5) / size
    aa = (np.arange(size) + 0.5) / size * 2 * np.pi
    R, A = np.meshgrid(rr, aa)
    # disk's local +y is image-up in the artwork; image rows grow downwards
    cx = ((R * np.cos(A) + 1) / 2 * n).astype(int).clip(0, n - 1)
    cy = ((1 - (R * np.sin(A) + 1) / 2) * n).astype(int).clip(0, n - 1)
    return art[cy, cx] * (0.97 + 0.03 * periodic_noise(rng, size, size, 3, 1)[..., None])


def fan_hub(size: int) -> np.ndarray:
    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size * 2 - 1
    img = np.ones((size, size, 3)) * np.array([40, 90, 160], float)
    img[(np.abs(x) < 0.12) & (y < 0)] = [240, 240, 240]  # a white mark: the rotation is visible
    img[np.hypot(x, y) < 0.25] = [220, 220, 225]
    return img


__all__ = [n for n in dir() if not n.startswith("_")]
