"""The speed/accuracy study: measure what each render and sensor knob costs and what it changes
(`spikesim tradeoff` is its command line; a Python script runs it with the same objects).

    spikesim tradeoff --scenes ball fan --light low normal --height 50 --width 80 --windows 3 -o out/tradeoff

Per scene and light: a reference run (a render per step, `--ref-spp` samples, spectral, float64,
every noise term) and one run per knob setting, each changing one knob of the reference: samples
per pixel, fixed keyframes every k steps, adaptive keyframes, mono, each noise term off, float32;
plus the draft and balanced quality presets (spikesim.quality) and the combinations of spp and
adaptive tolerance they were chosen among (COMBOS); and render seeds fixed for every step against
a seed per step at 1-2 spp (the `seeds` knob). For each run: render and simulate
wall time and their ratios to the reference (timed in the same process; a resumed process re-times
8 reference frames and scales the reference by them), and the
error against the reference stream (docs/design.md section 4: each knob's cost and its error against
a high-quality reference). Every run uses the reference's sensor seed and render seed, so the
sensor's temporal noise (Philox keyed by seed, pixel and step) is common to both and the difference
measures the knob; two extra runs give the noise floor: the reference with another sensor seed,
and with another sensor and render seed.

Accuracy downstream (docs/tradeoff.md, "Reconstruction and ground-truth axes"): every run's stream
is also reconstructed, by TFP over 205 steps and by the shipped network, and scored (aligned PSNR,
as `spikesim evaluate`) against the reference's ground truth at the window centres, with its
difference from the reference run's score; and ground truths rendered at fewer samples
(`gt_error_spp`) are compared with the reference's, the ground truth's own error.

Results are cached per run in the output folder (`<out>/runs/<scene>_<light>/<run>.json` + `.npz`,
the reconstruction scores in `<run>.recon.json`, the lower-sample ground truths in `gt_spp=N.json` +
`.npz`), so an interrupted study continues where it stopped; `--report-only` rebuilds the tables and
plot, scoring from the saved streams any run cached before the reconstruction axis existed.
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import logging
import math
import time
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

from spikesim._optional import require
from spikesim.config_io import file_problem, read_json_object
from spikesim.outputs import (atomic_write_file, check_replaceable, check_results_owned, make_dirs, output_folder,
                              results_writing, writable)
from spikesim.preset_rule import RECON_AXES  # the axes the quality presets are chosen on
from spikesim.render_settings import RenderSettings, render_knob

log = logging.getLogger(__name__)

PROBE_FRAMES = 8  # reference frames re-timed in each process that resumes a study
#: 1-spp probe renders (spectral, as the spp runs) each scene-light's Monte Carlo ratio is read from
#: (spikesim.quality.monte_carlo_ratio; the `fast` quality's sample rule stands on it).
MC_PROBES = 4
WINDOW = 41  # the paper's window: 2 * 20 + 1 steps (docs/design.md section 5)
KNOBS = ("spp", "keyframes", "adaptive", "variant", "noise", "precision", "quality", "combos", "seeds")
#: Combined settings the presets were chosen among (spp, adaptive tolerance in px): the fast knobs
#: together (mono when the light has one spectrum, float32, every noise term).
COMBOS = ((4, 0.25), (4, 1.0), (16, 0.25), (16, 0.5), (16, 1.0), (1, 1.0))
DEFAULT_SCENES = ("ball", "car", "cook", "fan", "rotate")
RECON_TFP_WINDOWS = 5
"""The reconstruction axis scores TFP over this many windows (TFP-205: the steps the shipped network
sees per sample, K = 5); a study with fewer windows uses the widest odd number it has."""
RECON_NET = "lrrep"
"""The network the reconstruction axis scores (model.pretrained: the shipped weights)."""
RECON_VERSION = 1
"""Bumped when the reconstruction scoring changes, so cached scores are computed again."""


# ---- configuration ------------------------------------------------------------------------------
#: The study's reference render: spectral, a render per step, 64 spp, ground truth at 256 spp,
#: 50 x 80 pixels (the camera's size too).
REFERENCE_RENDER = RenderSettings(variant="spectral", spp=64, gt_spp=256, resolution=(50, 80))
#: StudyConfig.of's flat names for the reference's render knobs.
_RENDER_ALIASES = {"ref_spp": "spp", "gt_spp": "gt_spp", "seed": "seed", "resolution": "resolution",
                   "device": "device"}


@dataclass(frozen=True)
class StudyConfig:
    """What the study measures and at which size. The reference's render knobs (samples per
    pixel, ground-truth samples, seed, resolution, render device) are one RenderSettings;
    `StudyConfig.of(ref_spp=..., resolution=..., ...)` builds one from flat knobs."""

    scenes: tuple[str, ...] = DEFAULT_SCENES
    """Bundled LLR scene names, or scene XML paths (with their lights.json and motion.json)."""
    lights: tuple[str, ...] = ("low", "normal")
    reference: RenderSettings = REFERENCE_RENDER
    """The reference run's renders; its resolution (height, width) is the camera's too."""
    windows: int = 3
    """41-step windows around the centre of the 861-step LLR sequence (step 430)."""
    backend: str = "auto"
    """The sensor backend."""
    knobs: tuple[str, ...] = KNOBS
    spp_values: tuple[int, ...] = (1, 4, 16)
    keyframe_values: tuple[int, ...] = (2, 4, 8, 16)
    adaptive_px: tuple[float, ...] = (0.25, 0.5, 1.0, 2.0)
    repeats: int = 3
    """Simulation timings: the minimum of this many repeats (a shared machine adds, never removes)."""
    seed_spp_values: tuple[int, ...] = (1, 2)
    """The `seeds` knob: at these samples per pixel, a render seed per step (fresh, as every other
    run) against one seed for every step (fixed)."""
    gt_error_spp: tuple[int, ...] = (16, 64)
    """The ground truth's own error: ground truths rendered at these samples per pixel, at the
    window centres, against the reference's (gt_spp); values >= gt_spp are skipped."""
    threads: int = 0
    """torch CPU threads for scoring the network (0: the free cores, model.threads)."""

    def __post_init__(self) -> None:
        if not self.scenes:
            raise ValueError("scenes: give at least one scene")
        bad = [l for l in self.lights if l not in ("low", "normal")]
        if bad or not self.lights:
            raise ValueError(f"lights={self.lights!r}: expected 'low' and/or 'normal'")
        r = self.reference.resolution
        if r is None or not all(v >= 11 for v in r):
            raise ValueError(f"resolution={r!r} must be (height, width), each >= 11 (SSIM's window)")
        if self.reference.variant != "spectral" or self.reference.keyframe_every != 1:
            raise ValueError("the reference renders spectrally, a frame per step")
        for name in ("windows", "repeats"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name}={v!r} must be a positive integer")
        if self.windows > 21:
            raise ValueError(f"windows={self.windows} exceeds the 21 windows of an LLR sequence")
        unknown = sorted(set(self.knobs) - set(KNOBS))
        if unknown:
            raise ValueError(f"unknown knob(s) {unknown}; known: {list(KNOBS)}")
        if any(s < 1 for s in self.spp_values) or any(k < 2 for k in self.keyframe_values):
            raise ValueError("spp_values must be >= 1 and keyframe_values >= 2")
        for name in ("seed_spp_values", "gt_error_spp"):
            v = getattr(self, name)
            if any(isinstance(s, bool) or not isinstance(s, int) or s < 1 for s in v):
                raise ValueError(f"{name}={v!r} must be positive integers")
        if isinstance(self.threads, bool) or not isinstance(self.threads, int) or self.threads < 0:
            raise ValueError(f"threads={self.threads!r} must be >= 0 (0: the free cores)")
        if any(not (p > 0) for p in self.adaptive_px):
            raise ValueError(f"adaptive_px={self.adaptive_px!r} must be positive")

    @classmethod
    def of(cls, **knobs: Any) -> "StudyConfig":
        """A config from flat knobs: ref_spp, gt_spp, seed, resolution and device set the
        reference's RenderSettings, the rest the config itself."""
        render = {_RENDER_ALIASES[k]: knobs.pop(k) for k in list(knobs) if k in _RENDER_ALIASES}
        return cls(reference=REFERENCE_RENDER.replace(**render), **knobs)

    resolution = render_knob("resolution", "reference")  # (height, width) of the camera and the renders
    ref_spp = render_knob("spp", "reference")
    gt_spp = render_knob("gt_spp", "reference")
    seed = render_knob("seed", "reference")
    device = render_knob("device", "reference")  # where Mitsuba renders

    @property
    def start(self) -> int:
        """First step: the windows are centred on the LLR sequence's centre window (index 10)."""
        return WINDOW * (10 - self.windows // 2)

    @property
    def num_steps(self) -> int:
        return WINDOW * self.windows

    def centres(self) -> list[int]:
        return [self.start + i * WINDOW + WINDOW // 2 for i in range(self.windows)]

    @property
    def tfp_span(self) -> int:
        """Steps of the reconstruction axis's TFP: RECON_TFP_WINDOWS windows (205 steps), or the
        largest odd number of windows the study has when it has fewer."""
        n = min(self.windows, RECON_TFP_WINDOWS)
        return WINDOW * (n if n % 2 else n - 1)

    def gt_error_values(self) -> list[int]:
        """The lower sample counts of the ground-truth error axis (those below gt_spp, ascending)."""
        return sorted({s for s in self.gt_error_spp if s < self.gt_spp})

    def result_key(self) -> dict[str, Any]:
        """The fields a cached run depends on."""
        return {"resolution": list(self.resolution), "windows": self.windows, "ref_spp": self.ref_spp,
                "gt_spp": self.gt_spp, "seed": self.seed}


@dataclass(frozen=True)
class RunSpec:
    """One run: the reference with one knob changed (or a quality preset)."""

    name: str
    knob: str
    settings: Any  # spikesim.quality.QualitySettings
    off_terms: tuple[str, ...] = ()
    sensor_seed: int = 0
    render_seed: int = 0
    """Seeds of the sensor (fixed patterns, temporal noise) and of the renders."""

    def to_dict(self) -> dict[str, Any]:
        d = {"name": self.name, "knob": self.knob, "settings": self.settings.to_dict(),
             "off_terms": list(self.off_terms), "sensor_seed": self.sensor_seed, "render_seed": self.render_seed}
        if self.step_seeds != "fresh":  # only then: runs cached before the knob keep their keys
            d["step_seeds"] = self.step_seeds
        return d

    @property
    def step_seeds(self) -> str:
        """"fresh" (a render seed per step) or "fixed" (one for every step): RenderSettings.step_seeds."""
        return self.settings.render.step_seeds


def plan_runs(cfg: StudyConfig) -> list[RunSpec]:
    """The reference, the noise floor and every knob setting the config asks for."""
    from spikesim.camera import NOISE_TERMS
    from spikesim.quality import PRESETS, QualitySettings

    ref = QualitySettings("reference", cfg.reference, keyframe_policy="every", noise="all", precision="float64")
    s0, s1 = cfg.seed, cfg.seed + 1

    def run(name: str, knob: str, settings: Any, off: tuple[str, ...] = (), sensor: int = s0,
            render: int = s0) -> RunSpec:
        return RunSpec(name, knob, settings, off_terms=off, sensor_seed=sensor, render_seed=render)

    runs = [run("reference", "reference", ref),
            run("floor: sensor seed", "floor", ref, sensor=s1),
            run("floor: sensor+render seed", "floor", ref, sensor=s1, render=s1)]
    if "spp" in cfg.knobs:
        runs += [run(f"spp={s}", "spp", ref.replace(spp=s)) for s in cfg.spp_values if s != cfg.ref_spp]
    if "keyframes" in cfg.knobs:
        runs += [run(f"k={k}", "keyframes", ref.replace(keyframe_policy="fixed", keyframe_every=k))
                 for k in cfg.keyframe_values]
    if "adaptive" in cfg.knobs:
        runs += [run(f"adaptive {p:g}px", "adaptive", ref.replace(keyframe_policy="adaptive", max_px_per_keyframe=p))
                 for p in cfg.adaptive_px]
    if "variant" in cfg.knobs:
        runs.append(run("mono", "variant", ref.replace(variant="mono")))
    if "noise" in cfg.knobs:
        runs += [run(f"-{t}", "noise", ref, off=(t,)) for t in NOISE_TERMS]
    if "precision" in cfg.knobs:
        runs.append(run("float32", "precision", ref.replace(precision="float32")))
    if "quality" in cfg.knobs:
        runs += [run(f"quality={n}", "quality", PRESETS[n]) for n in ("balanced", "draft")]
    if "combos" in cfg.knobs:
        combo = QualitySettings.of("combo", spp=1, gt_spp=cfg.gt_spp, variant="auto", keyframe_policy="adaptive",
                                noise="all", precision="float32")
        runs += [run(f"spp={n} adaptive {p:g}px", "combos", combo.replace(spp=n, max_px_per_keyframe=p))
                 for n, p in COMBOS]
    if "seeds" in cfg.knobs:  # fresh (the spp knob's run where it has one) against fixed render seeds
        names = {r.name for r in runs}
        for n in cfg.seed_spp_values:
            if f"spp={n}" not in names and n != cfg.ref_spp:
                runs.append(run(f"spp={n}", "seeds", ref.replace(spp=n)))
            runs.append(run(f"fixed seed spp={n}", "seeds", ref.replace(spp=n, step_seeds="fixed")))
    return runs


# ---- measuring one run --------------------------------------------------------------------------
class _TimedRenderer:
    """Wraps a SceneRenderer: times render_step and motion_px (both count as render cost), records
    every keyframe it produced, and renders each (step, spp) once."""

    def __init__(self, renderer: Any):
        self.r = renderer
        self.seconds = 0.0
        self.frames: dict[int, np.ndarray] = {}
        self._spp: int | None = None

    def render_step(self, step: int, spp: int | None = None) -> np.ndarray:
        if step in self.frames and spp == self._spp:
            return self.frames[step]
        t0 = time.perf_counter()
        y = self.r.render_step(step, spp=spp)
        self.seconds += time.perf_counter() - t0
        self.frames[step], self._spp = y, spp
        return y

    def motion_px(self, step: int) -> float:
        t0 = time.perf_counter()
        m = self.r.motion_px(step)
        self.seconds += time.perf_counter() - t0
        return m


class _Replay:
    """A renderer that returns frames already rendered (to re-time the simulation, or to reuse the
    reference's frames for runs that change only the sensor)."""

    def __init__(self, frames: dict[int, np.ndarray], motion: dict[int, float] | None = None,
                 source: Any = None):
        self.frames, self.motion, self.source = frames, motion or {}, source

    def render_step(self, step: int, spp: int | None = None) -> np.ndarray:
        return self.frames[step]

    def motion_px(self, step: int) -> float:
        if step not in self.motion:
            self.motion[step] = self.source.motion_px(step)
        return self.motion[step]


def interpolate_at(keyframes: dict[int, np.ndarray], step: int) -> np.ndarray:
    """y at `step` as the sensor sees it: linear between the keyframes around it (sensor.md)."""
    steps = sorted(keyframes)
    if step in keyframes:
        return keyframes[step]
    i = int(np.searchsorted(steps, step))
    if i == 0 or i == len(steps):
        raise ValueError(f"step {step} lies outside the keyframes {steps[0]}..{steps[-1]}")
    a, b = steps[i - 1], steps[i]
    w = (step - a) / (b - a)
    return (keyframes[a].astype(np.float64) * (1 - w) + keyframes[b] * w).astype(np.float32)


class SceneStudy:
    """All runs of one scene under one light, sharing loaded renderers and the reference frames."""

    def __init__(self, cfg: StudyConfig, scene: str, light: str, folder: Path):
        self.cfg, self.scene, self.light, self.folder = cfg, scene, light, folder
        self._renderers: dict[tuple[str, int, str], Any] = {}
        self._ref_frames: dict[int, np.ndarray] | None = None
        self._probe: float | None = None
        self._scene_key: dict[str, Any] | None = None
        self._warned_frames = False

    # renderers are loaded once per (variant, seed, step seeds) and warmed (the first render compiles)
    def renderer(self, variant: str, seed: int, step_seeds: str = "fresh") -> Any:
        key = (variant, seed, step_seeds)
        if key not in self._renderers:
            from spikesim.render import SceneRenderer
            r = SceneRenderer(self.scene, light=self.light, variant=variant, seed=seed, step_seeds=step_seeds,
                              settings=self.cfg.reference)
            r.render_step(self.cfg.start, spp=1)
            self._renderers[key] = r
        return self._renderers[key]

    def reference_frame_s(self) -> float:
        """Seconds per reference frame render in this process: `PROBE_FRAMES` steps rendered with
        the reference's settings, so runs resumed in a later process compare with a reference
        timed under the same machine load."""
        if self._probe is None:
            r = self.renderer("spectral", self.cfg.seed)
            steps = range(self.cfg.start, self.cfg.start + min(PROBE_FRAMES, self.cfg.num_steps))
            t0 = time.perf_counter()
            for step in steps:
                r.render_step(step, spp=self.cfg.ref_spp)
            self._probe = (time.perf_counter() - t0) / len(steps)
        return self._probe

    def monte_carlo_probe(self) -> dict[str, Any]:
        """The Monte Carlo ratio of the study's first step: MC_PROBES spectral 1-spp renders (the
        spp runs' variant) with seeds of their own."""
        from spikesim.quality import monte_carlo_ratio
        probes = self.renderer("spectral", self.cfg.seed).probe_frames(self.cfg.start, MC_PROBES, spp=1)
        ratio = monte_carlo_ratio(probes, self.base_camera().threshold_electrons)
        log.info("%s %s: Monte Carlo ratio %.3g (%d probes)", self.scene, self.light, ratio, MC_PROBES)
        return {"mc_ratio": ratio, "probes": MC_PROBES, "y_mean": float(probes.mean())}

    def base_camera(self) -> Any:
        from spikesim.camera import SpikeCamera
        h, w = self.cfg.resolution
        return SpikeCamera.realistic(height=h, width=w)

    def scene_key(self) -> dict[str, Any]:
        """`_scene_key` of this scene and light, its files hashed once per study."""
        if self._scene_key is None:
            self._scene_key = _scene_key(self.cfg, self.scene, self.light)
        return self._scene_key

    def reference_key(self) -> str:
        """The cache key of this scene and light's reference run (`_run_key`), for its frames."""
        return _run_key(self.scene_key(), plan_runs(self.cfg)[0])

    def reference_frames(self) -> dict[int, np.ndarray]:
        if self._ref_frames is None:
            data = _load_npz(self.folder / "reference_frames.npz", "steps", "frames")
            self._ref_frames = {int(s): f for s, f in zip(data["steps"], data["frames"])}
        return self._ref_frames

    def _frames_current(self) -> bool:
        """Whether the cached reference frames are this study's: a study with other inputs stopped
        while its reference's ground truth rendered left its own frames under this reference's
        record, and the runs that reuse them simulated the other study's light, rc 0 (round
        eighteen). Frames without this key (or damaged) are not reused: the run renders them."""
        if self._ref_frames is not None:
            return True
        path = self.folder / "reference_frames.npz"
        current = _npz_key(path) == self.reference_key()
        if current:
            try:  # the key intact, its frames damaged: rendered again too (round nineteen)
                self.reference_frames()
            except ValueError:
                current = False
        if not current and not self._warned_frames:
            self._warned_frames = True
            log.warning("%s: cached for another study (or damaged); the runs that would reuse the reference's "
                        "frames render them again", path)
        return current

    def _reuses_reference(self, spec: RunSpec) -> bool:
        s = spec.settings
        return (spec.knob != "reference" and s.keyframe_policy == "every" and s.spp == self.cfg.ref_spp
                and s.variant == "spectral" and spec.render_seed == self.cfg.seed and spec.step_seeds == "fresh"
                and self._frames_current())

    def run(self, spec: RunSpec) -> dict[str, Any]:
        """Render (or reuse), simulate, time; returns the row's timing fields and saves the stream."""
        from spikesim.simulate import Simulator
        from spikesim.stream import SpikeStream

        cfg, s = self.cfg, spec.settings
        run_key = _run_key(self.scene_key(), spec)  # in each of its files (_save_npz)
        if self._reuses_reference(spec):
            ref_row = _read_json(self.folder / "reference.json")
            source: Any = _Replay(self.reference_frames())
            render_s, reused = ref_row["render_s"], True
        else:
            source = _TimedRenderer(self.renderer(s.variant, spec.render_seed, spec.step_seeds))
            render_s, reused = None, False
        variant_used = getattr(getattr(source, "r", None), "variant", "spectral")
        base = self.base_camera()
        y_levels = None
        if s.noise == "auto":  # the light levels of the first frame decide the noise terms
            y_levels = np.percentile(source.render_step(cfg.start, spp=s.spp), [5, 50, 95])
        camera, decisions = s.camera(base, y_levels)
        if spec.off_terms:
            camera = camera.without(*spec.off_terms)
        t0 = time.perf_counter()
        sim = Simulator(camera, backend=cfg.backend, seed=spec.sensor_seed)
        stream = SpikeStream.concatenate(list(s.simulate(sim, source, cfg.start, cfg.num_steps)))
        wall = time.perf_counter() - t0
        if stream.num_steps != cfg.num_steps:
            raise RuntimeError(f"{spec.name}: simulated {stream.num_steps} steps, expected {cfg.num_steps}")
        keyframes = dict(source.frames)
        if not reused:
            render_s = source.seconds
        # the simulation alone, re-timed from the recorded keyframes (minimum of repeats)
        replay = _Replay(keyframes, source=source)
        sim_times = []
        for _ in range(cfg.repeats):
            t1 = time.perf_counter()
            again = SpikeStream.concatenate(list(s.simulate(Simulator(camera, backend=cfg.backend,
                                                                      seed=spec.sensor_seed),
                                                            replay, cfg.start, cfg.num_steps)))
            sim_times.append(time.perf_counter() - t1)
        if again != stream:
            raise RuntimeError(f"{spec.name}: re-simulating the recorded keyframes gave another stream")
        sim_s = min(sim_times)
        if s.keyframe_policy == "adaptive":  # static keyframes reuse a frame without rendering it
            keyframes = dict(s.keyframes(replay, cfg.start, cfg.num_steps))
        y_centres = np.stack([interpolate_at(keyframes, c) for c in cfg.centres()])
        extra: dict[str, np.ndarray] = {}
        timing: dict[str, float] = {}  # the reference's: its ground truth's render seconds too
        if spec.knob == "reference":
            steps = sorted(keyframes)
            _save_npz(self.folder / "reference_frames.npz", run_key, steps=np.array(steps),  # _frames_current
                      frames=np.stack([keyframes[k] for k in steps]))
            self._ref_frames = keyframes
            r = self.renderer("spectral", cfg.seed)
            t2 = time.perf_counter()
            extra["gt"] = np.stack([r.ground_truth(c, spp=cfg.gt_spp) for c in cfg.centres()])
            timing["gt_render_s"] = time.perf_counter() - t2
            log.info("%s %s: ground truth at %d centres (%d spp) in %.1f s", self.scene, self.light,
                     len(cfg.centres()), cfg.gt_spp, timing["gt_render_s"])
        if spec.knob == "reference":
            self._probe = render_s / cfg.num_steps
        _save_npz(self.folder / f"{_slug(spec.name)}.npz", run_key, packed=stream.packed, y_centres=y_centres, **extra)
        return {**timing, "render_s": float(render_s), "render_reused": reused, "simulate_s": float(sim_s),
                "ref_frame_s": self.reference_frame_s(),
                "first_pass_s": float(wall), "renders": len(source.frames) if not reused else cfg.num_steps,
                "keyframes": len(keyframes), "variant_used": variant_used, "camera": camera.to_dict(),
                "noise_decisions": [d.to_dict() for d in decisions], "backend": sim.backend_name}

    def render_ground_truth(self, spp: int) -> tuple[np.ndarray, float]:
        """Ground truth at the window centres with `spp` samples (the ground-truth error axis) and its
        render seconds. Rendered with the render seed + 1 (the floor run's renderer), so its Monte
        Carlo samples are independent of the reference ground truth's."""
        r = self.renderer("spectral", self.cfg.seed + 1)
        t0 = time.perf_counter()
        gt = np.stack([r.ground_truth(c, spp=spp) for c in self.cfg.centres()])
        return gt, time.perf_counter() - t0


def scene_label(scene: str) -> str:
    """How a studied scene is named in folders and tables: a bundled scene by its name, a scene XML
    (`tradeoff --xml`) by its folder, as `sweep` names it."""
    return Path(scene).parent.name if scene.lower().endswith(".xml") else scene


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "=.-" else "_" for c in name)


# ---- errors against the reference -----------------------------------------------------------------
def rel_rmse(x: np.ndarray, ref: np.ndarray) -> float:
    """sqrt(mean((x - ref)^2)) / mean(ref), as spikesim.render.benchmark.rel_rmse."""
    return float(np.sqrt(np.mean((np.asarray(x, np.float64) - ref) ** 2)) / max(float(np.mean(ref)), 1e-30))


def stream_metrics(packed: np.ndarray, ref_packed: np.ndarray, cfg: StudyConfig) -> dict[str, float]:
    """Firing-rate error, ISI distance and TFP PSNR/SSIM of a run's stream against the reference's."""
    import torch
    from scipy.stats import wasserstein_distance

    from model.metrics import psnr, ssim
    from model.representations import tfp_windows
    from spikesim.stats import firing_rate, inter_spike_intervals
    from spikesim.stream import SpikeStream

    h, w = cfg.resolution
    run, ref = SpikeStream(packed, h, w), SpikeStream(ref_packed, h, w)
    rate, rate_ref = firing_rate(run), firing_rate(ref)
    isi, isi_ref = inter_spike_intervals(run), inter_spike_intervals(ref)
    # Wasserstein-1 between the pooled ISI distributions (scipy; Villani 2009 for W1 on the line),
    # relative to the reference's mean ISI so that low and normal light compare
    if isi.size and isi_ref.size:
        isi_w1 = float(wasserstein_distance(isi, isi_ref) / isi_ref.mean())
    else:
        isi_w1 = float("nan")
    def tfps(s: SpikeStream) -> np.ndarray:
        b = torch.from_numpy(s.unpack()).reshape(cfg.windows, WINDOW, h, w)
        return tfp_windows(b).numpy()
    t, t_ref = tfps(run), tfps(ref)
    psnrs = [psnr(a, b) for a, b in zip(t, t_ref)]
    return {"rate_err": rel_rmse(rate, rate_ref), "rate_bias": float(rate.mean() / max(rate_ref.mean(), 1e-30) - 1),
            "isi_w1": isi_w1, "tfp_err": rel_rmse(t, t_ref),
            "tfp_psnr": float(np.mean(psnrs)) if all(map(math.isfinite, psnrs)) else float("inf"),
            "tfp_ssim": float(np.mean([ssim(a, b) for a, b in zip(t, t_ref)]))}


# ---- reconstruction against the reference's ground truth ------------------------------------------
_NETS: dict[str, Any] = {}


def recon_network(name: str = RECON_NET) -> Any:
    """The shipped network `name` as an evaluate method (model.methods), on the CPU, loaded once per
    process."""
    if name not in _NETS:
        from model.methods import method_from_spec
        _NETS[name] = method_from_spec(name, WINDOW, device="cpu")
    return _NETS[name]


def net_windows(name: str = RECON_NET) -> int:
    """K, the windows of context the network saw per training sample: it is scored only where the
    study has that many."""
    return int(recon_network(name).experiment.train.num_windows)


def _net_label(name: str = RECON_NET) -> str:
    from model.methods import pretrained_label
    return pretrained_label(name)


def recon_scores(packed: np.ndarray, gt: np.ndarray, cfg: StudyConfig, net: str = RECON_NET) -> dict[str, Any]:
    """Aligned PSNR (model.metrics.psnr_aligned, the score of `spikesim evaluate`) of two
    reconstructions of a run's stream against `gt`, the reference's ground truth at the window
    centres (windows, H, W), clipped at saturation as evaluate clips it; the mean over the windows:

    - TFP over cfg.tfp_span steps centred on each window centre (model.methods' `tfp:N`: near the
      ends of the study's stream it averages the windows within reach, as evaluate does);
    - the shipped network (`net`, model.pretrained) over the study's windows as one sequence, on the
      CPU with model.threads' thread count, where the study has its K windows; NaN otherwise.

    `recon_note` says where either departs from TFP-205 / a scored network."""
    import torch

    from model.methods import method_from_spec
    from model.metrics import psnr_aligned
    from model.streaming import TensorWindows
    from model.threads import set_cpu_threads
    from spikesim.dataset import SATURATION_Y
    from spikesim.stream import SpikeStream

    h, w = cfg.resolution
    spikes = SpikeStream(packed, h, w).unpack()
    if spikes.shape[0] != cfg.num_steps:
        raise ValueError(f"a stream of {spikes.shape[0]} steps; the study has {cfg.num_steps}")
    gts = np.clip(np.asarray(gt, dtype=np.float32), 0.0, SATURATION_Y)
    if gts.shape != (cfg.windows, h, w):
        raise ValueError(f"ground truth of shape {gts.shape}; expected {(cfg.windows, h, w)}")
    source = TensorWindows(torch.from_numpy(spikes != 0).reshape(cfg.windows, WINDOW, h, w))

    def score(method: Any) -> list[float]:
        with torch.no_grad():
            return [psnr_aligned(np.asarray(f, dtype=np.float32), gts[i]) for i, f in method.frames(source)]

    span, notes = cfg.tfp_span, []
    if span < WINDOW * RECON_TFP_WINDOWS:
        notes.append(f"TFP-{span}: {cfg.windows} window(s) allow no wider odd span "
                     f"(TFP-{WINDOW * RECON_TFP_WINDOWS} needs {RECON_TFP_WINDOWS})")
    tfp = score(method_from_spec(f"tfp:{span}", WINDOW))
    k = net_windows(net)
    if cfg.windows >= k:
        set_cpu_threads(cfg.threads)
        nets = score(recon_network(net))
    else:
        nets = []
        notes.append(f"{_net_label(net)} not scored: it needs {k} windows of context (K), the study has {cfg.windows}")
    return {"recon_tfp_span": span, "tfp_gt_psnr": float(np.mean(tfp)), "tfp_gt_psnr_frames": tfp,
            "net_gt_psnr": float(np.mean(nets)) if nets else math.nan, "net_gt_psnr_frames": nets,
            "recon_note": "; ".join(notes)}


_RECON_FLOATS = ("tfp_gt_psnr", "net_gt_psnr")


def _score_number(value: Any) -> float:
    """A cached PSNR: a JSON number, or "nan", "inf", "-inf" (the cache's writer, _jsonable, writes a
    non-finite value so); any other string, a bool or null is damage."""
    if value in ("nan", "inf", "-inf"):
        return float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{value!r:.40} is not a number")
    return float(value)


def cached_recon_scores(folder: Path, name: str, run_key: str, ref_key: str, packed: np.ndarray, gt: np.ndarray,
                        cfg: StudyConfig) -> dict[str, Any]:
    """recon_scores of run `name`, cached beside its stream as `<run>.recon.json`, keyed by the run's
    and the reference's cache keys, the span, the network's weights and RECON_VERSION: computed
    again only when one of those changes (runs measured before this axis existed get it here,
    without rendering). A folder that cannot be written to is warned about, not fatal."""
    from model.pretrained import PRETRAINED

    path = folder / f"{_slug(name)}.recon.json"
    key = _digest({"run": run_key, "reference": ref_key, "version": RECON_VERSION, "tfp_span": cfg.tfp_span,
                   "net": RECON_NET, "weights": PRETRAINED[RECON_NET].weights_sha256, "windows": cfg.windows})
    if path.exists():
        try:
            cached = _read_json(path)
        except ValueError as exc:
            log.warning("%s", exc)
        else:
            if cached.get("key") == key:
                try:  # an edited value ("abc", 5 for a list, a missing field) is damage, scored again (round 21)
                    for k in _RECON_FLOATS:
                        cached[k] = _score_number(cached[k])
                    for k in ("tfp_gt_psnr_frames", "net_gt_psnr_frames"):
                        if not isinstance(cached[k], list):
                            raise TypeError(f"{k} is not a list")
                        cached[k] = [_score_number(v) for v in cached[k]]
                except (KeyError, TypeError, ValueError) as exc:
                    log.warning("%s: damaged cache file (%s); the reconstructions are scored again", path, exc)
                else:
                    return cached
    scores = recon_scores(packed, gt, cfg)
    try:
        _write_json(path, {"key": key, **scores})
    except OSError as exc:
        log.warning("%s: reconstruction scores not cached (%s)", path, exc)
    return scores


# ---- the ground truth's own error ---------------------------------------------------------------------
def _gt_name(spp: int) -> str:
    return f"gt_spp={spp}"


def scene_identity(scene: str) -> dict[str, str]:
    """What the scene is made from, by content: its XML, motion and light files and every file the
    XML references, each by sha256 (as `generate` keys its jobs). In every cache key, so a study of
    a user's scene edited since its last run measures it again: the key held only the path as typed,
    and a rerun reported the old scene's figures, rc 0 (round sixteen)."""
    from spikesim.generation.inputs import identities, scene_file_inputs
    return identities(scene_file_inputs(scene))


def _scene_key(cfg: StudyConfig, scene: str, light: str) -> dict[str, Any]:
    """The part of every cache key that names the scene and its lighting."""
    return {**cfg.result_key(), "scene": scene, "scene_inputs": scene_identity(scene), "light": light}


def _gt_key(cfg: StudyConfig, scene: str, light: str, spp: int) -> str:
    return _digest({**_scene_key(cfg, scene, light), "gt_error_spp": spp, "render_seed": cfg.seed + 1})


def gt_error(gt: np.ndarray, ref_gt: np.ndarray) -> dict[str, float]:
    """A ground truth's error against the reference's, both (windows, H, W): relative RMS (as
    gt_err: mean over the centres) and aligned PSNR (as the reconstruction axis, both clipped at
    saturation)."""
    from model.metrics import psnr_aligned
    from spikesim.dataset import SATURATION_Y

    g, r = (np.clip(np.asarray(a, np.float64), 0.0, SATURATION_Y) for a in (gt, ref_gt))
    return {"gt_self_err": float(np.mean([rel_rmse(a, b) for a, b in zip(gt, ref_gt)])),
            "gt_self_psnr": float(np.mean([psnr_aligned(a, b) for a, b in zip(g, r)]))}


def _reference_folders(cfg: StudyConfig, out: Path) -> Iterator[tuple[str, str, Path, dict[str, Any]]]:
    """(scene, light, folder, reference row) of every scene and light whose reference is cached."""
    for scene in cfg.scenes:
        for light in cfg.lights:
            folder = out / "runs" / f"{scene_label(scene)}_{light}"
            if (folder / "reference.json").exists():
                yield scene, light, folder, _read_json(folder / "reference.json")


def _run_key(scene_key: dict[str, Any], spec: RunSpec) -> str:
    """The cache key of run `spec` of the scene and light whose `_scene_key` is `scene_key`."""
    return _digest({**scene_key, **spec.to_dict()})


def _check_current(path: Path, row: dict[str, Any], key: str) -> None:
    """A cached run read for the report must be the one these options and scene files make: a
    `--report-only` after the scene, the seed or the size changed reported the old study's figures,
    rc 0, or failed on the old size's streams (round seventeen)."""
    if row.get("key") != key:
        raise ValueError(f"{path}: cached for another scene, seed or size (not what these options and the scene's "
                         "files make now); run the study without --report-only to measure it again")


def collect_gt_rows(cfg: StudyConfig, out: Path) -> list[dict[str, Any]]:
    """The ground-truth error axis, per scene and light: the reference's ground truth (gt_spp, error
    0 by definition) and each cached lower-sample one (cfg.gt_error_values()) against it, with
    render seconds per frame and their ratio to the reference ground truth's. `gt_ref_err_est`
    estimates the reference ground truth's own relative error from it: the two are independent
    Monte Carlo estimates whose variances go as 1/spp, so err_ref = err * sqrt(s / (s + gt_spp))."""
    rows = []
    reference = plan_runs(cfg)[0]
    for scene, light, folder, ref in _reference_folders(cfg, out):
        ref_key = _run_key(_scene_key(cfg, scene, light), reference)
        ref_gt = _load_npz(folder / "reference.npz", "gt")["gt"]  # damaged: named first
        _check_current(folder / "reference.json", ref, ref_key)
        _check_npz_key(folder / "reference.npz", ref_key)
        ref_frame_s = float(ref.get("gt_render_s", math.nan)) / cfg.windows  # NaN: measured before it was kept
        timed = ref_frame_s * cfg.windows >= MIN_TIMED_S
        block = [{"scene": scene_label(scene), "light": light, "run": f"gt spp={cfg.gt_spp}", "knob": "gt",
                  "gt_spp": cfg.gt_spp, "gt_frame_s": ref_frame_s, "gt_time_ratio": _ratio(ref_frame_s, ref_frame_s, timed),
                  "gt_self_err": 0.0, "gt_self_psnr": math.inf, "gt_ref_err_est": math.nan}]
        for spp in cfg.gt_error_values():
            path = folder / f"{_gt_name(spp)}.json"
            if not _is_cached(path, folder / f"{_gt_name(spp)}.npz", _gt_key(cfg, scene, light, spp)):
                log.warning("%s: no ground truth at %d spp cached; run the study again (it renders only "
                            "those)", folder, spp)
                continue
            row = _read_json(path)
            gt = _load_npz(folder / f"{_gt_name(spp)}.npz", "gt")["gt"]  # its key: _is_cached above
            err = gt_error(gt, ref_gt)
            frame_s = float(row["gt_render_s"]) / cfg.windows
            block.append({"scene": scene_label(scene), "light": light, "run": f"gt spp={spp}", "knob": "gt", "gt_spp": spp,
                          "gt_frame_s": frame_s, "gt_time_ratio": _ratio(frame_s, ref_frame_s, timed), **err,
                          "gt_ref_err_est": err["gt_self_err"] * math.sqrt(spp / (spp + cfg.gt_spp))})
        front = pareto_front([(r["gt_frame_s"] if timed else math.nan, r["gt_self_err"]) for r in block])
        for r, f in zip(block, front):
            r["pareto_gt"] = f
        rows += block
    return rows


#: The reference run's time (render and sensor, s) below which the study gives no ratios of time:
#: a render's time varies by 10-30 ms from one call to the next on the 2-core machine (more when
#: it is shared), so a reference of a few ms gave speed-ups of inf and a Pareto front drawn out of
#: that noise (issue 40); at 0.25 s the noise is at most about 10 % of the reference.
MIN_TIMED_S = 0.25


def _ratio(a: float, b: float, timed: bool = True) -> float:
    """a / b where both are times worth dividing, else NaN (shown as n/a, never on a front)."""
    return a / b if timed and b > 0 and math.isfinite(a) and math.isfinite(b) else math.nan


def pareto_front(points: Sequence[tuple[float, float]]) -> list[bool]:
    """Which (cost, error) points no other point dominates (<= in both, < in one); NaN never is."""
    out = []
    for i, (c, e) in enumerate(points):
        if not (math.isfinite(c) and math.isfinite(e)):
            out.append(False)
            continue
        dominated = any(j != i and math.isfinite(c2) and math.isfinite(e2) and c2 <= c and e2 <= e
                        and (c2 < c or e2 < e) for j, (c2, e2) in enumerate(points))
        out.append(not dominated)
    return out


# ---- the study ------------------------------------------------------------------------------------
def run_study(cfg: StudyConfig, out: Path, progress: bool = True) -> list[dict[str, Any]]:
    """Run (or resume) every scene x light x run; returns the table rows."""
    from spikesim.progress import progress_bar

    for name in ("study.json", "runs", *REPORT_FILES):  # a link where the study writes: refused before any run
        writable(out, name)
    # a user's study.json or tradeoff.md there was replaced (round ten): refused before any run
    check_results_owned(out, ["study.json", *REPORT_FILES], "tradeoff")
    out.mkdir(parents=True, exist_ok=True)
    with results_writing(out, ["study.json"], "tradeoff"):  # recorded at once: an interrupted study resumes as its own
        _write_json(out / "study.json", dataclasses.asdict(cfg))
    runs = plan_runs(cfg)
    jobs = [(sc, li, r) for sc in cfg.scenes for li in cfg.lights for r in runs]
    session = f"{time.time():.0f}"
    studies: dict[tuple[str, str], SceneStudy] = {}
    bar = progress_bar(jobs, desc="tradeoff", unit="run", quiet=not progress)
    for scene, light, spec in bar:
        folder = out / "runs" / f"{scene_label(scene)}_{light}"
        make_dirs(out, "runs", f"{scene_label(scene)}_{light}")  # inside -o, no link on the way
        path = folder / f"{_slug(spec.name)}.json"
        key = _run_key(_scene_key(cfg, scene, light), spec)
        if _is_cached(path, folder / f"{_slug(spec.name)}.npz", key):
            log.debug("%s %s %s: cached", scene, light, spec.name)
            continue
        bar.set_postfix_str(f"{scene_label(scene)}/{light} {spec.name}")
        study = studies.setdefault((scene, light), SceneStudy(cfg, scene, light, folder))
        if spec.knob != "reference" and not (folder / "reference.json").exists():
            raise RuntimeError(f"{folder}: the reference run is missing; it runs first")
        t0 = time.perf_counter()
        row = study.run(spec)
        row.update({"key": key, "session": session, "scene": scene_label(scene), "light": light, **spec.to_dict()})
        _write_json(path, row)
        log.info("%s %s %-28s render %.2f s simulate %.3f s (%.1f s)", scene, light, spec.name, row["render_s"],
                 row["simulate_s"], time.perf_counter() - t0)
        if spec.knob == "reference":
            _write_json(folder / "reference.json", row)
    for scene in cfg.scenes:  # the ground truth's own error: lower-sample ground truths, cached each
        for light in cfg.lights:
            folder = out / "runs" / f"{scene_label(scene)}_{light}"
            for spp in cfg.gt_error_values():
                path, npz = folder / f"{_gt_name(spp)}.json", folder / f"{_gt_name(spp)}.npz"
                key = _gt_key(cfg, scene, light, spp)
                if _is_cached(path, npz, key):
                    continue
                study = studies.setdefault((scene, light), SceneStudy(cfg, scene, light, folder))
                gt, seconds = study.render_ground_truth(spp)
                _save_npz(npz, key, gt=gt)
                _write_json(path, {"key": key, "session": session, "gt_spp": spp, "gt_render_s": seconds,
                                   "render_seed": cfg.seed + 1, "centres": cfg.centres()})
                log.info("%s %s: ground truth at %d spp in %.1f s", scene, light, spp, seconds)
    for scene, light, folder, _ in list(_reference_folders(cfg, out)):  # each scene-light's Monte Carlo ratio
        path = _cache_slot(folder / "mc_probe.json")
        key = _mc_key(cfg, scene, light)
        if _probe_of(path, key) is not None:
            continue
        study = studies.setdefault((scene, light), SceneStudy(cfg, scene, light, folder))
        _write_json(path, {"key": key, "session": session, **study.monte_carlo_probe()})
    for st in studies.values():  # release Mitsuba scenes before the report
        st._renderers.clear()
    return collect_rows(cfg, out, runs)


def _probe_of(path: Path, key: str) -> dict[str, Any] | None:
    """The scene-light's cached Monte Carlo probe if it was measured under `key`, else None: a
    missing, damaged or other study's probe is measured again by a full run and NaN in a report
    (round twenty: a damaged one stopped the study, --report-only too, after every run)."""
    if not path.exists() and not path.is_symlink():
        return None
    try:
        probe = _read_json(path)
    except ValueError as exc:
        log.warning("%s", exc)
        return None
    if probe.get("key") != key:
        return None
    ratio = probe.get("mc_ratio")
    # a variance ratio: a finite number >= 0 (spikesim.quality.monte_carlo_ratio); true, "12", -5 or 1e400 were
    # reported as measured (round twenty-one)
    if isinstance(ratio, bool) or not isinstance(ratio, (int, float)) or not (math.isfinite(ratio) and ratio >= 0):
        log.warning("%s: damaged cache file (mc_ratio %.40r is not a finite number >= 0); the probe is measured "
                    "again", path, ratio)
        return None
    return probe


def _mc_key(cfg: StudyConfig, scene: str, light: str) -> str:
    return _digest({**_scene_key(cfg, scene, light), "mc_probes": MC_PROBES})


def collect_rows(cfg: StudyConfig, out: Path, runs: Sequence[RunSpec] | None = None) -> list[dict[str, Any]]:
    """The table: every cached run with its errors and cost ratios against its reference."""
    runs = runs or plan_runs(cfg)
    rows = []
    for scene, light, folder, ref in _reference_folders(cfg, out):
        scene_key = _scene_key(cfg, scene, light)  # the scene's files hashed once per scene-light
        ref_key = _run_key(scene_key, plan_runs(cfg)[0])
        ref_npz = _load_npz(folder / "reference.npz", "packed", "gt")  # damaged: named first
        _check_current(folder / "reference.json", ref, ref_key)
        _check_npz_key(folder / "reference.npz", ref_key)
        gt = ref_npz["gt"]
        ref_recon = cached_recon_scores(folder, "reference", ref["key"], ref["key"], ref_npz["packed"], gt, cfg)
        # the scene-light's light level (docs: the study's light classes)
        y_median = float(np.median(gt))
        probe = _probe_of(folder / "mc_probe.json", _mc_key(cfg, scene, light))
        # the sample rule's ratio (NaN until the study is run again: it renders only the probes)
        mc_ratio = float(probe["mc_ratio"]) if probe is not None else math.nan
        block = []
        untimed_said = False
        for spec in runs:
            p = folder / f"{_slug(spec.name)}.json"
            if not p.exists():
                continue
            row = _read_json(p)
            key = _run_key(scene_key, spec)
            _check_current(p, row, key)  # a missing run is left out; another study's refused
            data = _load_npz(folder / f"{_slug(spec.name)}.npz", "packed", "y_centres")
            _check_npz_key(folder / f"{_slug(spec.name)}.npz", key)
            same = row["session"] == ref["session"]
            # a run resumed in another process: the reference re-timed there (probe frames)
            ref_render = ref["render_s"] if same or "ref_frame_s" not in row else row["ref_frame_s"] * cfg.num_steps
            if row["render_reused"]:
                row["render_s"] = ref_render
            total, ref_total = row["render_s"] + row["simulate_s"], ref_render + ref["simulate_s"]
            timed = ref_total >= MIN_TIMED_S and total > 0  # else the ratios would be the machine's timing noise
            if not timed and not untimed_said:
                log.warning("%s %s: the reference took %.3f s, below the %.2f s a ratio of times needs (a render's "
                            "time varies by tens of ms from call to call): no time ratios and no Pareto front; use "
                            "a larger --height/--width or more --windows", scene, light, ref_total, MIN_TIMED_S)
                untimed_said = True
            m = stream_metrics(data["packed"], ref_npz["packed"], cfg)
            recon = (ref_recon if spec.knob == "reference" else
                     cached_recon_scores(folder, spec.name, row["key"], ref["key"], data["packed"], gt, cfg))
            block.append({
                "scene": scene_label(scene), "light": light, "ref_y_median": y_median, "ref_mc_ratio": mc_ratio,
                "ref_spp": cfg.ref_spp, "run": spec.name, "knob": spec.knob,
                "render_s": row["render_s"], "simulate_s": row["simulate_s"], "total_s": total,
                "render_ratio": _ratio(row["render_s"], ref_render, timed),
                "simulate_ratio": _ratio(row["simulate_s"], ref["simulate_s"], timed),
                "time_ratio": _ratio(total, ref_total, timed), "speedup": _ratio(ref_total, total, timed),
                "renders": row["renders"],
                **m, "gt_err": float(np.mean([rel_rmse(a, b) for a, b in zip(data["y_centres"], gt)])),
                "same_session": same, "render_reused": row["render_reused"],
                "recon_tfp_span": recon["recon_tfp_span"], "recon_note": recon["recon_note"],
                **{f"{a}_gt_psnr": recon[f"{a}_gt_psnr"] for a in RECON_AXES},
                **{f"{a}_gt_dpsnr": recon[f"{a}_gt_psnr"] - ref_recon[f"{a}_gt_psnr"] for a in RECON_AXES}})
        for a in RECON_AXES:  # the noise floor's spread: how far another seed moves the score
            spread = [abs(r[f"{a}_gt_dpsnr"]) for r in block
                      if r["knob"] == "floor" and math.isfinite(r[f"{a}_gt_dpsnr"])]
            for r in block:
                r[f"{a}_gt_floor"] = max(spread) if spread else math.nan
        for flag, error in PARETO_AXES.items():
            front = pareto_front([(r["time_ratio"], error(r)) if r["knob"] != "floor" else (math.nan, math.nan)
                                  for r in block])
            for r, f in zip(block, front):
                r[flag] = f
        rows += block
    return rows


#: Each Pareto flag of a run row and the error it is taken on (against time x reference): the
#: firing-rate error, and the reconstruction scores' loss against the reference run's (dB).
PARETO_AXES = {"pareto": lambda r: r["rate_err"], "pareto_tfp": lambda r: -r["tfp_gt_dpsnr"],
               "pareto_net": lambda r: -r["net_gt_dpsnr"]}


COLUMNS = ("scene", "light", "run", "knob", "render_s", "simulate_s", "time_ratio", "speedup", "simulate_ratio",
           "renders", "rate_err", "rate_bias", "isi_w1", "tfp_err", "tfp_psnr", "tfp_ssim", "gt_err", "pareto",
           "same_session", "recon_tfp_span", "tfp_gt_psnr", "tfp_gt_dpsnr", "tfp_gt_floor", "pareto_tfp",
           "net_gt_psnr", "net_gt_dpsnr", "net_gt_floor", "pareto_net", "recon_note",
           "gt_spp", "gt_frame_s", "gt_time_ratio", "gt_self_err", "gt_self_psnr", "gt_ref_err_est", "pareto_gt",
           "ref_y_median", "ref_mc_ratio", "ref_spp")
"""The CSV's columns: a row per run, then (knob "gt") a row per ground truth of the ground-truth
error axis, which fills only the scene, light, run, knob and gt_* columns. `ref_y_median`: the
median of the reference's ground truth (spikes per step), the scene-light's light level;
`ref_mc_ratio`: its Monte Carlo ratio (MC_PROBES spectral 1-spp probes of the first step,
spikesim.quality.monte_carlo_ratio); `ref_spp`: the reference's samples per pixel per step."""


def write_csv(rows: Sequence[dict[str, Any]], path: Path) -> None:
    text = io.StringIO(newline="")
    wr = csv.DictWriter(text, fieldnames=COLUMNS, extrasaction="ignore")
    wr.writeheader()
    wr.writerows(rows)
    atomic_write_file(path, lambda f: f.write(text.getvalue().encode()))


def _fmt(v: Any, fmt: str) -> str:
    """A table cell: `fmt` of v, or n/a where it is missing or NaN."""
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)


def markdown_table(rows: Sequence[dict[str, Any]], gt_rows: Sequence[dict[str, Any]] = ()) -> str:
    """One table per scene and light; Pareto-optimal runs (time against firing-rate error) in bold,
    a reconstruction score on its own axis's Pareto front marked *; under each, the noise floor of the
    reconstruction scores, any note on them, and the ground truth's own error (`gt_rows`)."""
    net = _net_label()
    parts = []
    keys = dict.fromkeys([(r["scene"], r["light"]) for r in rows] + [(r["scene"], r["light"]) for r in gt_rows])
    for key in keys:
        parts.append(f"\n**{key[0]}, {key[1]} light**\n")
        block = [r for r in rows if (r["scene"], r["light"]) == key]
        if block:
            span = block[0].get("recon_tfp_span", WINDOW * RECON_TFP_WINDOWS)
            parts.append(f"| run | render s | sim s | time x ref | speed-up | rate err | rate bias | ISI W1 | TFP PSNR | "
                         f"TFP SSIM | GT err | TFP-{span} vs GT | Δ | {net} vs GT | Δ |\n"
                         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
            for r in block:
                name = f"**{r['run']}**" if r["pareto"] else r["run"]
                recon = " | ".join(
                    f"{_fmt(r.get(f'{a}_gt_psnr'), '{:.2f}')} | {_fmt(r.get(f'{a}_gt_dpsnr'), '{:+.2f}')}"
                    + ("*" if r.get(f"pareto_{a}") else "") for a in RECON_AXES)
                parts.append(f"| {name} | {r['render_s']:.2f} | {r['simulate_s']:.3f} | {_fmt(r['time_ratio'], '{:.3f}')} | "
                             f"{_fmt(r['speedup'], '{:.1f}')} | {r['rate_err']:.3f} | {r['rate_bias']:+.3f} | {r['isi_w1']:.3f} | "
                             f"{r['tfp_psnr']:.1f} | {r['tfp_ssim']:.3f} | {r['gt_err']:.3f} | {recon} |")
            floor = {a: block[0].get(f"{a}_gt_floor", math.nan) for a in RECON_AXES}
            notes = sorted({r.get("recon_note") for r in block if r.get("recon_note")})
            parts.append(f"\nAgainst the reference's ground truth: aligned PSNR (dB) of TFP-{span} and {net}, Δ = run - "
                         f"reference run (* on the Pareto front of time against the loss -Δ). Noise floor (the larger "
                         f"|Δ| of the two floor runs): TFP-{span} {_fmt(floor['tfp'], '{:.2f}')} dB, {net} "
                         f"{_fmt(floor['net'], '{:.2f}')} dB." + "".join(f" Note: {n}." for n in notes))
        gts = [r for r in gt_rows if (r["scene"], r["light"]) == key]
        if gts:
            parts.append("\n| ground truth | s per frame | time x ref GT | rel RMSE vs ref GT | aPSNR vs ref GT | "
                         "ref GT err (est.) |\n|---|---|---|---|---|---|")
            for r in gts:
                name = f"**{r['run']}**" if r.get("pareto_gt") else r["run"]
                parts.append(f"| {name} | {_fmt(r['gt_frame_s'], '{:.3f}')} | {_fmt(r['gt_time_ratio'], '{:.3f}')} | "
                             f"{r['gt_self_err']:.4f} | {_fmt(r['gt_self_psnr'], '{:.2f}')} | "
                             f"{_fmt(r['gt_ref_err_est'], '{:.4f}')} |")
    return "\n".join(parts) + "\n"


_COLOURS = {"reference": "k", "spp": "tab:blue", "keyframes": "tab:orange", "adaptive": "tab:green",
            "variant": "tab:purple", "noise": "tab:grey", "precision": "tab:brown", "combos": "tab:olive",
            "quality": "tab:red", "seeds": "tab:cyan"}


def _scatter_knobs(ax: Any, block: Sequence[dict[str, Any]], y: Any) -> None:
    """The runs of one scene-light at (time x reference, y(r)), a colour per knob, some named."""
    for knob, c in _COLOURS.items():
        pts = [r for r in block if r["knob"] == knob and math.isfinite(y(r))]
        if pts:
            ax.scatter([r["time_ratio"] for r in pts], [y(r) for r in pts], s=18, c=c, label=knob, marker="o")
    for r in block:
        if r["knob"] in ("quality", "spp", "keyframes", "adaptive", "seeds") and math.isfinite(y(r)):
            ax.annotate(r["run"].replace("quality=", ""), (r["time_ratio"], y(r)),
                        fontsize=6, xytext=(2, 2), textcoords="offset points")


def _front_line(ax: Any, points: Sequence[tuple[float, float]]) -> None:
    front = sorted(points)
    if front:
        ax.plot(*zip(*front), color="tab:red", lw=1, alpha=0.6)


def _rate_panel(ax: Any, block: Sequence[dict[str, Any]]) -> None:
    nonzero = [r["rate_err"] for r in block if r["rate_err"] > 0]
    zero = min(nonzero) / 3 if nonzero else 1e-4  # identical streams sit at the bottom edge

    def err(r: dict[str, Any]) -> float:
        return r["rate_err"] if r["rate_err"] > 0 else zero
    for f, ls in zip([r["rate_err"] for r in block if r["knob"] == "floor"], ("--", ":")):
        ax.axhline(f, color="k", ls=ls, lw=0.8)
    _scatter_knobs(ax, block, err)
    _front_line(ax, [(r["time_ratio"], err(r)) for r in block if r.get("pareto")])
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylabel("firing-rate error (rel. RMS)", fontsize=8)
    ax.text(0.99, 0.01, "bottom edge: identical to the reference; dashed: sensor-seed noise floor",
            transform=ax.transAxes, ha="right", va="bottom", fontsize=5)


def _recon_panel(ax: Any, block: Sequence[dict[str, Any]], axis: str, label: str) -> None:
    """Loss of aligned PSNR against the reference run's (dB; below 0: the run scored higher), the
    floor runs' spread as a grey band."""
    def loss(r: dict[str, Any]) -> float:
        return -r[f"{axis}_gt_dpsnr"]
    floor = block[0].get(f"{axis}_gt_floor", math.nan) if block else math.nan
    if math.isfinite(floor):
        ax.axhspan(-floor, floor, color="0.85", lw=0)
    ax.axhline(0, color="k", lw=0.5)
    _scatter_knobs(ax, block, loss)
    _front_line(ax, [(r["time_ratio"], loss(r)) for r in block if r.get(f"pareto_{axis}")])
    ax.set_xscale("log")
    ax.set_ylabel(f"{label} aPSNR loss vs reference (dB)", fontsize=8)
    ax.text(0.99, 0.01, "grey: noise floor (another sensor / render seed)", transform=ax.transAxes, ha="right",
            va="bottom", fontsize=5)


def _gt_panel(ax: Any, block: Sequence[dict[str, Any]]) -> None:
    """Ground truths at fewer samples: relative error against the reference ground truth against
    render seconds per frame; the reference's own (error 0) at the bottom edge."""
    pts = [r for r in block if math.isfinite(r["gt_frame_s"])]
    nonzero = [r["gt_self_err"] for r in pts if r["gt_self_err"] > 0]
    zero = min(nonzero) / 3 if nonzero else 1e-4

    def err(r: dict[str, Any]) -> float:
        return r["gt_self_err"] if r["gt_self_err"] > 0 else zero
    ax.scatter([r["gt_frame_s"] for r in pts], [err(r) for r in pts], s=18, c="tab:blue")
    for r in pts:
        ax.annotate(f"{r['gt_spp']} spp", (r["gt_frame_s"], err(r)), fontsize=6, xytext=(2, 2),
                    textcoords="offset points")
    _front_line(ax, [(r["gt_frame_s"], err(r)) for r in pts if r.get("pareto_gt")])
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("ground-truth render s / frame", fontsize=8)
    ax.set_ylabel("GT error vs reference GT (rel. RMS)", fontsize=8)


def plot(rows: Sequence[dict[str, Any]], path: Path, gt_rows: Sequence[dict[str, Any]] = ()) -> None:
    """A row of panels per scene and light, a panel per accuracy axis: firing-rate error (relative RMS),
    and each reconstruction score's loss against the reference run's (dB), against time (x reference);
    the ground truth's own error against its render time. The Pareto front joined, the noise floors
    dashed (firing rate) or shaded (reconstruction)."""
    matplotlib = require("matplotlib", "plot", "the trade study's plot")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    keys = list(dict.fromkeys([(r["scene"], r["light"]) for r in rows] + [(r["scene"], r["light"]) for r in gt_rows]))
    span = rows[0].get("recon_tfp_span", WINDOW * RECON_TFP_WINDOWS) if rows else WINDOW * RECON_TFP_WINDOWS
    panels: list[tuple[str, str]] = [("rate", "firing rate")] if rows else []
    for axis, label in (("tfp", f"TFP-{span}"), ("net", _net_label())):
        if any(math.isfinite(r.get(f"{axis}_gt_dpsnr", math.nan)) for r in rows):
            panels.append((axis, label))
    if gt_rows:
        panels.append(("gt", "ground truth"))
    fig, axes = plt.subplots(len(keys), len(panels), figsize=(4.6 * len(panels), 3.4 * len(keys)), squeeze=False)
    for i, key in enumerate(keys):
        block = [r for r in rows if (r["scene"], r["light"]) == key]
        gblock = [r for r in gt_rows if (r["scene"], r["light"]) == key]
        for j, (axis, label) in enumerate(panels):
            ax = axes[i, j]
            if not (gblock if axis == "gt" else block):
                ax.axis("off")
                continue
            if axis != "gt" and not any(math.isfinite(r["time_ratio"]) and r["time_ratio"] > 0 for r in block):
                # an untimed study (a reference under MIN_TIMED_S): no time axis to place the runs on; a log
                # axis of NaNs failed the whole command (a fast CPU made the tests' small studies untimed)
                ax.text(0.5, 0.5, f"no time ratios: the reference took under {MIN_TIMED_S:g} s\n(a larger "
                        "--height/--width or more --windows)", transform=ax.transAxes, ha="center", va="center",
                        fontsize=7)
                ax.set_xticks([])
                ax.set_yticks([])
            elif axis == "rate":
                _rate_panel(ax, block)
            elif axis == "gt":
                _gt_panel(ax, gblock)
            else:
                _recon_panel(ax, block, axis, label)
            if axis != "gt":
                ax.set_xlabel("time / reference", fontsize=8)
            ax.set_title(f"{key[0]}, {key[1]} light: {label}", fontsize=9)
            ax.tick_params(labelsize=7)
            for a in (ax.xaxis, ax.yaxis):  # a narrow log range labels its minor ticks on top of each other
                a.set_minor_formatter(NullFormatter())
    first = axes[0, 0]
    if first.get_legend_handles_labels()[0]:
        first.legend(fontsize=6, loc="lower left")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=72)
    plt.close(fig)
    from PIL import Image  # a 64-colour palette keeps the figure small for the docs
    image = Image.open(buf).convert("RGB").quantize(64)
    atomic_write_file(path, lambda f: image.save(f, format="PNG", optimize=True))


REPORT_FILES = ("tradeoff.csv", "tradeoff.md", "tradeoff.png")
PARETO_PLOT = "tradeoff_pareto.png"  # --images DIR: the plot again, for a paper's figures


def write_report(rows: Sequence[dict[str, Any]], out: Path, images: Path | None = None,
                 gt_rows: Sequence[dict[str, Any]] = ()) -> None:
    """tradeoff.csv, .md and .png in `out` (and the plot in `images`), each written whole, never
    through a link (spikesim.outputs). `gt_rows` (collect_gt_rows) add the ground-truth error axis."""
    for name in REPORT_FILES:
        writable(out, name)
    if images is not None:
        writable(images, PARETO_PLOT)
        check_results_owned(images, [PARETO_PLOT], "tradeoff", "--images")  # a user's PNG (round ten)
    ours = check_results_owned(out, REPORT_FILES, "tradeoff")
    drawn = bool(rows or gt_rows)
    written = [name for name in REPORT_FILES if drawn or name != "tradeoff.png"]
    # the earlier report removed first (no earlier plot left beside the new table: round ten) and
    # each file recorded as it is written: an interrupted plot left tables every rerun refused (round twelve)
    with output_folder(out), results_writing(out, written, "tradeoff", stale=ours):
        write_csv([*rows, *gt_rows], out / "tradeoff.csv")
        atomic_write_file(out / "tradeoff.md", lambda f: f.write(markdown_table(rows, gt_rows).encode()))
        if drawn:
            plot(rows, out / "tradeoff.png", gt_rows)
    if drawn and images is not None:
        with output_folder(images), results_writing(images, [PARETO_PLOT], "tradeoff", "--images"):
            plot(rows, images / PARETO_PLOT, gt_rows)


# ---- cache files: written whole (spikesim.outputs: temporary file, then rename; an interrupted study
# leaves the old file or the new one), read with errors naming the file ----
def _cache_slot(path: Path) -> Path:
    """`path`, where the study keeps a cache file, if a cache file may be written there; else a
    ValueError in the study's words: a FIFO, device, socket, link or folder there is refused before
    its run is measured again, not after, and the advice is to remove it (round twenty: "choose
    another output", after the run had been simulated again)."""
    try:
        check_replaceable(path)
    except ValueError:
        problem = "is a symlink" if path.is_symlink() else (file_problem(path) or "is not a regular file")
    else:
        if not path.is_dir():
            return path
        problem = "is a folder"
    raise ValueError(f"{path}: {problem}, where this study keeps a cache file; remove it and run the study again "
                     "(that run is then measured again)")


def _write_json(path: Path, obj: Any) -> None:
    _cache_slot(path)
    atomic_write_file(path, lambda f: f.write((json.dumps(_jsonable(obj), indent=2) + "\n").encode()))


#: The array in every cached .npz that holds its run's cache key: a study with other inputs stopped
#: between a run's .npz and its .json left its arrays under the other study's record (round
#: eighteen), so each file answers for itself.
NPZ_KEY = "cache_key"


def _save_npz(path: Path, key: str, **arrays: np.ndarray) -> None:
    _cache_slot(path)  # a FIFO at a cache file was replaced (round nineteen)
    atomic_write_file(path, lambda f: np.savez_compressed(f, **arrays, **{NPZ_KEY: np.array(key)}))


#: What np.load raises on a damaged archive: a cut or edited zip, a deflate stream that does not
#: inflate (zlib.error: a traceback in round nineteen), a header claiming TiBs (MemoryError).
_DAMAGED_NPZ = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error, MemoryError)


def _npz_key(path: Path) -> str | None:
    """The cache key a cached .npz was written under; None for one without (an older spikesim's),
    a damaged, a missing one, or anything that is not a regular file (a FIFO hung np.load)."""
    if file_problem(path):
        return None
    try:
        with np.load(path) as z:
            return str(z[NPZ_KEY]) if NPZ_KEY in z.files else None
    except _DAMAGED_NPZ:
        return None


def _check_npz_key(path: Path, key: str) -> None:
    """A cached .npz read for the report must have been written under `key`: another study's
    arrays, or arrays cached without a key, are refused as `_check_current` refuses a record."""
    if _npz_key(path) != key:
        raise ValueError(f"{path}: cached for another scene, seed or size, or by an older spikesim (not what these "
                         "options and the scene's files make now); run the study without --report-only to measure "
                         "it again")


def _read_json(path: Path) -> dict[str, Any]:
    try:
        # measured values may be infinite (a PSNR of a perfect match); a cache is larger than a config
        return read_json_object(path, "cache file", finite=False, limit=64 << 20)
    except ValueError as exc:
        raise ValueError(f"{path}: damaged cache file ({exc}); delete it to measure that run again") from exc


def _load_npz(path: Path, *keys: str) -> dict[str, np.ndarray]:
    """The named arrays of a cached .npz, read now (a damaged archive fails here, naming it)."""
    problem = file_problem(path)
    if problem:  # a FIFO there hung np.load (round nineteen)
        raise ValueError(f"{path}: {problem}, where a cache file belongs; delete it to measure that run again")
    try:
        with np.load(path) as z:
            return {k: z[k] for k in keys}
    except _DAMAGED_NPZ as exc:
        raise ValueError(f"{path}: damaged cache file ({type(exc).__name__}: {exc}); delete it to measure that run "
                         "again") from exc


def _is_cached(row_path: Path, npz_path: Path, key: str) -> bool:
    """Whether a run's results are cached for this configuration; a damaged cache is measured again,
    and something that is not a regular file at either path refused first (_cache_slot)."""
    for path in (row_path, npz_path):
        _cache_slot(path)
    if not (row_path.exists() and npz_path.exists()):
        return False
    try:
        if _read_json(row_path).get("key") != key or _npz_key(npz_path) != key:
            return False
    except ValueError as exc:
        log.warning("%s", exc)
        return False
    if not _npz_intact(npz_path):  # its key intact, an array damaged: a traceback later (round nineteen)
        log.warning("%s: damaged cache file; that run is measured again", npz_path)
        return False
    return True


def _npz_intact(path: Path) -> bool:
    """Whether every array of a cached .npz inflates to what its checksum says (zip's CRC-32)."""
    try:
        with zipfile.ZipFile(path) as z:
            return z.testzip() is None
    except _DAMAGED_NPZ:
        return False


def _digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(_jsonable(obj), sort_keys=True).encode()).hexdigest()[:16]


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    return obj


__all__ = ["StudyConfig", "RunSpec", "plan_runs", "run_study", "collect_rows", "collect_gt_rows", "pareto_front",
           "stream_metrics", "recon_scores", "gt_error", "markdown_table", "write_report", "interpolate_at"]
