"""`spikesim generate`: build LLR, RLLR or a user's own dataset from scene XML.

A dataset is a list of `SceneJob`s, each a plain, JSON-serialisable description of one scene
folder (spikesim/dataset.py documents the layout). A job is run by one process from start to end
and its folder appears only when complete, so generation is resumable: complete folders whose
recorded job equals the planned one are skipped, anything else is (re)built. Jobs run in a local
process pool by default, or as Ray tasks writing to a shared path.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import os
import shutil
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

log = logging.getLogger("spikesim.generate")

WINDOW = 41  # the reconstruction window (paper, section "Implementation Details")


# ---- presets --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Preset:
    """Dataset sizes and quality knobs. `paper` is the published size; `small` runs in minutes
    on a 2-core CPU (the demo and the tests use it)."""

    name: str
    height: int
    width: int
    llr_windows: int
    """Continuous windows per LLR scene (paper: 21 of 41 steps)."""
    llr_scenes: tuple[str, ...]
    rllr_scenes: int
    """Random scenes in RLLR (paper: 100)."""
    rllr_steps: int
    """Steps per RLLR scene (paper: 1000)."""
    rllr_gt_stride: int = 1
    """Ground truth every this many steps in RLLR (1 = every step, as the paper)."""
    spp: int = 4
    gt_spp: int = 64
    variant: str = "auto"
    """Renderer variant: "auto" = mono when the lights share one spectrum, else spectral."""
    keyframe_every: int = 1

    def __post_init__(self) -> None:
        for f in ("height", "width", "llr_windows", "rllr_steps", "rllr_gt_stride", "spp", "gt_spp", "keyframe_every"):
            if int(getattr(self, f)) < 1:
                raise ValueError(f"preset {self.name}: {f} must be >= 1")
        if self.rllr_scenes < 0:
            raise ValueError(f"preset {self.name}: rllr_scenes must be >= 0")


PRESETS: dict[str, Preset] = {
    "paper": Preset("paper", 250, 400, llr_windows=21, llr_scenes=("ball", "car", "cook", "fan", "rotate"),
                    rllr_scenes=100, rllr_steps=1000),
    "small": Preset("small", 64, 100, llr_windows=3, llr_scenes=("ball", "fan"), rllr_scenes=3, rllr_steps=164,
                    rllr_gt_stride=41, spp=2, gt_spp=16),
}


# ---- jobs -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SceneJob:
    """Everything that determines one scene folder, bit for bit."""

    name: str
    source: dict[str, Any]
    """{"type": "scene", "scene": name-or-xml, "motion": path|None, "lights": path|None, "light": str}
    or {"type": "pattern", "peak_y": float} (the built-in pattern, no renderer)
    or {"type": "random", "index": int} (an RLLR random scene, built from the seed)."""
    camera: dict[str, Any]
    render: dict[str, Any]
    num_steps: int
    gt_steps: tuple[int, ...]
    windows: tuple[tuple[int, int], ...] = ()
    """(start, stop) of each reconstruction window, stop exclusive; its centre has ground truth."""
    light_power_factor: float = 1.0
    """Multiplies every light's power (RLLR's random darkening, paper). Light transport is linear
    in emitter power, so it is applied to the rendered radiance: identical, and no re-render."""
    seed: int = 0
    keyframe_every: int = 1
    flip: bool = True
    quality: str | None = None
    """A `spikesim.quality` preset (draft / balanced / reference) that sets the render and sensor
    knobs (spp, variant, keyframe policy, noise terms, precision) instead of the fields above."""

    def __post_init__(self) -> None:
        if self.quality is not None:
            from spikesim.quality import QualitySettings
            QualitySettings.from_name(self.quality)  # validates the name
        if self.num_steps < 1:
            raise ValueError(f"job {self.name}: num_steps must be >= 1")
        if not 0 < self.light_power_factor <= 1e6 or not np.isfinite(self.light_power_factor):
            raise ValueError(f"job {self.name}: light_power_factor={self.light_power_factor} must be positive and finite")
        bad = [s for s in self.gt_steps if not 0 <= s < self.num_steps]
        if bad:
            raise ValueError(f"job {self.name}: ground-truth steps {bad[:5]} outside [0, {self.num_steps})")

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["gt_steps"] = list(self.gt_steps)
        d["windows"] = [list(w) for w in self.windows]
        return d

    @property
    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:16]


def llr_windows(num_windows: int, window: int = WINDOW) -> tuple[tuple[tuple[int, int], ...], tuple[int, ...]]:
    """Consecutive windows from step 0 and their centre steps (paper: t_i = i (2 dt + 1))."""
    wins = tuple((i * window, (i + 1) * window) for i in range(num_windows))
    return wins, tuple(a + window // 2 for a, _ in wins)


def _camera_dict(preset: Preset, camera: Any | None) -> dict[str, Any]:
    from spikesim.camera import SpikeCamera
    cam = camera or SpikeCamera.realistic()
    return cam.replace(height=preset.height, width=preset.width).to_dict()


def _render_dict(preset: Preset, seed: int) -> dict[str, Any]:
    return {"variant": preset.variant, "spp": preset.spp, "gt_spp": preset.gt_spp, "seed": seed,
            "resolution": [preset.height, preset.width]}


def plan_llr(preset: Preset, seed: int = 0, camera: Any | None = None, scenes: list[str] | None = None,
             lights: tuple[str, ...] = ("normal", "low"), quality: str | None = None) -> list[SceneJob]:
    wins, centres = llr_windows(preset.llr_windows)
    jobs = []
    for i, scene in enumerate(scenes or preset.llr_scenes):
        for j, light in enumerate(lights):
            s = seed * 1000 + i * 10 + j
            jobs.append(SceneJob(name=f"{scene}_{light}", source={"type": "scene", "scene": scene, "light": light},
                                 camera=_camera_dict(preset, camera), render=_render_dict(preset, s),
                                 num_steps=wins[-1][1], gt_steps=centres, windows=wins, seed=s,
                                 keyframe_every=preset.keyframe_every, quality=quality))
    return jobs


def plan_rllr(preset: Preset, seed: int = 0, camera: Any | None = None, count: int | None = None,
              source: str = "random", quality: str | None = None) -> list[SceneJob]:
    """RLLR: random scenes, each darkened by a random factor in (0, 1) (paper, "RLLR")."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
    n = preset.rllr_scenes if count is None else count
    gt = tuple(range(0, preset.rllr_steps, preset.rllr_gt_stride))
    jobs = []
    for i in range(n):
        factor = float(rng.uniform(0.0, 1.0))
        while factor == 0.0:  # (0, 1): open at 0
            factor = float(rng.uniform(0.0, 1.0))
        s = seed * 100_000 + i
        src = {"type": "random", "index": i, "scene_seed": s} if source == "random" else {"type": "pattern", "peak_y": 0.3, "pattern_seed": s}
        jobs.append(SceneJob(name=f"rllr_{i:04d}", source=src, camera=_camera_dict(preset, camera),
                             render=_render_dict(preset, s), num_steps=preset.rllr_steps, gt_steps=gt,
                             light_power_factor=factor, seed=s, keyframe_every=preset.keyframe_every,
                             quality=quality if source == "random" else None))
    return jobs


def plan_user(xml: str, light: str, preset: Preset, num_windows: int | None = None, seed: int = 0,
              motion: str | None = None, lights: str | None = None, camera: Any | None = None,
              light_power_factor: float = 1.0, name: str | None = None, quality: str | None = None) -> list[SceneJob]:
    wins, centres = llr_windows(num_windows or preset.llr_windows)
    src = {"type": "scene", "scene": str(Path(xml).resolve()), "light": light,
           "motion": str(Path(motion).resolve()) if motion else None, "lights": str(Path(lights).resolve()) if lights else None}
    return [SceneJob(name=name or f"{Path(xml).parent.name}_{light}", source=src, camera=_camera_dict(preset, camera),
                     render=_render_dict(preset, seed), num_steps=wins[-1][1], gt_steps=centres, windows=wins,
                     light_power_factor=light_power_factor, seed=seed, keyframe_every=preset.keyframe_every,
                     quality=quality)]


# ---- running one job ------------------------------------------------------------------------------
class _FrameSource:
    """What a job renders from: frames(start, n, keyframe_every), ground_truth(step), describe()."""

    def __init__(self, job: SceneJob, workdir: Path):
        src = job.source
        self.scale = job.light_power_factor
        h, w = job.camera["height"], job.camera["width"]
        if src["type"] == "pattern":
            from spikesim.patterns import MovingPattern
            self._pattern = MovingPattern(height=h, width=w, peak_y=float(src.get("peak_y", 0.25)),
                                          seed=int(src.get("pattern_seed", job.seed)),
                                          readout_period_s=job.camera["readout_period_s"])
            self._renderer = None
        else:
            from spikesim.camera import SpikeCamera
            from spikesim.render import SceneRenderer
            if src["type"] == "random":
                from scenes.random_scene import build_random_scene
                scene, motion, lights, light = build_random_scene(int(src["scene_seed"]), workdir / "random_scene")
            else:
                scene, motion, lights, light = src["scene"], src.get("motion"), src.get("lights"), src["light"]
            render = {k: v for k, v in job.render.items()}
            render["resolution"] = tuple(render["resolution"])
            if job.quality is not None:
                from spikesim.quality import QualitySettings
                render.update(QualitySettings.from_name(job.quality).render_kwargs())
            self._renderer = SceneRenderer(scene, light=light, motion=motion, lights=lights,
                                           camera=SpikeCamera.from_dict(job.camera), **render)
            self._pattern = None

    @property
    def renderer(self) -> Any:
        return self._renderer

    def scaled(self) -> Any:
        """The renderer as the quality presets call it (render_step, motion_px), with the light
        power factor applied."""
        return _ScaledRenderer(self._renderer, self.scale)

    def frames(self, start: int, n: int, k: int) -> Iterator[np.ndarray]:
        if self._renderer is not None:
            it = self._renderer.frames(start, n, keyframe_every=k)
        else:
            it = self._pattern.frames(-(-(n - 1) // k) + 1, start=start, every=k)
        for f in it:
            yield f * np.float32(self.scale) if self.scale != 1.0 else f

    def ground_truth(self, step: int) -> np.ndarray:
        img = self._renderer.ground_truth(step) if self._renderer is not None else self._pattern.frame(step)
        return img * np.float32(self.scale) if self.scale != 1.0 else img

    def describe(self) -> dict[str, Any]:
        if self._renderer is not None:
            return self._renderer.describe()
        return {"pattern": dataclasses.asdict(self._pattern)}


def _without_prefix(obj: Any, prefix: str, replacement: str) -> Any:
    """`obj` with `prefix` replaced in every string: a random scene is built in a temporary
    folder, whose path would otherwise make meta.json differ between runs of the same job."""
    if isinstance(obj, str):
        return obj.replace(prefix, replacement)
    if isinstance(obj, dict):
        return {k: _without_prefix(v, prefix, replacement) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_without_prefix(v, prefix, replacement) for v in obj]
    return obj


class _ScaledRenderer:
    """A renderer whose frames are multiplied by the job's light power factor."""

    def __init__(self, renderer: Any, scale: float):
        self._r, self._scale = renderer, np.float32(scale)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._r, name)

    def render_step(self, step: int, spp: int | None = None) -> np.ndarray:
        y = self._r.render_step(step, spp=spp)
        return y * self._scale if self._scale != 1 else y


def run_job(job: SceneJob, root: str | Path, progress: Callable[[str, int, int], None] | None = None,
            backend: str = "auto", threads: int | None = None) -> dict[str, Any]:
    """Render, simulate and write one scene folder; returns timing and size."""
    from spikesim.camera import SpikeCamera
    from spikesim.dataset import write_scene
    from spikesim.simulate import Simulator
    from spikesim.stream import DatWriter

    if threads and threads >= 2:
        # Dr.Jit with a single worker thread deadlocks in Mitsuba's render (measured: a job with
        # dr.set_thread_count(1) never finished), so one-core workers keep Dr.Jit's default pool.
        from spikesim._drjit import dr
        dr.set_thread_count(threads)
    root = Path(root)
    work = root / f".{job.name}.work"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    t0 = time.perf_counter()
    try:
        source = _FrameSource(job, work)
        cam = SpikeCamera.from_dict(job.camera)
        quality_record = None
        if job.quality is not None and source.renderer is not None:
            from spikesim.quality import QualitySettings
            q = QualitySettings.from_name(job.quality)
            y_levels = None
            if q.noise == "auto":  # the light levels decide which noise terms can show
                y_levels = np.percentile(source.renderer.render_step(0) * np.float32(source.scale), [5, 50, 95])
            cam, decisions = q.camera(cam, y_levels)
            for d in decisions:
                log.debug("%s: noise %s", job.name, d.to_dict())
            quality_record = q.record(decisions)
        sim = Simulator(cam, backend=backend, seed=job.seed)
        dat = work / "spikes.dat"
        written = 0
        with DatWriter(dat, cam.height, cam.width, flip=job.flip) as writer:
            if quality_record is not None:
                parts = q.simulate(sim, source.scaled(), 0, job.num_steps)
            else:
                frames = source.frames(0, job.num_steps, job.keyframe_every)
                parts = sim.stream(frames, keyframe_every=job.keyframe_every, final=True)
            for part in parts:
                take = min(part.num_steps, job.num_steps - written)
                if take <= 0:
                    break
                writer.write(part.slice(0, take))
                written += take
                if progress:
                    progress(job.name, written, job.num_steps)
        t_frames = time.perf_counter() - t0

        def ground_truth() -> Iterator[tuple[int, np.ndarray]]:
            for step in job.gt_steps:
                yield step, source.ground_truth(step)

        meta = {"job": job.to_dict(), "job_digest": job.digest, "camera": job.camera, "seed": job.seed,
                "height": cam.height, "width": cam.width,
                "windows": [list(w) for w in job.windows], "light_power_factor": job.light_power_factor,
                "source": _without_prefix(source.describe(), str(work), "<built from the job's seed>"),
                "simulator": sim.describe(num_steps=written),
                "quality": quality_record}
        write_scene(root, job.name, dat, ground_truth(), meta, flip=job.flip)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    total = time.perf_counter() - t0
    size = sum(p.stat().st_size for p in (root / job.name).rglob("*") if p.is_file())
    return {"name": job.name, "seconds": total, "frames_and_spikes_seconds": t_frames, "bytes": size}


# ---- resumable, parallel generation ---------------------------------------------------------------
def job_status(job: SceneJob, root: Path) -> str:
    """'done' (complete, same job), 'stale' (complete, different job) or 'todo'."""
    meta_path = root / job.name / "meta.json"
    if not meta_path.exists():
        return "todo"
    try:
        meta = json.loads(meta_path.read_text())
    except ValueError:
        return "stale"
    return "done" if meta.get("job_digest") == job.digest else "stale"


def _worker_init(threads: int) -> None:
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))


def _run_in_worker(job: SceneJob, root: str, threads: int, queue: Any) -> dict[str, Any]:
    def progress(name: str, done: int, total: int) -> None:
        queue.put((name, done, total))
    return run_job(job, root, progress=progress, threads=threads)


def generate(jobs: list[SceneJob], root: str | Path, workers: int | None = None, ray_address: str | None = None,
             info: dict[str, Any] | None = None, overwrite_stale: bool = False, show_progress: bool = True) -> dict[str, Any]:
    """Run the jobs that are not done yet, then write the manifest. Returns a report."""
    from tqdm import tqdm

    from spikesim.dataset import write_manifest

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise ValueError("two jobs share a scene name")
    todo = []
    for job in jobs:
        status = job_status(job, root)
        if status == "stale":
            if not overwrite_stale:
                raise FileExistsError(f"{root / job.name} was generated with other parameters; "
                                      "use --overwrite to rebuild it, or another output folder")
            shutil.rmtree(root / job.name)
            status = "todo"
        if status == "todo":
            todo.append(job)
    log.info("%d scene(s) planned, %d already complete, %d to generate in %s",
             len(jobs), len(jobs) - len(todo), len(todo), root)
    results: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    if todo:
        if ray_address is not None:
            results = _generate_ray(todo, root, ray_address, show_progress)
        else:
            results = _generate_local(todo, root, workers or min(len(todo), os.cpu_count() or 1), show_progress, tqdm)
    manifest = write_manifest(root, {**(info or {}), "jobs": {j.name: j.digest for j in jobs}})
    return {"root": str(root), "generated": results, "skipped": len(jobs) - len(todo),
            "seconds": time.perf_counter() - t0, "manifest": str(manifest)}


def _generate_local(todo: list[SceneJob], root: Path, workers: int, show_progress: bool, tqdm: Any) -> list[dict[str, Any]]:
    cores = os.cpu_count() or 1
    if workers <= 1:
        results = []
        overall = tqdm(total=len(todo), desc="scenes", unit="scene", disable=not show_progress, position=0)
        for job in todo:
            bar = tqdm(total=job.num_steps, desc=job.name, unit="step", leave=False, disable=not show_progress, position=1)

            def progress(name: str, done: int, total: int, bar=bar) -> None:
                bar.n = done
                bar.refresh()
            results.append(run_job(job, root, progress=progress))
            bar.close()
            overall.update(1)
        overall.close()
        return results
    import multiprocessing as mp
    ctx = mp.get_context("spawn")  # Dr.Jit / Mitsuba state must not be forked
    threads = max(1, cores // workers)
    manager = ctx.Manager()
    queue = manager.Queue()
    results = []
    bars: dict[str, Any] = {}
    overall = tqdm(total=len(todo), desc="scenes", unit="scene", disable=not show_progress, position=0)
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(threads,)) as pool:
        pending = {pool.submit(_run_in_worker, job, str(root), threads, queue): job for job in todo}
        while pending:
            done, _ = wait(list(pending), timeout=0.5, return_when=FIRST_COMPLETED)
            while not queue.empty():
                name, n, total = queue.get()
                if name not in bars:
                    bars[name] = tqdm(total=total, desc=name, unit="step", leave=False, disable=not show_progress,
                                      position=1 + len(bars) % max(1, workers))
                bars[name].n = n
                bars[name].refresh()
            for fut in done:
                job = pending.pop(fut)
                results.append(fut.result())  # re-raises a worker's error, naming nothing partial
                if job.name in bars:
                    bars.pop(job.name).close()
                overall.update(1)
    overall.close()
    manager.shutdown()
    return results


def _generate_ray(todo: list[SceneJob], root: Path, address: str, show_progress: bool) -> list[dict[str, Any]]:
    """One Ray task per scene; `root` must be a path every node can write (a shared filesystem)."""
    try:
        import ray
    except ModuleNotFoundError as exc:
        raise RuntimeError("Ray is not installed: pip install 'spikesim[cluster]'") from exc
    from tqdm import tqdm
    if not ray.is_initialized():
        ray.init(address=None if address == "local" else address, log_to_driver=False,
                 runtime_env={"env_vars": {"PYTHONPATH": str(Path(__file__).resolve().parents[1])}})
    remote = ray.remote(num_cpus=1)(run_job)
    refs = {remote.remote(job, str(root), None, "auto", 1): job for job in todo}
    results = []
    with tqdm(total=len(todo), desc="scenes (ray)", unit="scene", disable=not show_progress) as bar:
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1)
            for r in ready:
                refs.pop(r)
                results.append(ray.get(r))
                bar.update(1)
    return results


# ---- command line ---------------------------------------------------------------------------------
def run(args: argparse.Namespace) -> int:
    from spikesim.camera import SpikeCamera

    preset = PRESETS[args.preset]
    if args.height or args.width:
        preset = dataclasses.replace(preset, height=args.height or preset.height, width=args.width or preset.width)
    if args.spp:
        preset = dataclasses.replace(preset, spp=args.spp)
    for arg, f in (("keyframe_every", "keyframe_every"), ("gt_spp", "gt_spp"), ("steps", "rllr_steps"),
                   ("gt_stride", "rllr_gt_stride")):
        if getattr(args, arg):
            preset = dataclasses.replace(preset, **{f: getattr(args, arg)})
    if args.windows and args.kind == "llr":
        preset = dataclasses.replace(preset, llr_windows=args.windows)
    camera = SpikeCamera.from_file(args.camera) if args.camera else None
    if args.kind == "llr":
        jobs = plan_llr(preset, seed=args.seed, camera=camera, scenes=args.scenes, quality=args.quality)
    elif args.kind == "rllr":
        jobs = plan_rllr(preset, seed=args.seed, camera=camera, count=args.count,
                         source="pattern" if args.pattern else "random", quality=args.quality)
    else:
        if not args.xml:
            raise ValueError("generate scene needs --xml (and usually --motion, --lights, --light)")
        jobs = plan_user(args.xml, args.light, preset, num_windows=args.windows, seed=args.seed, motion=args.motion,
                         lights=args.lights, camera=camera, light_power_factor=args.light_power_factor,
                         quality=args.quality)
    if args.kind == "rllr" and args.windows:
        raise ValueError("--windows applies to llr and scene; RLLR takes --steps")
    report = generate(jobs, args.out, workers=args.workers, ray_address=args.ray,
                      info={"kind": args.kind, "preset": dataclasses.asdict(preset), "seed": args.seed},
                      overwrite_stale=args.overwrite, show_progress=not args.quiet)
    for r in report["generated"]:
        print(f"  {r['name']}: {r['seconds']:.1f} s, {r['bytes'] / 1e6:.2f} MB")
    print(f"{args.out}: {len(report['generated'])} scene(s) generated, {report['skipped']} already complete, "
          f"{report['seconds']:.1f} s; manifest {report['manifest']}")
    return 0


def run_verify(args: argparse.Namespace) -> int:
    from spikesim.dataset import read_manifest, verify
    problems = verify(args.root, checksums=not args.quick)
    n = len(read_manifest(args.root)["scenes"])
    for p in problems:
        print(p)
    print(f"{args.root}: {n} scene(s), " + ("intact" if not problems else f"{len(problems)} problem(s)"))
    return 1 if problems else 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("generate", help="generate LLR, RLLR or a user dataset (resumable, parallel)")
    p.add_argument("kind", choices=["llr", "rllr", "scene"])
    p.add_argument("--preset", choices=sorted(PRESETS), default="small")
    p.add_argument("-o", "--out", type=Path, required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scenes", nargs="*", help="LLR scenes (default: the preset's)")
    p.add_argument("--count", type=int, help="RLLR scenes (default: the preset's)")
    p.add_argument("--pattern", action="store_true", help="RLLR from the built-in pattern instead of random 3D scenes")
    p.add_argument("--xml", help="scene XML (generate scene)")
    p.add_argument("--motion", help="motion file (default: motion.json beside the XML)")
    p.add_argument("--lights", help="lights file (default: lights.json beside the XML)")
    p.add_argument("--light", default="normal", help="lighting condition in the lights file")
    p.add_argument("--light-power-factor", type=float, default=1.0, help="scale every light's power")
    p.add_argument("--windows", type=int, help="41-step windows per scene (llr, scene)")
    p.add_argument("--steps", type=int, help="steps per RLLR scene (paper 1000)")
    p.add_argument("--gt-stride", type=int, help="RLLR ground truth every this many steps (paper 1)")
    p.add_argument("--gt-spp", type=int, help="samples per pixel of ground-truth renders")
    p.add_argument("--camera", help="camera config file")
    p.add_argument("--height", type=int)
    p.add_argument("--width", type=int)
    p.add_argument("--spp", type=int)
    p.add_argument("--keyframe-every", type=int)
    p.add_argument("--quality", choices=["draft", "balanced", "reference"],
                   help="render/sensor knobs from spikesim.quality (measured presets; docs/tradeoff.md); "
                        "overrides --spp/--keyframe-every and the variant")
    p.add_argument("--workers", type=int, help="local processes (default: one per core)")
    p.add_argument("--ray", metavar="ADDRESS", help="run on a Ray cluster ('auto', an address, or 'local')")
    p.add_argument("--overwrite", action="store_true", help="rebuild scenes generated with other parameters")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)
    v = sub.add_parser("verify", help="check a dataset against its manifest")
    v.add_argument("root", type=Path)
    v.add_argument("--quick", action="store_true", help="sizes only, no checksums")
    v.set_defaults(func=run_verify)
