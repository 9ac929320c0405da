"""SceneRenderer: a physically lit, moving scene rendered step by step into y (spikes per step).

One scene is loaded once and re-rendered many times: motion is applied by parameter updates and
every frame reuses the compiled kernels, so memory stays flat over thousands of frames
(docs/design.md section 4). Frames are yielded one at a time, never held as a sequence.

Time sampling. Step n integrates light over [n T, (n + 1) T) (docs/design.md section 2), so the frame
for step n is the mean over that interval: a render at its midpoint, or, when objects move more
than `blur_threshold_px` pixels within the step, the mean of s renders at sub-step midpoints
(Mitsuba 3.9 has no motion blur of its own, docs/design.md section 4). Ground truth at step n is the
same quantity rendered with many more samples: gt_spp per pixel of the image, spread over its
sub-step renders (`samples_per_substep`), where a frame's spp are each render's.
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..keyframes import keyframe_steps
from ..render_settings import RenderSettings, check_samples, merge_layers
from .animate import Animator
from .backend import dr, mi, resolve_device, use_variant, variant_name
from .errors import SceneError
from .exposure import Exposure, Optics, PixelResponse
from .motion import MotionSpec, load_motion
from .projection import PinholeCamera
from .mono import spectrum_mix
from .scene import SceneFiles, load_scene, prepare_xml, scene_lighting, with_subject
from .scene_checks import check_camera, check_frame
from .illuminance_meter import MeteredIlluminance, meter_illuminance

#: What `SceneRenderer.subject_illuminance` reports, in the words a dataset record uses.
SUBJECT_DIRECT = "direct, computed at the light file's subject (no occlusion, no inter-reflection)"
SUBJECT_METERED = "total (direct and indirect), metered on the surface at the view centre"

#: Seed streams, so frames and ground truth at the same step use independent samples.
_FRAMES, _GROUND_TRUTH, _PREVIEW = 0, 1, 2
_PROBES = 3  # probe i renders as stream _PROBES + i: seeds of their own, apart from the frames


def samples_per_substep(spp: int, substeps: int) -> int:
    """Samples per pixel of each of an image's `substeps` motion-blur renders when the image has
    `spp` in all: ceil(spp / substeps), as a renderer with motion blur of its own spreads a pixel's
    samples over the shutter. A ground-truth image that moves spends the samples of a still one
    (up to rounding), not `substeps` times them; its Monte Carlo error per pixel is then a still
    image's, where the renders' own `spp` each would make it sqrt(substeps) lower at substeps times
    the cost (docs/tradeoff.md section 7, "Ground truth samples per image")."""
    return -(-int(spp) // int(substeps))


def _seed(*parts: int) -> int:
    """A 32-bit render seed from integer parts (NumPy's SeedSequence hashing)."""
    return int(np.random.SeedSequence([int(p) for p in parts]).generate_state(1, np.uint32)[0])


class SceneRenderer:
    """Render a scene under one lighting condition as y frames for the spike sensor.

    `camera` (a spikesim.camera.SpikeCamera) supplies the resolution, readout period and
    threshold; `optics` and `pixel` the exposure assumptions; or pass a whole `exposure`.

    >>> r = SceneRenderer("ball", light="low", variant="mono", spp=4)
    >>> for y in r.frames(0, 41):      # (250, 400) float32 arrays, one per step
    ...     ...
    """

    def __init__(self, scene: str | Path, light: str = "normal", variant: str | None = None,
                 spp: int | None = None, resolution: tuple[int, int] | None = None, seed: int | None = None,
                 *, camera: Any = None, optics: Optics | None = None, pixel: PixelResponse | None = None,
                 exposure: Exposure | None = None, motion: str | Path | None = None,
                 lights: str | Path | None = None, settings: RenderSettings | None = None,
                 light_power_factor: float = 1.0, **overrides: Any):
        if camera is not None and not all(hasattr(camera, k) for k in ("height", "width", "readout_period_s",
                                                                        "threshold_electrons")):
            raise TypeError(f"camera: expected a spikesim.camera.SpikeCamera (e.g. SpikeCamera.preset({camera!r})), "
                            f"got {type(camera).__name__}")  # "realistic" was an AttributeError deep inside
        film = {"resolution": (int(camera.height), int(camera.width))} if camera is not None else None
        values, _ = merge_layers([("camera", film), ("settings", settings.to_dict() if settings else None),
                                  ("arguments", {"variant": variant, "spp": spp, "resolution": resolution,
                                                 "seed": seed, **overrides})])
        self.settings = RenderSettings.from_dict(values)
        factor = light_power_factor
        if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not 0 < factor <= 1e6:
            raise ValueError(f"light_power_factor={factor!r} must be a number in (0, 1e6]")
        self.light_power_factor = float(factor)
        """Multiplies every light's power; light transport is linear in it, so it scales y."""
        self.files = SceneFiles.resolve(scene, motion=motion, lights=lights)
        self.light = light
        self.lighting = scene_lighting(self.files, light)  # the light file's condition, or the XML's emitters
        self.motion = load_motion(self.files.motion) if self.files.motion else MotionSpec.static()
        self.exposure = exposure or Exposure.for_camera(camera, optics=optics, pixel=pixel)
        self.variant = self.settings.variant
        if self.variant == "auto":
            self.variant = "mono" if len(spectrum_mix(self.lighting)) == 1 else "spectral"
        self.device = resolve_device(self.settings.device)  # "llvm" or "cuda": where device frames live
        self._variant = variant_name(self.variant, self.device)
        use_variant(self._variant)
        text, self.sensor_id, (h, w) = prepare_xml(self.files.xml, self.variant, self.lighting,
                                                   self.exposure.pixel, self.settings.resolution)
        self.height, self.width = h, w
        try:
            for what in ("spp", "gt_spp"):
                check_samples(getattr(self.settings, what), h, w, what)
        except ValueError as exc:
            raise SceneError(self.files.xml, str(exc)) from None
        self.scene = load_scene(self.files.xml, text)
        self.lighting = with_subject(self.lighting, self.scene, self.sensor_id)  # view centre if none given
        self.params = mi.traverse(self.scene)
        self.animator = Animator(self.scene, self.params, self.motion)
        self.camera_model = PinholeCamera.from_params(self.params, self.sensor_id, w, h)
        check_camera(self.files.xml, self.camera_model.to_world, self.camera_model.x_fov_deg)
        self._gain = self.exposure.gain_map(h, w, self.camera_model.x_fov_deg)
        if self.light_power_factor != 1.0:
            self._gain = (self._gain * self.light_power_factor).astype(self._gain.dtype, copy=False)
        self._gain_device: Any = None  # the gain map on the render device, made on first use
        self.stats = {"renders": 0, "render_seconds": 0.0, "frames": 0}
        self._view: tuple[np.ndarray, np.ndarray] | None = None  # _view_samples, made on first use
        self._metered: MeteredIlluminance | None = None  # metered_illuminance, measured on first use

    # ---- time ---------------------------------------------------------------------------------
    @property
    def readout_period_s(self) -> float:
        return self.exposure.readout_period_s

    def time_of(self, step: float, fraction: float = 0.5) -> float:
        """Seconds on the motion clock at `fraction` of step `step`'s readout period."""
        return self.motion.start_time_s + (step + fraction) * self.readout_period_s

    def camera_at(self, t: float) -> PinholeCamera:
        """The camera's pose at time t: the rest pose, moved when the motion file moves the camera."""
        if self.sensor_id not in self.motion.targets:
            return self.camera_model
        return self.camera_model.moved(self.motion.transform(self.sensor_id, t))

    def motion_px(self, step: int) -> float:
        """Largest image-plane displacement (pixels) of anything the camera sees during step
        `step`: each moving object's sample points, projected through the camera at the start and
        at the end of the step; and, when the camera itself moves, the scene points it sees (a
        grid of pixels at their depth in the rest pose, `_view_samples`), carried along the camera's
        rays at the start and projected through its pose at the end, which covers both its turn
        (every point shifts, the far ones included) and its translation (near points the most)."""
        if not self.animator.moving:
            return 0.0
        t0, t1 = self.time_of(step, 0.0), self.time_of(step, 1.0)
        cam0, cam1 = self.camera_at(t0), self.camera_at(t1)
        skip = (self.sensor_id,)
        a, _ = cam0.project(self.animator.world_points(t0, skip))
        b, _ = cam1.project(self.animator.world_points(t1, skip))
        d = [np.linalg.norm(b - a, axis=-1)]
        if cam0 is not self.camera_model:
            pixels, depth = self._view_samples()
            origins, dirs = cam0.rays(pixels)
            seen, _ = cam1.project(origins + depth[:, None] * dirs)
            d.append(np.linalg.norm(seen - pixels, axis=-1))
        d = np.concatenate(d)
        d = d[np.isfinite(d)]
        return float(d.max()) if d.size else 0.0

    #: Pixels per side of the grid whose depths sample what a moving camera sees.
    VIEW_SAMPLES = 16

    def _view_samples(self) -> tuple[np.ndarray, np.ndarray]:
        """A grid of pixel centres (K, 2) and the distance along each one's ray to the surface
        it sees in the rest pose (K,); rays that hit nothing see the background, which counts as
        far away (a thousand times the scene's size): it shifts with the camera's turn only."""
        if self._view is None:
            cols = (np.arange(min(self.VIEW_SAMPLES, self.width)) + 0.5) * self.width / min(self.VIEW_SAMPLES, self.width)
            rows = (np.arange(min(self.VIEW_SAMPLES, self.height)) + 0.5) * self.height / min(self.VIEW_SAMPLES, self.height)
            pixels = np.stack(np.meshgrid(cols, rows), axis=-1).reshape(-1, 2)
            use_variant(self._variant)
            origins, dirs = self.camera_model.rays(pixels)
            ray = mi.Ray3f(mi.Point3f(*(origins.T.astype(np.float32))), mi.Vector3f(*(dirs.T.astype(np.float32))))
            depth = np.array(self.scene.ray_intersect(ray).t, dtype=np.float64).ravel()
            bbox = self.scene.bbox()
            size = float(np.linalg.norm(np.array(bbox.max, dtype=np.float64).ravel()
                                        - np.array(bbox.min, dtype=np.float64).ravel()))
            far = 1e3 * max(size, float(np.linalg.norm(self.camera_model.to_world[:3, 3])), 1.0)
            depth = np.where(np.isfinite(depth) & (depth > 0), depth, far)
            self._view = pixels, depth
        return self._view

    def substeps_for(self, step: int) -> int:
        """Renders averaged for step `step` (settings.substeps, or from the motion in pixels)."""
        s = self.settings
        if s.substeps != "auto":
            return int(s.substeps)
        return int(min(s.max_substeps, max(1, math.ceil(self.motion_px(step) / s.blur_threshold_px - 1e-9))))

    # ---- rendering ----------------------------------------------------------------------------
    def _film_tensor(self, step: int, spp: int, stream: int, per_image: bool = False) -> Any:
        """Mean film value over step `step` (electron-weighted radiance; RGB for previews), as a
        Mitsuba tensor (H, W, C) on the render device. `spp` is each sub-step render's samples, or
        with `per_image` the image's, spread over its renders (`samples_per_substep`)."""
        use_variant(self._variant)
        n = self.substeps_for(step)
        each = samples_per_substep(spp, n) if per_image else spp
        acc = None
        for sub in range(n):
            self.animator.apply(self.time_of(step, (sub + 0.5) / n))
            t0 = time.perf_counter()
            img = mi.render(self.scene, spp=each, seed=self.render_seed(stream, step, sub))
            self.stats["render_seconds"] += time.perf_counter() - t0
            self.stats["renders"] += 1
            acc = img if acc is None else acc + img
        return acc if n == 1 else acc / n

    def render_seed(self, stream: int, step: int, sub: int = 0) -> int:
        """The seed of one render: from (seed, stream, step, sub-step), or with step 0's in place of
        the step when settings.step_seeds is "fixed" (the same noise pattern at every step)."""
        return _seed(self.settings.seed, stream, step if self.settings.step_seeds == "fresh" else 0, sub)

    def _film(self, step: int, spp: int, stream: int, per_image: bool = False) -> np.ndarray:
        """The film of `_film_tensor`, copied to the host."""
        return np.array(self._film_tensor(step, spp, stream, per_image), dtype=np.float32)

    def render_step(self, step: int, spp: int | None = None) -> np.ndarray:
        """y at step `step` (float32 (H, W)), with `spp` samples per render (default: settings.spp)."""
        return self._to_y(step, self._film(self._check_step(step), self._spp(spp, self.settings.spp), _FRAMES))

    def render_step_device(self, step: int, spp: int | None = None) -> Any:
        """y at step `step` as a flat Dr.Jit array of H W values (row-major) that stays on the
        render device, for a Simulator on the same device (`settings.device`): no host round
        trip per frame. Non-finite values are left for the sensor kernel to reject (it names
        the frame); checking here would cost a device sync per frame."""
        if self.variant == "rgb":
            raise ValueError("the rgb variant renders previews only (preview_rgb); use 'mono' or 'spectral' for y")
        film = self._film_tensor(self._check_step(step), self._spp(spp, self.settings.spp), _FRAMES)
        channels = film.shape[2]
        values = film.array
        if channels != 1:  # the y channel is the first of each pixel
            values = dr.gather(type(values), values, dr.arange(mi.UInt32, self.height * self.width) * channels)
        if self._gain_device is None:
            self._gain_device = mi.Float(self._gain.ravel())
        return dr.maximum(values * self._gain_device, 0.0)

    def probe_frames(self, step: int, count: int, spp: int = 1) -> np.ndarray:
        """`count` renders of y at step `step` with independent seeds (none of them a frame's or the
        ground truth's), float32 (count, H, W): the Monte Carlo noise of one step, which
        spikesim.quality.monte_carlo_ratio reads."""
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise ValueError(f"count={count!r} must be a positive integer")
        step = self._check_step(step)
        return np.stack([self._to_y(step, self._film(step, spp, _PROBES + i)) for i in range(count)])

    def ground_truth(self, step: int, spp: int | None = None) -> np.ndarray:
        """Ground-truth y at step `step`: the same mean over the readout period, with `spp`
        (default gt_spp) samples per pixel in all, spread over its motion-blur renders."""
        return self._to_y(step, self._film(self._check_step(step), self._spp(spp, self.settings.gt_spp), _GROUND_TRUTH,
                                           per_image=True))

    def frames(self, start_step: int = 0, num_steps: int = 1, keyframe_every: int | None = None,
               device: bool = False) -> Iterator[Any]:
        """Stream y frames for steps start_step .. start_step + num_steps - 1.

        With keyframe_every = k > 1 (default: settings.keyframe_every) only keyframes are rendered: frame j is y at step
        start_step + j k (spikesim.keyframes.keyframe_steps), so the last keyframe reaches or
        passes the last step and the sensor can interpolate every step in between
        (spikesim.simulate.Simulator.run(frames, keyframe_every=k)). With `device=True` the
        frames are Dr.Jit arrays on the render device (`render_step_device`).
        """
        self._check_step(start_step)
        if keyframe_every is None:
            keyframe_every = self.settings.keyframe_every
        if isinstance(num_steps, bool) or not isinstance(num_steps, int) or num_steps < 1:
            raise ValueError(f"num_steps={num_steps!r} must be a positive integer")
        if isinstance(keyframe_every, bool) or not isinstance(keyframe_every, int) or keyframe_every < 1:
            raise ValueError(f"keyframe_every={keyframe_every!r} must be a positive integer")
        render = self.render_step_device if device else self.render_step
        for step in keyframe_steps(start_step, num_steps, keyframe_every):
            yield render(step)
            self.stats["frames"] += 1

    def preview_rgb(self, step: int, spp: int | None = None) -> np.ndarray:
        """Linear RGB (H, W, 3) scaled like y (luminance ~ y), for pictures; needs variant="rgb"."""
        if self.variant != "rgb":
            raise ValueError("preview_rgb needs variant='rgb' (RGB renders are for previews only)")
        return self._film(self._check_step(step), self._spp(spp, self.settings.gt_spp), _PREVIEW,
                          per_image=True) * self._gain[..., None]

    def _to_y(self, step: int, film: np.ndarray) -> np.ndarray:
        if self.variant == "rgb":
            raise ValueError("the rgb variant renders previews only (preview_rgb); use 'mono' or 'spectral' for y")
        y = film[..., 0] * self._gain
        check_frame(self.files.xml, step, y, self.lighting)
        return np.maximum(y, 0.0).astype(np.float32, copy=False)

    @staticmethod
    def _spp(spp: Any, default: int) -> int:
        """A call's samples per pixel: None for the settings', else a positive integer (0 silently took
        the default, -1 was Dr.Jit's own error, 1.5 and "4" were taken; round six)."""
        if spp is None:
            return default
        if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
            raise ValueError(f"spp={spp!r} must be a positive integer (None: the settings' {default})")
        return int(spp)

    @staticmethod
    def _check_step(step: int) -> int:
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 0:
            raise ValueError(f"step={step!r} must be a non-negative integer")
        return int(step)

    # ---- the light at the subject -------------------------------------------------------------
    def metered_illuminance(self) -> MeteredIlluminance | None:
        """The illuminance on the subject's surface, direct and indirect, metered in the scene at
        its rest pose (illuminance_meter.py; light power factor included); None without a subject.
        Measured once, on first use (about 2-5 s on a CPU)."""
        if self.lighting.subject is None:
            return None
        if self._metered is None:
            m = meter_illuminance(self.files.xml, self.lighting, *self.lighting.subject, device=self.device)
            f = self.light_power_factor
            self._metered = dataclasses.replace(m, total_lux=m.total_lux * f, total_se_lux=m.total_se_lux * f,
                                                direct_lux=m.direct_lux * f, direct_se_lux=m.direct_se_lux * f)
            use_variant(self._variant)
        return self._metered

    def subject_illuminance(self) -> tuple[float | None, str]:
        """The illuminance that names this scene's light level (lx), and what it is.

        A light file's subject keeps the figure its lamps were set by: the direct illuminance there,
        computed (inverse-square law and form factors, no occlusion), as a lighting designer states
        it. A subject the camera found (the view centre of a scene without one) is metered: direct
        and indirect light on the surface the camera sees, which is what a light meter held there
        would read, and which is not 0 on a surface lit only by bounced light."""
        if self.lighting.subject is None:
            return None, "none"
        if self.lighting.subject_from == "light file":
            return float(self.lighting.subject_illuminance_lux()) * self.light_power_factor, SUBJECT_DIRECT
        return self.metered_illuminance().total_lux, SUBJECT_METERED

    # ---- reproducibility ----------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        """Every parameter that determines the output, for a dataset's meta.json."""
        light = self.lighting.describe(self.exposure.pixel)
        if self.light_power_factor != 1.0:
            from spikesim.render.lights import scale_light_amounts
            light = {**scale_light_amounts(light, self.light_power_factor),
                     "light_power_factor": self.light_power_factor}
        lux, kind = self.subject_illuminance()
        if "subject" in light:
            if kind == SUBJECT_METERED:  # measured only where it is the scene's figure (a light file's is computed)
                light["subject"] = {**light["subject"], **self.metered_illuminance().describe()}
            light["subject"] = {**light["subject"], "illuminance_lux": lux, "illuminance": kind}
        return {
            "scene": self.files.name,
            "files": {k: str(getattr(self.files, k)) for k in ("xml", "motion", "lights") if getattr(self.files, k)},
            "sha256": self.files.digests(),
            "light": light,
            "motion": self.motion.describe(),
            "render": {**self.settings.to_dict(), "variant_used": self.variant, "height": self.height,
                       "width": self.width, "mitsuba_variant": self._variant, "reconstruction_filter": "box",
                       "time_sampling": "mean over each readout period (sub-step midpoints)"},
            "camera": {"x_fov_deg": self.camera_model.x_fov_deg,
                       "to_world": self.camera_model.to_world.tolist()},
            "exposure": {**self.exposure.to_dict(), "y_per_radiance": self.exposure.y_per_radiance},
            "versions": {"mitsuba": mi.__version__, "drjit": __import__("drjit").__version__},
        }


__all__ = ["SceneRenderer", "RenderSettings", "samples_per_substep", "SUBJECT_DIRECT", "SUBJECT_METERED"]
