"""How long a generation will take, said before it starts: the renders it plans, counted from the
jobs, and a time from a short calibration on one of its own scenes.

Rendering is 96-99 % of generation at the paper's size (docs/tradeoff.md), and a render's cost is
a fixed part (scene traversal, launch, readback: about 30 ms at 400 x 250 on the 2-core machine)
plus a part that grows with samples x pixels. The calibration renders one step of the first job at
1 spp, its frame spp and its ground-truth spp (after a warm-up render that pays Dr.Jit's kernel
compilation), each CALIBRATION_REPEATS times keeping the fastest, solves those two costs (per
render: a step's motion-blur sub-steps are counted as renders), and times the sensor on a few
steps of that frame; each job's
time is then its frame renders, ground-truth renders and pixel-steps at those rates, scaled by its
pixels, and the jobs are shared out over the workers, largest first. It costs a few seconds, so it
runs only for plans large enough to be worth estimating (ESTIMATE_MIN_RENDERS).

What a job renders depends on its scene's motion: adaptive keyframes (the `balanced` and `draft`
qualities) render only the steps the motion plan needs, and a step that moves by more than the
blur threshold is several renders (motion-blur sub-steps). And scenes render at different speeds.
So the estimate reads up to MOTION_SAMPLE_SCENES of the plan's scenes (loading each and timing
one render, a few seconds each; every scene where a sample rule chooses the samples per scene) and
gives every other job their means, with the spread that leaves. Measured on a paper-size
LLR of Ball and Cook (`balanced`, 2 workers, the machine shared with 2 other processes
throughout): counting every step once estimated 16.0 min; the motion plans, 7.5 min; the motion
plans and each scene's speed, 9.4 min; the three runs took 9.6, 9.5 and 9.6 min.
"""
from __future__ import annotations

import json
import logging
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from spikesim.generation.plan import UNRENDERED_SOURCES
from spikesim.keyframes import keyframe_count

if TYPE_CHECKING:
    from spikesim.generation.plan import SceneJob

log = logging.getLogger("spikesim.generate")

#: Plans with fewer renders than this start without an estimate: the calibration (a few seconds)
#: would be a large part of their time. The paper's LLR plans 8,820 renders, its RLLR 100,000+.
ESTIMATE_MIN_RENDERS = 2000
SENSOR_CALIBRATION_STEPS = 64
#: Timings of each calibration render and of each read scene's render; the least is kept. One
#: timing each gave the paper RLLR's per-sample cost as 154-216 ns from one run to the next on an
#: idle machine (docs/performance.md section 4a).
CALIBRATION_REPEATS = 3
SPEED_REPEATS = 2
#: Distinct scenes (both lights of a scene share their motion) whose motion plans an estimate reads.
MOTION_SAMPLE_SCENES = 6
#: Where a quality's sample rule chooses each scene's samples, the estimate reads every scene (its
#: probes, a load and one render: 1-2 s a scene) unless told otherwise: the samples set a scene's
#: render cost over a 16x range, so a mean over a few scenes misleads. The paper RLLR at `fast`
#: read 6 scenes estimated 127 min, 40 read 173 min; docs/performance.md section 4 has the run.
READ_EVERY_SCENE_WITH_A_SAMPLE_RULE = True


@dataclass(frozen=True)
class Calibration:
    """Costs measured on one scene: a render's fixed seconds and seconds per sample per pixel, and
    the sensor's seconds per pixel-step."""

    scene: str
    pixels: int
    startup_s: float
    """Per job: loading its scene and compiling its kernels (the first render)."""
    fixed_s: float
    per_sample_pixel_s: float
    sensor_per_pixel_step_s: float

    def render_s(self, spp: int, pixels: int) -> float:
        return self.fixed_s + self.per_sample_pixel_s * spp * pixels


@dataclass(frozen=True)
class PlannedWork:
    """One job's renders and pixel-steps."""

    name: str
    frame_renders: int
    gt_renders: int
    spp: float
    """Samples per pixel of a frame render (a mean over the read scenes where a sample rule chooses them)."""
    gt_spp: float
    pixels: int
    steps: int
    render_scale: float = 1.0
    """This job's render time over the calibrated scene's at the same samples (1 where not read)."""
    read: bool = False
    """Whether its scene was read (its motion, speed and samples), not given the read ones' means."""
    gt_images: int | None = None
    """Ground-truth images (None: one per ground-truth render). Each spends gt_spp samples per pixel
    in all over its motion-blur renders (spikesim.render.renderer.samples_per_substep), so its
    renders add their fixed cost only; ceil's rounding, under substeps / gt_spp, is left out."""

    def seconds(self, cal: Calibration) -> float:
        images = self.gt_renders if self.gt_images is None else self.gt_images
        gt = self.gt_renders * cal.fixed_s + images * cal.per_sample_pixel_s * self.gt_spp * self.pixels
        return (cal.startup_s + self.render_scale * (self.frame_renders * cal.render_s(self.spp, self.pixels) + gt)
                + self.steps * self.pixels * cal.sensor_per_pixel_step_s)


def _render_spp(job: "SceneJob") -> tuple[int, int]:
    from spikesim.render_settings import RenderSettings
    settings = RenderSettings.from_dict(job.render)
    if job.quality is not None:
        settings = settings.replace(**job.quality_settings.render_kwargs())
    return int(settings.spp), int(settings.gt_spp)


def planned_work(job: "SceneJob") -> PlannedWork:
    """The renders a job will make (frames at its keyframe spacing, ground truth), as run_job
    counts them; a built-in pattern renders nothing."""
    pixels = int(job.camera["height"]) * int(job.camera["width"])
    if job.source.get("type") in UNRENDERED_SOURCES:
        return PlannedWork(job.name, 0, 0, 0, 0, pixels, job.num_steps)
    spp, gt_spp = _render_spp(job)
    return PlannedWork(job.name, keyframe_count(job.num_steps, job.keyframe_every), len(job.gt_steps), spp, gt_spp,
                       pixels, job.num_steps, gt_images=len(job.gt_steps))


def adaptive_policy(job: "SceneJob") -> Any:
    """The job's adaptive keyframe policy, or None where it renders at a fixed spacing."""
    if job.quality is None or job.source.get("type") in UNRENDERED_SOURCES:
        return None
    q = job.quality_settings
    return q.adaptive_policy() if q.keyframe_policy == "adaptive" else None


def frame_render_count(renderer: Any, job: "SceneJob") -> int:
    """The renders a job's frames will take: the steps it renders (adaptive keyframes: the first
    step and every planned keyframe whose image may have changed, spikesim.render.adaptive's
    motion plan; else every `keyframe_every`-th step), each times its motion-blur sub-steps
    (`substeps_for`, one render each)."""
    from spikesim.keyframes import keyframe_steps
    policy = adaptive_policy(job)
    if policy is not None:
        from spikesim.render.adaptive import motion_plan
        plan = motion_plan(renderer, 0, int(job.num_steps) - 1, policy)
        steps = [plan[0][0]] + [step for step, changed in plan[1:] if changed]
    else:
        steps = list(keyframe_steps(0, int(job.num_steps), int(job.keyframe_every)))
    substeps = getattr(renderer, "substeps_for", None)
    return sum(int(substeps(s)) if substeps is not None else 1 for s in steps)


def gt_render_count(renderer: Any, job: "SceneJob") -> int:
    """The renders a job's ground truth will take: each ground-truth step times its motion-blur
    sub-steps, as for the frames (the paper RLLR's fast scenes need several: each adds a render's
    fixed cost, its samples being the image's share)."""
    substeps = getattr(renderer, "substeps_for", None)
    return sum(int(substeps(s)) if substeps is not None else 1 for s in job.gt_steps)


def sample_rule(job: "SceneJob") -> Any:
    """The job's quality when it chooses its samples per scene (`sample_rule`), else None."""
    if job.quality is None or job.source.get("type") in UNRENDERED_SOURCES:
        return None
    q = job.quality_settings
    return q if q.sample_rule is not None else None


def _motion_key(job: "SceneJob") -> str:
    """Jobs with the same key render alike (the light does not move anything; it does change the
    Monte Carlo noise that chooses the samples of a quality with a sample rule, so there each light
    and power factor is read)."""
    light = [job.source.get("light"), job.light_power_factor] if sample_rule(job) is not None else None
    return json.dumps([{k: v for k, v in job.source.items() if k != "light"}, job.num_steps, job.keyframe_every,
                       adaptive_policy(job) is not None, light], sort_keys=True, default=str)


def one_render_s(renderer: Any, step: int, spp: int, repeats: int = 1) -> float:
    """Seconds of one render at `spp`, timed on step `step` (the least of `repeats` timings: a
    render is slowed by what else the machine does, never sped up). `render_step` renders each of
    the step's motion-blur sub-steps, and the plan counts those renders already
    (`frame_render_count`, `gt_render_count`), so the step's time is divided by them: timing the
    whole step counted a moving scene's sub-steps twice (docs/performance.md section 4a)."""
    substeps = getattr(renderer, "substeps_for", None)
    n = max(1, int(substeps(step)) if substeps is not None else 1)
    best = math.inf
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        renderer.render_step(step, spp=spp)
        best = min(best, time.perf_counter() - t0)
    return best / n


def with_motion_plans(jobs: Sequence["SceneJob"], works: list[PlannedWork], device: str = "auto",
                      load: Any = None, sample_scenes: int | None = None) -> tuple[list[PlannedWork], int]:
    """`works` with each job's frame renders read from its scene's motion (`frame_render_count`) and
    its render speed relative to the first job's (one render at the job's samples after a warm-up,
    where the renderer renders): up to MOTION_SAMPLE_SCENES distinct scenes exactly (every scene
    where a quality's sample rule chooses the samples), the other jobs at the read scenes' means. A quality with a sample rule takes each read job's samples from
    its probe renders as run_job does, and gives the others the mean samples of the read jobs of
    the same light name (else of all read ones). `load(job)` gives a job's renderer
    (default: the job's own scene, loaded in a temporary folder). Returns the works and how many
    scenes were read. `sample_scenes` replaces MOTION_SAMPLE_SCENES (`generate --estimate-scenes`)."""
    import dataclasses

    from spikesim.generation.job import sample_rule_choice
    rendered = [i for i, j in enumerate(jobs) if works[i].frame_renders and j.source.get("type") not in UNRENDERED_SOURCES]
    knobs: dict[str, tuple[int, int]] = {}  # sample-rule jobs read: (spp, gt_spp) by motion key

    def read(job: "SceneJob", spp: int) -> tuple[int, float | None, int] | None:
        with tempfile.TemporaryDirectory(prefix="spikesim-motion-") as tmp:  # a random scene's files
            if load is not None:
                renderer = load(job)
            else:
                from spikesim.generation.job import _FrameSource
                renderer = _FrameSource(job, Path(tmp), device).renderer
            if renderer is None:
                return None
            seconds = None
            if hasattr(renderer, "render_step"):
                renderer.render_step(0, spp=1)  # warm-up: kernels compile
                q = sample_rule(job)
                if q is not None:  # the samples run_job will choose, from the same probes
                    from spikesim.camera import SpikeCamera
                    ne = SpikeCamera.from_dict(job.camera).threshold_electrons
                    chosen = sample_rule_choice(q, renderer, job.light_power_factor, ne)
                    knobs[_motion_key(job)] = (chosen["spp"], q.gt_spp)
                seconds = one_render_s(renderer, 1, max(spp, 1), repeats=SPEED_REPEATS)
            return frame_render_count(renderer, job), seconds, gt_render_count(renderer, job)

    ratios: dict[str, float] = {}
    gt_ratios: dict[str, float] = {}
    speeds: dict[str, float] = {}
    limit = sample_scenes
    if limit is None:
        ruled = READ_EVERY_SCENE_WITH_A_SAMPLE_RULE and any(sample_rule(jobs[i]) is not None for i in rendered)
        limit = len(rendered) if ruled else MOTION_SAMPLE_SCENES
    for i in rendered:
        key = _motion_key(jobs[i])
        if key in ratios or len(ratios) >= limit:
            continue
        got = read(jobs[i], works[i].spp)
        if got is None:
            continue
        ratios[key] = got[0] / works[i].frame_renders
        if works[i].gt_renders:
            gt_ratios[key] = got[2] / works[i].gt_renders
        if got[1] is not None:
            speeds[key] = got[1]
    if not ratios:
        return works, 0
    mean = sum(ratios.values()) / len(ratios)
    gt_mean = sum(gt_ratios.values()) / len(gt_ratios) if gt_ratios else 1.0
    first = speeds.get(_motion_key(jobs[rendered[0]])) if rendered else None
    scales = {k: v / first for k, v in speeds.items()} if first else {}
    mean_scale = sum(scales.values()) / len(scales) if scales else 1.0
    by_light: dict[Any, list[tuple[int, int]]] = {}
    for i in rendered:
        if _motion_key(jobs[i]) in knobs:
            by_light.setdefault(jobs[i].source.get("light"), []).append(knobs[_motion_key(jobs[i])])
    every = [k for ks in by_light.values() for k in ks]
    out = list(works)
    for i in rendered:
        key = _motion_key(jobs[i])
        extra: dict[str, Any] = {}
        if sample_rule(jobs[i]) is not None and every:
            spp, gt_spp = knobs.get(key) or tuple(np.mean(by_light.get(jobs[i].source.get("light"), every), axis=0))
            extra = {"spp": spp, "gt_spp": gt_spp}
        out[i] = dataclasses.replace(works[i], frame_renders=max(1, round(ratios.get(key, mean) * works[i].frame_renders)),
                                     gt_renders=round(gt_ratios.get(key, gt_mean) * works[i].gt_renders),
                                     render_scale=scales.get(key, mean_scale), read=key in ratios, **extra)
    return out, len(ratios)


def calibrate(job: "SceneJob", device: str = "auto") -> Calibration:
    """Time one job's renders and sensor (a few seconds); see the module docstring."""
    from spikesim.camera import SpikeCamera
    from spikesim.generation.job import _FrameSource
    from spikesim.simulate import Simulator

    work = planned_work(job)
    with tempfile.TemporaryDirectory(prefix="spikesim-calibrate-") as tmp:
        t0 = time.perf_counter()
        source = _FrameSource(job, Path(tmp), device)
        renderer = source.renderer
        fixed, per = 0.0, 0.0
        if renderer is not None:
            renderer.render_step(0, spp=1)  # warm-up: the scene's kernels compile on the first render
        startup = time.perf_counter() - t0
        if renderer is not None:
            counts = sorted({1, max(work.spp, 1), max(work.gt_spp, 1)})
            times = {spp: math.inf for spp in counts}
            for _ in range(CALIBRATION_REPEATS):  # interleaved, so a slow spell slows no one count throughout
                for spp in counts:
                    times[spp] = min(times[spp], one_render_s(renderer, 1, spp))
            lo, hi = min(times), max(times)
            if hi > lo:  # two sample counts: the fixed part and the part that grows with samples
                per = max(0.0, (times[hi] - times[lo]) / ((hi - lo) * work.pixels))
                fixed = max(0.0, times[lo] - per * lo * work.pixels)
            else:
                fixed = times[lo]
            frame = np.asarray(renderer.render_step(0, spp=1), dtype=np.float32) * np.float32(source.scale)
        else:
            frame = np.full((job.camera["height"], job.camera["width"]), 0.1, np.float32)
        sim = Simulator(SpikeCamera.from_dict(job.camera), seed=job.seed)
        for _ in sim.stream(iter([frame] * 8)):  # warm-up: the sensor kernel compiles
            pass
        sensor = math.inf
        for _ in range(SPEED_REPEATS):
            t0 = time.perf_counter()
            for _ in sim.stream(iter([frame] * SENSOR_CALIBRATION_STEPS)):
                pass
            sensor = min(sensor, (time.perf_counter() - t0) / (SENSOR_CALIBRATION_STEPS * work.pixels))
    return Calibration(job.name, work.pixels, startup, fixed, per, sensor)


def share_out(seconds: Sequence[float], workers: int) -> float:
    """Wall seconds of jobs run by `workers` processes, each taking the next job when free (largest
    first: the order that bounds the finish best)."""
    free = [0.0] * max(1, workers)
    for s in sorted(seconds, reverse=True):
        i = free.index(min(free))
        free[i] += s
    return max(free) if seconds else 0.0


@dataclass(frozen=True)
class Estimate:
    renders: int
    gt_renders: int
    seconds: float
    workers: int
    calibration: Calibration | None
    motion_scenes: int = 0
    """Scenes whose motion set the jobs' frame renders (0: every planned keyframe counted once)."""
    samples: tuple[tuple[int, int], ...] = ()
    """(samples per step, jobs) over the plan where a quality's sample rule chose them per scene."""
    spread_s: float = 0.0
    """One standard deviation of `seconds` from the jobs not read, which take the read ones' mean:
    the read jobs' spread, for the unread jobs' own times and for that mean (0 where every job
    was read, or fewer than 2)."""
    unread: int = 0
    job_seconds: tuple[tuple[str, float], ...] = ()
    """(job name, seconds on one of `workers` workers sharing the cores) for each job; empty
    without a calibration."""
    adaptive_jobs: int = 0
    """Jobs whose quality places keyframes by the motion (`adaptive_policy`): without reading the
    motion, their count is an upper bound (a render at every planned keyframe)."""

    def summary(self) -> str:
        what = f"{self.renders:,} frame renders and {self.gt_renders:,} ground-truth renders"
        if self.motion_scenes:
            what += f" (read from the motion and render speed of {self.motion_scenes} scene(s))"
        elif self.adaptive_jobs:
            # the count the run used to be compared with: it renders fewer (issue 40: 773 planned, 861 logged)
            what = (f"{what}, counted as a frame at every step ({self.adaptive_jobs} job(s) place keyframes by the "
                    "motion and render fewer; a fast step renders motion-blur sub-steps; --estimate reads the "
                    "scenes' motion and counts them)")
        if self.samples:
            what += "; samples per step: " + ", ".join(f"{n} job(s) at {spp}" for spp, n in self.samples)
        if self.calibration is None:
            return f"plan: {what}; no time estimate for a plan this small (--estimate for one)"
        c = self.calibration
        spread = (f" +- {self.spread_s / 60:.1f} min ({self.unread} job(s) not read take the read ones' mean; "
                  "--estimate-scenes reads more)") if self.spread_s > 0 else ""
        return (f"plan: {what}; estimate {self.seconds / 60:.1f} min{spread} on {self.workers} worker(s) "
                f"(calibrated on {c.scene}: {c.startup_s:.1f} s to load a scene, a render "
                f"{c.fixed_s * 1e3:.0f} ms + {c.per_sample_pixel_s * 1e9:.1f} ns "
                f"per sample per pixel, the sensor {c.sensor_per_pixel_step_s * 1e9:.1f} ns per pixel-step"
                + ("; scenes not read render at the read ones' mean)" if self.motion_scenes and self.unread
                   else ")" if self.motion_scenes else "; other scenes may render faster or slower)"))


def estimate(jobs: Sequence["SceneJob"], workers: int, device: str = "auto", calibrate_at: int | None = None,
             calibration: Calibration | None = None, motion_loader: Any = None,
             sample_scenes: int | None = None) -> Estimate:
    """The plan's renders and, for a plan of at least `calibrate_at` renders (ESTIMATE_MIN_RENDERS),
    its wall time from a calibration on its first job, the frame renders read from the scenes'
    motion (`with_motion_plans`; `motion_loader` as its `load`, up to `sample_scenes` scenes)."""
    works = [planned_work(j) for j in jobs]
    renders, gts = sum(w.frame_renders for w in works), sum(w.gt_renders for w in works)
    threshold = ESTIMATE_MIN_RENDERS if calibrate_at is None else calibrate_at
    adaptive = sum(1 for j in jobs if adaptive_policy(j) is not None)
    if calibration is None and (not jobs or renders + gts < threshold):
        return Estimate(renders, gts, 0.0, workers, None, adaptive_jobs=adaptive)
    cal = calibration or calibrate(jobs[0], device)
    works, motion_scenes = with_motion_plans(jobs, works, device, load=motion_loader, sample_scenes=sample_scenes)
    renders, gts = sum(w.frame_renders for w in works), sum(w.gt_renders for w in works)
    # the calibration rendered with every core; W workers share them, so each job takes about
    # min(W, cores) times its calibrated time (Dr.Jit's renders scale with cores, measured 1.6-1.9x on 2)
    import os
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    slow = min(workers, cores)
    times = [w.seconds(cal) * slow for w in works]
    seconds = share_out(times, workers)
    ruled = [round(w.spp) for j, w in zip(jobs, works) if sample_rule(j) is not None]
    samples = tuple(sorted((spp, ruled.count(spp)) for spp in set(ruled)))
    read = [t for t, w in zip(times, works) if w.read]
    unread = sum(1 for w in works if w.frame_renders and not w.read) if motion_scenes else 0
    spread = 0.0
    if unread and len(read) >= 2:
        # the unread jobs' total: u draws of the read jobs' spread, and u times the error of their mean
        var = float(np.var(read, ddof=1))
        spread = math.sqrt(unread * var + unread ** 2 * var / len(read)) / max(1, min(workers, len(works)))
    return Estimate(renders, gts, seconds, workers, cal, motion_scenes, samples, spread, unread,
                    tuple((j.name, t) for j, t in zip(jobs, times)), adaptive)


def log_estimate(est: Estimate) -> None:
    log.info("%s", est.summary())


__all__ = ["Calibration", "PlannedWork", "Estimate", "ESTIMATE_MIN_RENDERS", "MOTION_SAMPLE_SCENES", "planned_work",
           "adaptive_policy", "frame_render_count", "gt_render_count", "one_render_s", "with_motion_plans", "calibrate", "share_out", "estimate"]
