"""RLLR's `photo` content: video-like scenes made without a renderer.

A REDS frame is a photograph of a street or of people, textured and lit over the whole frame, under
a camera that moves; RLLR's 3D scenes (`procedural`, `natural`) are mostly a dark room with small
objects in it. This source fills the frame the way a video does:

- a backdrop: a photograph (scikit-image's bundled pictures, scenes/natural_textures.PHOTOS) or a
  dead-leaves image, larger than the frame, the camera panning across it (a straight pan at an
  image speed drawn log-uniformly in PAN_PX_PER_STEP, or a shake: the pan plus a wobble), or,
  with a chance `still_share`, standing still;
- in front of it, 0-3 objects: discs and rectangles cut from other pictures, each crossing the view
  at its own speed (OBJECT_PX_PER_STEP);
- light: white (reflectance 1) maps to `peak_y` expected spikes per step, times RLLR's darkening
  factor, so the same scene spans the light range the dataset draws.

Frames are exact, per step, in y units (bilinear sampling of the pictures at each step's position;
no Monte Carlo noise, so the ground truth is clean; no motion blur inside a 25 us step, where the
image moves at most PAN_PX_PER_STEP[1] pixels). Two picture sets: `train` (PHOTOS and dead leaves)
and `heldout` (HELD_OUT_PHOTOS, never in a training scene), for test pairs made the way another
simulator makes its REDS data (pipelines/reds_like.py): there `encoding="srgb"` takes the picture's
8-bit grey value as the intensity, as that simulator reads its PNG frames, where `linear` (the
default) takes the physical reflectance.

A scene is its seed, its picture set, its size, its length, PHOTO_PAN_VERSION and scikit-image's
version (its pictures).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from scenes.natural_scene import _log_uniform
from scenes.natural_textures import PHOTOS, Photo, dead_leaves, linear_to_srgb, photo_folder, srgb_to_linear

PHOTO_PAN_VERSION = 1
"""Raise with any change that builds another scene from the same parameters."""
#: White's expected spikes per step before RLLR's darkening: just below the sensor's saturation
#: (y = 1 spike per step), so the brightest scenes reach it and the darkening reaches LLR's low light.
PHOTO_PEAK_Y = 0.8
#: The camera's image speed, pixels per 25 us step, log-uniform: from barely moving to past the
#: fastest REDS-like motion (natural_scene.CAMERA_PX_PER_STEP, extended to 2 px per step).
PAN_PX_PER_STEP = (0.02, 2.0)
#: Objects crossing in front, pixels per step, log-uniform.
OBJECT_PX_PER_STEP = (0.05, 3.0)
#: The pictures a test pair may use and no training scene does: scikit-image's other bundled
#: pictures with photographic content (licences as scikit-image's `skimage.data` docs state them).
HELD_OUT_PHOTOS: dict[str, Photo] = {
    "motorcycle": Photo("motorcycle_left.png", "Middlebury stereo data (Scharstein et al.), as skimage.data "
                        "ships it", "skimage.data.stereo_motorcycle"),
    "retina": Photo("retina.jpg", "CC BY 3.0 (Mikael Haggstrom)", "skimage.data.retina"),
    "ihc": Photo("ihc.png", "public domain", "skimage.data.immunohistochemistry"),
    "moon": Photo("moon.png", "no known copyright restrictions", "skimage.data.moon"),
    "page": Photo("page.png", "public domain", "skimage.data.page"),
}
PHOTO_SETS = ("train", "heldout")
ENCODINGS = ("linear", "srgb")
_LUMA = np.array([0.2126, 0.7152, 0.0722])


@functools.lru_cache(maxsize=8)
def _picture(filename: str, encoding: str) -> np.ndarray:
    """A bundled picture as grey intensity in [0, 1], float64 (H, W)."""
    from PIL import Image

    path = photo_folder() / filename
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the installed scikit-image has no {filename} (needed by photo scenes)")
    with Image.open(path) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
    return (srgb_to_linear(rgb) if encoding == "linear" else rgb) @ _LUMA


def _resize(img: np.ndarray, h: int, w: int) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.fromarray(img.astype(np.float32), mode="F").resize((w, h), Image.Resampling.BILINEAR),
                      dtype=np.float64)


def _shift(canvas: np.ndarray, y: float, x: float, h: int, w: int) -> np.ndarray:
    """canvas sampled bilinearly on the h x w grid offset by (y, x) (inside the canvas)."""
    iy, ix = int(math.floor(y)), int(math.floor(x))
    fy, fx = y - iy, x - ix
    a = canvas[iy:iy + h + 1, ix:ix + w + 1]
    top = a[:h, :w] * (1 - fx) + a[:h, 1:w + 1] * fx
    bottom = a[1:h + 1, :w] * (1 - fx) + a[1:h + 1, 1:w + 1] * fx
    return top * (1 - fy) + bottom * fy


@dataclass(frozen=True)
class PhotoPan:
    """A video-like scene in y units (module docstring); frame(step), frames(n, start, every) as
    spikesim.patterns.MovingPattern, so a generation job takes either."""

    height: int
    width: int
    num_steps: int
    seed: int = 0
    peak_y: float = PHOTO_PEAK_Y
    photo_set: str = "train"
    encoding: str = "linear"
    still_share: float = 0.0
    """The chance that the camera stands still (objects still cross in front): LLR's static
    backgrounds, where an average over several windows is the best classic estimate. Drawn from a
    stream of its own, so a scene with 0 is the scene it was before this field existed."""

    def __post_init__(self) -> None:
        if not (isinstance(self.still_share, (int, float)) and 0.0 <= self.still_share <= 1.0):
            raise ValueError(f"still_share={self.still_share!r}: expected a chance in [0, 1]")
        if not (isinstance(self.height, int) and isinstance(self.width, int) and self.height > 0 and self.width > 0):
            raise ValueError(f"photo scene size must be positive integers, got {self.height}x{self.width}")
        if not (isinstance(self.num_steps, int) and self.num_steps >= 1):
            raise ValueError(f"photo scene num_steps must be an integer >= 1, got {self.num_steps!r}")
        if not (math.isfinite(self.peak_y) and self.peak_y >= 0):
            raise ValueError(f"peak_y must be finite and >= 0, got {self.peak_y}")
        if self.photo_set not in PHOTO_SETS:
            raise ValueError(f"photo_set={self.photo_set!r}; expected one of {PHOTO_SETS}")
        if self.encoding not in ENCODINGS:
            raise ValueError(f"encoding={self.encoding!r}; expected one of {ENCODINGS}")

    # ---- the scene, drawn once from the seed ------------------------------------------------
    def _pictures(self) -> dict[str, Photo]:
        return PHOTOS if self.photo_set == "train" else HELD_OUT_PHOTOS

    def _draw_picture(self, rng: np.random.Generator, h: int, w: int, dead_leaves_share: float) -> tuple[np.ndarray, dict]:
        """A grey picture of at least h x w pixels (a random crop, flip and zoom of a bundled one, or
        dead leaves), and its record."""
        if self.photo_set == "train" and rng.random() < dead_leaves_share:
            side = max(h, w)
            size = min(1024, max(64, side))
            img = dead_leaves(rng, size, colour=bool(rng.random() < 0.7))
            grey = (img if self.encoding == "linear" else linear_to_srgb(img)) @ _LUMA
            return _resize(grey, h, w), {"kind": "dead-leaves"}
        name = str(rng.choice(sorted(self._pictures())))
        photo = self._pictures()[name]
        pic = _picture(photo.filename, self.encoding)
        ph, pw = pic.shape
        frac = rng.uniform(0.5, 1.0)  # the share of the picture's shorter side the crop keeps
        ch = max(8, int(min(ph, pw * h / w) * frac))
        cw = max(8, int(ch * w / h))
        cw = min(cw, pw)
        ch = min(ch, ph)
        y0, x0 = int(rng.integers(0, ph - ch + 1)), int(rng.integers(0, pw - cw + 1))
        crop = pic[y0:y0 + ch, x0:x0 + cw]
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        return _resize(crop, h, w), {"kind": "photo", "name": name, "file": photo.filename, "licence": photo.licence,
                                     "crop": [x0, y0, cw, ch]}

    @functools.cached_property
    def layout(self) -> dict:
        """The backdrop canvas, the camera path and the objects: everything drawn from the seed."""
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed), 5150]))
        h, w, n = self.height, self.width, self.num_steps
        speed = _log_uniform(rng, *PAN_PX_PER_STEP)
        angle = rng.uniform(0, 2 * math.pi)
        kind = str(rng.choice(["pan", "shake"], p=[0.7, 0.3]))
        wobble = speed * rng.uniform(0.5, 2.0) if kind == "shake" else 0.0
        period = float(rng.uniform(40, 400))  # steps per wobble cycle (1-10 ms)
        vy, vx = speed * math.sin(angle), speed * math.cos(angle)
        amp = wobble * period / (2 * math.pi)  # a wobble whose peak speed is `wobble` px per step
        reach_y = abs(vy) * (n - 1) + 2 * amp + 2
        reach_x = abs(vx) * (n - 1) + 2 * amp + 2
        ch, cw = int(math.ceil(h + reach_y)) + 2, int(math.ceil(w + reach_x)) + 2
        backdrop, record = self._draw_picture(rng, ch, cw, dead_leaves_share=0.3)
        start = (amp + 1 + (abs(vy) * (n - 1) if vy < 0 else 0.0), amp + 1 + (abs(vx) * (n - 1) if vx < 0 else 0.0))
        objects = []
        for i in range(int(rng.integers(0, 4))):
            size = int(max(6, min(h, w) * rng.uniform(0.1, 0.45)))
            tex, rec = self._draw_picture(rng, size, size, dead_leaves_share=0.4)
            shape = str(rng.choice(["disc", "rect"]))
            yy, xx = np.mgrid[0:size, 0:size] + 0.5
            mask = (np.hypot(yy - size / 2, xx - size / 2) <= size / 2) if shape == "disc" else np.ones((size, size), bool)
            ospeed = _log_uniform(rng, *OBJECT_PX_PER_STEP)
            oangle = rng.uniform(0, 2 * math.pi)
            # placed so that it is in view at the scene's middle step
            mid = (rng.uniform(-size / 2, h - size / 2), rng.uniform(-size / 2, w - size / 2))
            objects.append({"texture": tex * rng.uniform(0.5, 1.0), "mask": mask, "mid": mid,
                            "velocity": (ospeed * math.sin(oangle), ospeed * math.cos(oangle)),
                            "record": {"shape": shape, "size_px": size, "px_per_step": ospeed, **rec}})
        gain = float(rng.uniform(0.5, 1.0))  # surfaces are not all white paper
        if self.still_share > 0 and np.random.default_rng(
                np.random.SeedSequence([int(self.seed), 5152])).random() < self.still_share:
            kind, speed, wobble, vy, vx, amp = "still", 0.0, 0.0, 0.0, 0.0, 0.0  # the drawn canvas still fits
        return {"canvas": backdrop * gain, "start": start, "velocity": (vy, vx), "wobble_amp": amp,
                "wobble_period": period, "wobble_phase": float(rng.uniform(0, 2 * math.pi)), "objects": objects,
                "record": {"camera": {"kind": kind, "px_per_step": speed, "wobble_px_per_step": wobble},
                           "backdrop": record, "objects": [o["record"] for o in objects]}}

    def camera_offset(self, step: float) -> tuple[float, float]:
        lay = self.layout
        ph = 2 * math.pi * step / lay["wobble_period"] + lay["wobble_phase"]
        a = lay["wobble_amp"]
        return (lay["start"][0] + lay["velocity"][0] * step + a * math.sin(ph),
                lay["start"][1] + lay["velocity"][1] * step + a * math.sin(1.3 * ph + 1.0))

    # ---- frames ------------------------------------------------------------------------------
    def frame(self, step: int) -> np.ndarray:
        """y at `step` (expected spikes per step), float32 (H, W)."""
        lay = self.layout
        h, w = self.height, self.width
        oy, ox = self.camera_offset(step)
        img = _shift(lay["canvas"], oy, ox, h, w)
        mid = (self.num_steps - 1) / 2
        for o in lay["objects"]:
            size = o["mask"].shape[0]
            y = o["mid"][0] + o["velocity"][0] * (step - mid)
            x = o["mid"][1] + o["velocity"][1] * (step - mid)
            iy, ix = int(round(y)), int(round(x))  # objects move by whole pixels: crisp edges
            y0, x0, y1, x1 = max(iy, 0), max(ix, 0), min(iy + size, h), min(ix + size, w)
            if y0 >= y1 or x0 >= x1:
                continue
            m = o["mask"][y0 - iy:y1 - iy, x0 - ix:x1 - ix]
            region = img[y0:y1, x0:x1]
            region[m] = o["texture"][y0 - iy:y1 - iy, x0 - ix:x1 - ix][m]
        return (np.clip(img, 0.0, 1.0) * self.peak_y).astype(np.float32)

    def frames(self, num_steps: int, start: int = 0, every: int = 1) -> Iterator[np.ndarray]:
        for i in range(num_steps):
            yield self.frame(start + i * every)

    def describe(self) -> dict:
        still = {"still_share": self.still_share} if self.still_share > 0 else {}
        return {"photo_scene": {"generator": "scenes/photo_pan.py", "version": PHOTO_PAN_VERSION,
                                "seed": int(self.seed), "peak_y": self.peak_y, "photo_set": self.photo_set,
                                "encoding": self.encoding, **still, **self.layout["record"]}}


__all__ = ["PhotoPan", "PHOTO_PAN_VERSION", "PHOTO_PEAK_Y", "PAN_PX_PER_STEP", "OBJECT_PX_PER_STEP",
           "HELD_OUT_PHOTOS", "PHOTO_SETS", "ENCODINGS"]
