"""The speed/accuracy study: measure what each render and sensor knob costs and what it changes
(`spikesim tradeoff` is its command line; a Python script runs it with the same objects).

    spikesim tradeoff --scenes ball fan --light low normal --height 50 --width 80 --windows 3 -o out/tradeoff

Per scene and light: a reference run (a render per step, `--ref-spp` samples, spectral, float64,
every noise term) and one run per knob setting, each changing one knob of the reference: samples
per pixel, fixed keyframes every k steps, adaptive keyframes, mono, each noise term off, float32;
plus the draft and balanced quality presets (spikesim.quality) and the combinations of spp and
adaptive tolerance they were chosen among (COMBOS). For each run: render and simulate
wall time and their ratios to the reference (timed in the same process; a resumed process re-times
8 reference frames and scales the reference by them), and the
error against the reference stream (docs/design.md section 4: each knob's cost and its error against
a high-quality reference). Every run uses the reference's sensor seed and render seed, so the
sensor's temporal noise (Philox keyed by seed, pixel and step) is common to both and the difference
measures the knob; two extra runs give the noise floor: the reference with another sensor seed,
and with another sensor and render seed.

Results are cached per run in the output folder (`<out>/runs/<scene>_<light>/<run>.json` + `.npz`),
so an interrupted study continues where it stopped; `--report-only` rebuilds the tables and plot.
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from spikesim._optional import require
from spikesim.config_io import read_json_object
from spikesim.outputs import atomic_write_file, make_dirs, output_folder, writable
from spikesim.render_settings import RenderSettings, render_knob

log = logging.getLogger(__name__)

PROBE_FRAMES = 8  # reference frames re-timed in each process that resumes a study
WINDOW = 41  # the paper's window: 2 * 20 + 1 steps (docs/design.md section 5)
KNOBS = ("spp", "keyframes", "adaptive", "variant", "noise", "precision", "quality", "combos")
#: Combined settings the presets were chosen among (spp, adaptive tolerance in px): the fast knobs
#: together (mono when the light has one spectrum, float32, every noise term).
COMBOS = ((4, 0.25), (4, 1.0), (16, 0.25), (16, 0.5), (16, 1.0), (1, 1.0))
DEFAULT_SCENES = ("ball", "car", "cook", "fan", "rotate")


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
        return {"name": self.name, "knob": self.knob, "settings": self.settings.to_dict(),
                "off_terms": list(self.off_terms), "sensor_seed": self.sensor_seed, "render_seed": self.render_seed}


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
        self._renderers: dict[tuple[str, int], Any] = {}
        self._ref_frames: dict[int, np.ndarray] | None = None
        self._probe: float | None = None

    # renderers are loaded once per (variant, seed) and warmed (the first render compiles)
    def renderer(self, variant: str, seed: int) -> Any:
        key = (variant, seed)
        if key not in self._renderers:
            from spikesim.render import SceneRenderer
            r = SceneRenderer(self.scene, light=self.light, variant=variant, seed=seed, settings=self.cfg.reference)
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

    def base_camera(self) -> Any:
        from spikesim.camera import SpikeCamera
        h, w = self.cfg.resolution
        return SpikeCamera.realistic(height=h, width=w)

    def reference_frames(self) -> dict[int, np.ndarray]:
        if self._ref_frames is None:
            data = _load_npz(self.folder / "reference_frames.npz", "steps", "frames")
            self._ref_frames = {int(s): f for s, f in zip(data["steps"], data["frames"])}
        return self._ref_frames

    def _reuses_reference(self, spec: RunSpec) -> bool:
        s = spec.settings
        return (spec.knob != "reference" and s.keyframe_policy == "every" and s.spp == self.cfg.ref_spp
                and s.variant == "spectral" and spec.render_seed == self.cfg.seed)

    def run(self, spec: RunSpec) -> dict[str, Any]:
        """Render (or reuse), simulate, time; returns the row's timing fields and saves the stream."""
        from spikesim.simulate import Simulator
        from spikesim.stream import SpikeStream

        cfg, s = self.cfg, spec.settings
        if self._reuses_reference(spec):
            ref_row = _read_json(self.folder / "reference.json")
            source: Any = _Replay(self.reference_frames())
            render_s, reused = ref_row["render_s"], True
        else:
            source = _TimedRenderer(self.renderer(s.variant if s.variant != "auto" else "auto", spec.render_seed))
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
        if spec.knob == "reference":
            steps = sorted(keyframes)
            _save_npz(self.folder / "reference_frames.npz", steps=np.array(steps),
                      frames=np.stack([keyframes[k] for k in steps]))
            self._ref_frames = keyframes
            r = self.renderer("spectral", cfg.seed)
            t2 = time.perf_counter()
            extra["gt"] = np.stack([r.ground_truth(c, spp=cfg.gt_spp) for c in cfg.centres()])
            log.info("%s %s: ground truth at %d centres (%d spp) in %.1f s", self.scene, self.light,
                     len(cfg.centres()), cfg.gt_spp, time.perf_counter() - t2)
        if spec.knob == "reference":
            self._probe = render_s / cfg.num_steps
        _save_npz(self.folder / f"{_slug(spec.name)}.npz", packed=stream.packed, y_centres=y_centres, **extra)
        return {"render_s": float(render_s), "render_reused": reused, "simulate_s": float(sim_s),
                "ref_frame_s": self.reference_frame_s(),
                "first_pass_s": float(wall), "renders": len(source.frames) if not reused else cfg.num_steps,
                "keyframes": len(keyframes), "variant_used": variant_used, "camera": camera.to_dict(),
                "noise_decisions": [d.to_dict() for d in decisions], "backend": sim.backend_name}


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
    out.mkdir(parents=True, exist_ok=True)
    _write_json(out / "study.json", dataclasses.asdict(cfg))
    runs = plan_runs(cfg)
    jobs = [(sc, li, r) for sc in cfg.scenes for li in cfg.lights for r in runs]
    session = f"{time.time():.0f}"
    studies: dict[tuple[str, str], SceneStudy] = {}
    bar = progress_bar(jobs, desc="tradeoff", unit="run", quiet=not progress)
    for scene, light, spec in bar:
        folder = out / "runs" / f"{scene}_{light}"
        make_dirs(out, "runs", f"{scene}_{light}")  # inside -o, no link on the way
        path = folder / f"{_slug(spec.name)}.json"
        key = _digest({**cfg.result_key(), "scene": scene, "light": light, **spec.to_dict()})
        if _is_cached(path, folder / f"{_slug(spec.name)}.npz", key):
            log.debug("%s %s %s: cached", scene, light, spec.name)
            continue
        bar.set_postfix_str(f"{scene}/{light} {spec.name}")
        study = studies.setdefault((scene, light), SceneStudy(cfg, scene, light, folder))
        if spec.knob != "reference" and not (folder / "reference.json").exists():
            raise RuntimeError(f"{folder}: the reference run is missing; it runs first")
        t0 = time.perf_counter()
        row = study.run(spec)
        row.update({"key": key, "session": session, "scene": scene, "light": light, **spec.to_dict()})
        _write_json(path, row)
        log.info("%s %s %-28s render %.2f s simulate %.3f s (%.1f s)", scene, light, spec.name, row["render_s"],
                 row["simulate_s"], time.perf_counter() - t0)
        if spec.knob == "reference":
            _write_json(folder / "reference.json", row)
    for st in studies.values():  # release Mitsuba scenes before the report
        st._renderers.clear()
    return collect_rows(cfg, out, runs)


def collect_rows(cfg: StudyConfig, out: Path, runs: Sequence[RunSpec] | None = None) -> list[dict[str, Any]]:
    """The table: every cached run with its errors and cost ratios against its reference."""
    runs = runs or plan_runs(cfg)
    rows = []
    for scene in cfg.scenes:
        for light in cfg.lights:
            folder = out / "runs" / f"{scene}_{light}"
            if not (folder / "reference.json").exists():
                continue
            ref = _read_json(folder / "reference.json")
            ref_npz = _load_npz(folder / "reference.npz", "packed", "gt")
            gt = ref_npz["gt"]
            block = []
            for spec in runs:
                p = folder / f"{_slug(spec.name)}.json"
                if not p.exists():
                    continue
                row = _read_json(p)
                data = _load_npz(folder / f"{_slug(spec.name)}.npz", "packed", "y_centres")
                same = row["session"] == ref["session"]
                # a run resumed in another process: the reference re-timed there (probe frames)
                ref_render = ref["render_s"] if same or "ref_frame_s" not in row else row["ref_frame_s"] * cfg.num_steps
                if row["render_reused"]:
                    row["render_s"] = ref_render
                total, ref_total = row["render_s"] + row["simulate_s"], ref_render + ref["simulate_s"]
                m = stream_metrics(data["packed"], ref_npz["packed"], cfg)
                block.append({
                    "scene": scene, "light": light, "run": spec.name, "knob": spec.knob,
                    "render_s": row["render_s"], "simulate_s": row["simulate_s"], "total_s": total,
                    "render_ratio": row["render_s"] / ref_render, "simulate_ratio": row["simulate_s"] / ref["simulate_s"],
                    "time_ratio": total / ref_total, "speedup": ref_total / total, "renders": row["renders"],
                    **m, "gt_err": float(np.mean([rel_rmse(a, b) for a, b in zip(data["y_centres"], gt)])),
                    "same_session": same, "render_reused": row["render_reused"]})
            front = pareto_front([(r["time_ratio"], r["rate_err"]) if r["knob"] != "floor" else (math.nan, math.nan)
                                  for r in block])
            for r, f in zip(block, front):
                r["pareto"] = f
            rows += block
    return rows


COLUMNS = ("scene", "light", "run", "knob", "render_s", "simulate_s", "time_ratio", "speedup", "simulate_ratio",
           "renders", "rate_err", "rate_bias", "isi_w1", "tfp_err", "tfp_psnr", "tfp_ssim", "gt_err", "pareto",
           "same_session")


def write_csv(rows: Sequence[dict[str, Any]], path: Path) -> None:
    text = io.StringIO(newline="")
    wr = csv.DictWriter(text, fieldnames=COLUMNS, extrasaction="ignore")
    wr.writeheader()
    wr.writerows(rows)
    atomic_write_file(path, lambda f: f.write(text.getvalue().encode()))


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """One table per scene and light; Pareto-optimal runs in bold."""
    head = ("| run | render s | sim s | time x ref | speed-up | rate err | rate bias | ISI W1 | TFP PSNR | "
            "TFP SSIM | GT err |\n|---|---|---|---|---|---|---|---|---|---|---|")
    parts = []
    for key in dict.fromkeys((r["scene"], r["light"]) for r in rows):
        parts.append(f"\n**{key[0]}, {key[1]} light**\n\n{head}")
        for r in (r for r in rows if (r["scene"], r["light"]) == key):
            name = f"**{r['run']}**" if r["pareto"] else r["run"]
            parts.append(f"| {name} | {r['render_s']:.2f} | {r['simulate_s']:.3f} | {r['time_ratio']:.3f} | "
                         f"{r['speedup']:.1f} | {r['rate_err']:.3f} | {r['rate_bias']:+.3f} | {r['isi_w1']:.3f} | "
                         f"{r['tfp_psnr']:.1f} | {r['tfp_ssim']:.3f} | {r['gt_err']:.3f} |")
    return "\n".join(parts) + "\n"


def plot(rows: Sequence[dict[str, Any]], path: Path) -> None:
    """Error (firing rate, relative RMS) against time (x reference), per scene and light; the
    Pareto front joined, the two noise floors dashed."""
    matplotlib = require("matplotlib", "plot", "the trade study's plot")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(dict.fromkeys((r["scene"], r["light"]) for r in rows))
    cols = min(2, len(keys))
    nrows = -(-len(keys) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 3.6 * nrows), squeeze=False)
    colours = {"reference": "k", "spp": "tab:blue", "keyframes": "tab:orange", "adaptive": "tab:green",
               "variant": "tab:purple", "noise": "tab:grey", "precision": "tab:brown", "combos": "tab:olive",
               "quality": "tab:red"}
    for ax, key in zip(axes.flat, keys):
        block = [r for r in rows if (r["scene"], r["light"]) == key]
        nonzero = [r["rate_err"] for r in block if r["rate_err"] > 0]
        zero = min(nonzero) / 3 if nonzero else 1e-4  # identical streams sit at the bottom edge
        def err(r: dict[str, Any]) -> float:
            return r["rate_err"] if r["rate_err"] > 0 else zero
        floor = [r["rate_err"] for r in block if r["knob"] == "floor"]
        for f, ls in zip(floor, ("--", ":")):
            ax.axhline(f, color="k", ls=ls, lw=0.8)
        for knob, c in colours.items():
            pts = [r for r in block if r["knob"] == knob]
            if pts:
                ax.scatter([r["time_ratio"] for r in pts], [err(r) for r in pts], s=18, c=c, label=knob,
                           marker="o" if knob != "floor" else "x")
        for r in block:
            if r["knob"] in ("quality", "spp", "keyframes", "adaptive"):
                ax.annotate(r["run"].replace("quality=", ""), (r["time_ratio"], err(r)),
                            fontsize=6, xytext=(2, 2), textcoords="offset points")
        front = sorted((r["time_ratio"], err(r)) for r in block if r.get("pareto"))
        if front:
            ax.plot(*zip(*front), color="tab:red", lw=1, alpha=0.6)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{key[0]}, {key[1]} light", fontsize=9)
        ax.set_xlabel("time / reference", fontsize=8)
        ax.set_ylabel("firing-rate error (rel. RMS)", fontsize=8)
        ax.text(0.99, 0.01, "bottom edge: identical to the reference; dashed: sensor-seed noise floor",
                transform=ax.transAxes, ha="right", va="bottom", fontsize=5)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(keys):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=6, loc="lower left")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=72)
    plt.close(fig)
    from PIL import Image  # a 64-colour palette keeps the figure small for the docs
    image = Image.open(buf).convert("RGB").quantize(64)
    atomic_write_file(path, lambda f: image.save(f, format="PNG", optimize=True))


REPORT_FILES = ("tradeoff.csv", "tradeoff.md", "tradeoff.png")


def write_report(rows: Sequence[dict[str, Any]], out: Path, images: Path | None = None) -> None:
    """tradeoff.csv, .md and .png in `out` (and the plot in `images`), each written whole, never
    through a link (spikesim.outputs)."""
    for name in REPORT_FILES:
        writable(out, name)
    if images is not None:
        writable(images, "tradeoff_pareto.png")
    with output_folder(out):
        write_csv(rows, out / "tradeoff.csv")
        atomic_write_file(out / "tradeoff.md", lambda f: f.write(markdown_table(rows).encode()))
        if rows:
            plot(rows, out / "tradeoff.png")
    if rows and images is not None:
        with output_folder(images):
            plot(rows, images / "tradeoff_pareto.png")


# ---- cache files: written whole (spikesim.outputs: temporary file, then rename; an interrupted study
# leaves the old file or the new one), read with errors naming the file ----
def _write_json(path: Path, obj: Any) -> None:
    atomic_write_file(path, lambda f: f.write((json.dumps(_jsonable(obj), indent=2) + "\n").encode()))


def _save_npz(path: Path, **arrays: np.ndarray) -> None:
    atomic_write_file(path, lambda f: np.savez_compressed(f, **arrays))


def _read_json(path: Path) -> dict[str, Any]:
    try:
        # measured values may be infinite (a PSNR of a perfect match); a cache is larger than a config
        return read_json_object(path, "cache file", finite=False, limit=64 << 20)
    except ValueError as exc:
        raise ValueError(f"{path}: damaged cache file ({exc}); delete it to measure that run again") from exc


def _load_npz(path: Path, *keys: str) -> dict[str, np.ndarray]:
    """The named arrays of a cached .npz, read now (a damaged archive fails here, naming it)."""
    try:
        with np.load(path) as z:
            return {k: z[k] for k in keys}
    except (ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: damaged cache file ({exc}); delete it to measure that run again") from exc


def _is_cached(row_path: Path, npz_path: Path, key: str) -> bool:
    """Whether a run's results are cached for this configuration; a damaged cache is measured again."""
    if not (row_path.exists() and npz_path.exists()):
        return False
    try:
        return _read_json(row_path).get("key") == key
    except ValueError as exc:
        log.warning("%s", exc)
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


__all__ = ["StudyConfig", "RunSpec", "plan_runs", "run_study", "collect_rows", "pareto_front", "stream_metrics",
           "markdown_table", "write_report", "interpolate_at"]
