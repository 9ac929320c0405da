"""Render settings: the one record of the renderer's knobs (variant, samples per pixel, keyframe
spacing, seed and per-step seeding, sub-steps, resolution, device), and the one place where layers of them (defaults,
a preset, a scene's own XML, a settings file, command-line flags) are merged, remembering where
each value came from.

SceneRenderer (spikesim.render), the quality presets (spikesim.quality), dataset generation
(spikesim.generation) and the trade study (pipelines.tradeoff_study) all hold a RenderSettings rather
than declaring these knobs again. Importing this module does not import Mitsuba.
"""
from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from spikesim._drjit import DEVICE_CHOICES

VARIANTS = ("auto", "mono", "spectral", "rgb")
STEP_SEEDS = ("fresh", "fixed")
DEFAULT = "default"
"""The origin of a value no layer set."""


def _positive_int(name: str, v: Any) -> None:
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise ValueError(f"{name}={v!r} must be a positive integer")


MAX_SAMPLES_PER_RENDER = (1 << 32) - 1
"""Mitsuba renders a whole image in one wavefront of pixels x spp samples, and Dr.Jit indexes
arrays with 32-bit integers: more samples in one render fail deep inside Mitsuba."""


def check_samples(spp: int, height: int, width: int, what: str = "spp") -> None:
    """A ValueError naming `what` when spp samples for each of height x width pixels do not fit
    in one render (MAX_SAMPLES_PER_RENDER)."""
    total = int(spp) * int(height) * int(width)
    if total > MAX_SAMPLES_PER_RENDER:
        raise ValueError(f"{what}={spp} at {height}x{width} pixels is {total:.3g} samples in one render, more than "
                         f"the {MAX_SAMPLES_PER_RENDER + 1:.3g} Mitsuba can take; lower it")


@dataclass(frozen=True)
class RenderSettings:
    """The renderer's knobs (everything that changes the output besides the scene files)."""

    variant: str = "auto"
    """"mono" (fast path: one number per surface, its sensor reflectance under the light, and the
    light's spectrum folded into its power), "spectral" (spectral rendering weighted by the
    silicon response), "rgb" (previews only, no y), or "auto": mono when the lighting has a
    single spectrum (then mono is exact up to inter-reflections), spectral when it mixes spectra."""
    spp: int = 4
    """Samples per pixel of each render of a frame (a step with s sub-steps renders s times)."""
    gt_spp: int = 64
    """Samples per pixel of a ground-truth image, spread over its motion-blur sub-step renders
    (ceil(gt_spp / s) each, spikesim.render.renderer.samples_per_substep); `spp` is each frame
    render's own, since the sample rule measures a frame's noise as rendered."""
    keyframe_every: int = 1
    """Steps between rendered frames; the sensor interpolates in between (spikesim.keyframes)."""
    seed: int = 0
    """Every render's seed derives from (seed, stream, step, sub-step): frames are reproducible and
    independent of where a stream starts."""
    step_seeds: str = "fresh"
    """"fresh": each step renders with its own seed (consecutive frames have independent Monte Carlo
    noise, which the sensor averages over a window); "fixed": every step renders with step 0's seed
    (sub-steps still differ), so the noise pattern repeats from frame to frame. A knob of the
    speed/accuracy study (docs/tradeoff.md)."""
    substeps: int | str = "auto"
    """Renders averaged per step: an integer, or "auto" = ceil(motion in pixels / blur_threshold_px)."""
    blur_threshold_px: float = 1.0
    max_substeps: int = 16
    resolution: tuple[int, int] | None = None
    """(height, width) override, e.g. (25, 40) for tests; default: the camera's, else the XML's."""
    device: str = "auto"
    """Dr.Jit backend: "llvm" (CPU), "cuda" (GPU), or "auto" (the GPU when there is one)."""

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"variant={self.variant!r}; expected 'auto', 'mono', 'spectral' or 'rgb'")
        for name in ("spp", "gt_spp", "keyframe_every", "max_substeps"):
            _positive_int(name, getattr(self, name))
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed={self.seed!r} must be a non-negative integer")
        if self.step_seeds not in STEP_SEEDS:
            raise ValueError(f"step_seeds={self.step_seeds!r}; expected one of {STEP_SEEDS}")
        if self.substeps != "auto":
            _positive_int("substeps", self.substeps)
        if not self.blur_threshold_px > 0:
            raise ValueError(f"blur_threshold_px={self.blur_threshold_px!r} must be positive")
        if self.resolution is not None:
            r = tuple(self.resolution)
            if len(r) != 2 or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in r):
                raise ValueError(f"resolution={self.resolution!r} must be (height, width) positive integers")
            object.__setattr__(self, "resolution", r)
        if self.device not in DEVICE_CHOICES:
            raise ValueError(f"device={self.device!r}; expected one of {DEVICE_CHOICES}")

    def replace(self, **changes: Any) -> "RenderSettings":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["resolution"] = list(self.resolution) if self.resolution else None
        return d

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "RenderSettings":
        from spikesim.config_io import check_known_fields
        check_known_fields(cls, dict(data), "render settings")
        d = dict(data)
        if d.get("resolution") is not None:
            d["resolution"] = tuple(d["resolution"])
        return cls(**d)

    @classmethod
    def from_file(cls, path: str | Path) -> "RenderSettings":
        from spikesim.config_io import load_config_file
        return load_config_file(path, cls.from_dict)


RENDER_KNOBS = tuple(f.name for f in dataclasses.fields(RenderSettings))


def split_render_knobs(values: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """`values` as (render knobs, everything else)."""
    render = {k: v for k, v in values.items() if k in RENDER_KNOBS}
    return render, {k: v for k, v in values.items() if k not in RENDER_KNOBS}


def render_knob(knob: str, holder: str = "render") -> property:
    """A read-only attribute that reads `knob` of the RenderSettings held in field `holder`."""
    return property(lambda self: getattr(getattr(self, holder), knob), doc=f"{holder}.{knob} (RenderSettings)")


class HoldsRenderSettings:
    """For a frozen dataclass that holds its render knobs in a RenderSettings field `render`:
    the common knobs read through, and `replace` sends render knobs to that record."""

    spp = render_knob("spp")
    gt_spp = render_knob("gt_spp")
    variant = render_knob("variant")
    keyframe_every = render_knob("keyframe_every")

    def replace(self, **changes: Any) -> Any:
        render, rest = split_render_knobs(changes)
        if render:
            rest["render"] = self.render.replace(**render)  # type: ignore[attr-defined]
        return dataclasses.replace(self, **rest)  # type: ignore[type-var]


def merge_layers(layers: Sequence[tuple[str, Mapping[str, Any] | None]]) -> tuple[dict[str, Any], dict[str, str]]:
    """Merge layers of settings, later ones winning, and say where each value came from.

    Each layer is (origin, values), e.g. ("preset small", {...}), ("scene XML", {...}),
    ("--spp", {"spp": 8}); a value of None is "not given" and leaves the one below it. Returns the
    merged values and, for each, the origin of the layer that set it."""
    values: dict[str, Any] = {}
    origins: dict[str, str] = {}
    for origin, layer in layers:
        for key, value in (layer or {}).items():
            if value is not None:
                values[key], origins[key] = value, origin
    return values, origins


__all__ = ["RenderSettings", "RENDER_KNOBS", "STEP_SEEDS", "VARIANTS", "DEFAULT", "HoldsRenderSettings", "merge_layers",
           "render_knob", "split_render_knobs"]
