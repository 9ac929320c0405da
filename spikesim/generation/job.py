"""Running one scene job: render (or draw the pattern), simulate, and write its scene folder.

A job runs in one process from start to end, in a work folder `.<name>.work` inside the output
root; its scene folder appears, whole and with its checksums, only when it is complete
(spikesim.dataset.write_scene).
"""
from __future__ import annotations

import dataclasses
import logging
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

import numpy as np

from spikesim.dataset import TWIN_SPIKES, inside_root, remove_inside, write_scene
from spikesim.outputs import writing
from spikesim.keyframes import keyframe_count
from spikesim.render.lights import scale_light_amounts
from spikesim.render_settings import RenderSettings

if TYPE_CHECKING:
    from spikesim.generation.plan import SceneJob

log = logging.getLogger("spikesim.generate")


def sample_rule_choice(quality: Any, renderer: Any, scale: float, threshold_electrons: float) -> dict[str, Any]:
    """What a quality's sample rule makes of a scene: its probe renders at step 0 (scaled by the
    job's light factor), their Monte Carlo ratio, the samples chosen and the predicted loss, as
    meta.json records them (`generate` and its estimate read scenes alike)."""
    from spikesim.quality import monte_carlo_ratio
    rule = quality.sample_rule
    probes = renderer.probe_frames(0, rule.probes, spp=1) * np.float32(scale)
    ratio = monte_carlo_ratio(probes, threshold_electrons)
    spp = rule.spp_for(ratio)
    return {"mc_ratio": ratio, "y_mean": float(probes.mean()), "spp": spp,
            "predicted_loss_db": rule.predicted_loss_db(ratio, spp), "rule": dataclasses.asdict(rule)}


class _FrameSource:
    """What a job renders from: frames(start, n, keyframe_every), ground_truth(step), describe()."""

    def __init__(self, job: SceneJob, workdir: Path, device: str = "auto"):
        src = job.source
        self.scale = job.light_power_factor
        self.gt_images, self.gt_max = 0, 0.0
        h, w = job.camera["height"], job.camera["width"]
        if src["type"] == "pattern":
            from spikesim.patterns import MovingPattern
            self._pattern = MovingPattern(height=h, width=w, peak_y=float(src.get("peak_y", 0.25)),
                                          seed=int(src.get("pattern_seed", job.seed)),
                                          readout_period_s=job.camera["readout_period_s"])
            self._renderer = None
        elif src["type"] == "photo":
            from scenes.photo_pan import PhotoPan
            self._pattern = PhotoPan(height=h, width=w, num_steps=int(job.num_steps), seed=int(src["scene_seed"]),
                                     peak_y=float(src["peak_y"]), photo_set=str(src.get("photo_set", "train")),
                                     encoding=str(src.get("encoding", "linear")),
                                     still_share=float(src.get("still_share", 0.0)))
            self._renderer = None
        else:
            from spikesim.camera import SpikeCamera
            from spikesim.render import SceneRenderer
            self._content = None
            if src["type"] == "random" and src.get("content", "procedural") == "natural":
                from scenes.natural_scene import NATURAL_LAMPS_LUX, build_natural_scene
                with writing(workdir / "random_scene"):  # a full disk names the folder, not a mesh library's call
                    scene, motion, lights, light = build_natural_scene(
                        int(src["scene_seed"]), workdir / "random_scene", resolution=(h, w),
                        lamps_lux=tuple(src.get("lamps_lux", NATURAL_LAMPS_LUX)),
                        readout_period_s=float(job.camera["readout_period_s"]))
                self._content = workdir / "random_scene" / "content.json"
            elif src["type"] == "random":
                from scenes.random_scene import LAMPS_LUX_BEFORE_STUDY, build_random_scene
                with writing(workdir / "random_scene"):
                    scene, motion, lights, light = build_random_scene(
                        int(src["scene_seed"]), workdir / "random_scene",
                        lamps_lux=tuple(src.get("lamps_lux", LAMPS_LUX_BEFORE_STUDY)))
            else:
                scene, motion, lights, light = src["scene"], src.get("motion"), src.get("lights"), src["light"]
            settings = RenderSettings.from_dict(job.render)
            if job.quality is not None:
                settings = settings.replace(**job.quality_settings.render_kwargs())
            self._renderer = SceneRenderer(scene, light=light, motion=motion, lights=lights,
                                           camera=SpikeCamera.from_dict(job.camera),
                                           settings=settings.replace(device=device))
            self._pattern = None

    @property
    def renderer(self) -> Any:
        return self._renderer

    def scaled(self, device: bool = False) -> Any:
        """The renderer as the quality presets call it (render_step, motion_px), with the light
        power factor applied; with `device`, its frames stay on the render device."""
        return _ScaledRenderer(self._renderer, self.scale, device)

    def frames(self, start: int, n: int, k: int, device: bool = False) -> Iterator[Any]:
        """y frames (keyframes every k steps); with `device`, Dr.Jit arrays on the render device."""
        if self._renderer is not None:
            it = self._renderer.frames(start, n, keyframe_every=k, device=device)
        else:
            it = self._pattern.frames(keyframe_count(n, k), start=start, every=k)
        for f in it:
            yield f * np.float32(self.scale) if self.scale != 1.0 else f

    def ground_truth(self, step: int) -> np.ndarray:
        img = (self._renderer.ground_truth(step) if self._renderer is not None
               else self._pattern.frame(step))
        self.gt_images += 1
        self.gt_max = max(self.gt_max, float(np.max(img))) if img.size else self.gt_max
        return img * np.float32(self.scale) if self.scale != 1.0 else img

    def check_lit(self) -> None:
        """A rendered scene's ground truth (before the light power factor) must not be black: its
        lights are on, so a black image means a camera, integrator or emitter that cannot light
        the sensor (spikesim.render.scene_checks)."""
        if self._renderer is not None:
            from spikesim.render.scene_checks import check_lit
            check_lit(self._renderer.files.xml, self.gt_max, self.gt_images, self._renderer.lighting)

    def rendered_frames_error(self, exc: ValueError) -> ValueError:
        """A frame the sensor refused (not finite: spikesim.simulate.check_frame and the device
        kernel name the frame), named with the scene's XML."""
        if self._renderer is None or not str(exc).startswith("frame ") or str(self._renderer.files.xml) in str(exc):
            return exc
        from spikesim.render.scene_checks import non_finite_frame_error
        return non_finite_frame_error(self._renderer.files.xml, f"a rendered frame cannot be simulated: {exc}",
                                      self._renderer.lighting)

    def describe(self) -> dict[str, Any]:
        """The source's record, its light as the job renders it: photometric amounts (lux, lumens,
        candela, power) scaled by the light power factor, like the frames."""
        if self._renderer is None:
            describe = getattr(self._pattern, "describe", None)
            return describe() if describe is not None else {"pattern": dataclasses.asdict(self._pattern)}
        out = self._renderer.describe()
        if getattr(self, "_content", None) is not None:  # a natural scene: its textures' sources and licences
            import json
            out["content"] = json.loads(self._content.read_text())
        if self.scale != 1.0 and "light" in out:
            out["light"] = {**scale_light_amounts(out["light"], self.scale), "light_power_factor": self.scale}
        return out


def subject_illuminance_lux(source: dict[str, Any]) -> float | None:
    """The illuminance at the scene's subject as rendered (light power factor included), if the
    lighting records one."""
    subject = source.get("light", {}).get("subject") or {}
    lux = subject.get("illuminance_lux", subject.get("direct_illuminance_lux"))  # records before the meter: direct
    return float(lux) if isinstance(lux, (int, float)) else None


def subject_illuminance_kind(source: dict[str, Any]) -> str | None:
    """What `subject_illuminance_lux` is: computed direct light at a light file's subject, or the
    total metered on the surface at the view centre (SceneRenderer.subject_illuminance)."""
    subject = source.get("light", {}).get("subject") or {}
    if "illuminance" in subject:
        return str(subject["illuminance"])
    return "direct, computed" if "direct_illuminance_lux" in subject else None


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
    """A renderer whose frames are multiplied by the job's light power factor (and, with
    `device`, stay on the render device)."""

    def __init__(self, renderer: Any, scale: float, device: bool = False):
        self._r, self._scale, self._device = renderer, np.float32(scale), device

    def __getattr__(self, name: str) -> Any:
        return getattr(self._r, name)

    def render_step(self, step: int, spp: int | None = None) -> Any:
        y = (self._r.render_step_device if self._device else self._r.render_step)(step, spp=spp)
        return y * self._scale if self._scale != 1 else y


def _inputs_as_planned(job: SceneJob) -> list[Any]:
    """The job's inputs with their sha256 (spikesim.generation.inputs), which must still be the
    ones it was planned with: a file edited while the run was going would otherwise be written
    under the identity of its earlier content."""
    from spikesim.generation.inputs import changes, identities, job_inputs
    inputs = job_inputs(job.source, job.quality)
    if (found := changes(job.inputs, identities(inputs))):
        raise ValueError(f"{job.name}: {', '.join(found)} since this run was planned; run generate again")
    return inputs


def run_job(job: SceneJob, root: str | Path, progress: Callable[[str, int, int], None] | None = None,
            backend: str = "auto", threads: int | None = None, device: str = "auto") -> dict[str, Any]:
    """Render, simulate and write one scene folder; returns timing and size.

    `device` is where Mitsuba renders ("auto": the GPU when there is one); with the sensor
    `backend` "auto" the sensor runs there too, and frames never leave the device: only packed
    spikes come back, to be written."""
    from spikesim.camera import SpikeCamera
    from spikesim.simulate import Simulator, TwinSimulator
    from spikesim.stream import DatWriter

    if threads is not None and threads >= 2:
        # Dr.Jit with a single worker thread deadlocks in Mitsuba's render (measured: a job with
        # dr.set_thread_count(1) never finished), so one-core workers keep Dr.Jit's default pool.
        from spikesim._drjit import dr
        dr.set_thread_count(threads)
    root = Path(root)
    work_name = f".{job.name}.work"
    work = inside_root(root, work_name, follow=False)
    remove_inside(root, work_name)  # debris of a killed run
    work.mkdir(parents=True)
    t0 = time.perf_counter()
    twin_writer = None
    try:
        source = _FrameSource(job, work, device)
        inputs = _inputs_as_planned(job)  # hashed once the renderer has read its files
        cam = SpikeCamera.from_dict(job.camera)
        quality_record = None
        if job.quality is not None and source.renderer is not None:
            q = job.quality_settings
            y_levels = sampling = None
            if q.sample_rule is not None:  # probe renders: the scene's Monte Carlo noise decides the samples
                sampling = sample_rule_choice(q, source.renderer, source.scale, cam.threshold_electrons)
                rule = q.sample_rule
                q = q.for_scene(sampling["mc_ratio"])
                if sampling["predicted_loss_db"] > rule.tolerance_db:  # the cap binds
                    log.warning("%s: Monte Carlo ratio %.3g asks more than the %d spp the rule may give: "
                                "predicted loss %.2f dB (tolerance %.2g)", job.name, sampling["mc_ratio"],
                                rule.max_spp, sampling["predicted_loss_db"], rule.tolerance_db)
                log.info("%s: Monte Carlo ratio %.3g (mean y %.3g spikes/step): %d spp per step, predicted "
                         "loss %.2f dB", job.name, sampling["mc_ratio"], sampling["y_mean"], q.spp,
                         sampling["predicted_loss_db"])
            if q.noise == "auto":  # a probe frame: the light decides the noise terms
                probe = source.renderer.render_step(0) * np.float32(source.scale)
                y_levels = np.percentile(probe, [5, 50, 95])
            cam, decisions = q.camera(cam, y_levels)
            for d in decisions:
                log.debug("%s: noise %s", job.name, d.to_dict())
            quality_record = q.record(decisions)
            if sampling is not None:
                quality_record["sample_rule"] = sampling
        renderer = source.renderer
        if backend == "auto" and renderer is not None:
            backend = renderer.device  # the sensor where the frames are
        sim = Simulator(cam, backend=backend, seed=job.seed)
        on_device = renderer is not None and sim.backend_name == renderer.device
        dat = work / "spikes.dat"
        twin_dat = work / TWIN_SPIKES if job.twin else None
        twin_writer = DatWriter(twin_dat, cam.height, cam.width, flip=job.flip) if twin_dat is not None else None
        twin_written = 0

        def write_twin(part: Any) -> None:  # the twin's parts cover the same steps, cut at num_steps alike
            nonlocal twin_written
            take = min(part.num_steps, job.num_steps - twin_written)
            if take > 0:
                twin_writer.write(part.slice(0, take))
                twin_written += take
        if twin_writer is not None:
            sim = TwinSimulator(sim, write_twin)  # one render per frame, two sensor passes
        written = 0
        # progress counts renders, ground truth included (the bar said 100 % at 78 s of a 180 s
        # scene, counting simulated steps only); a pattern has no render: its steps count instead
        k = job.keyframe_every if renderer is not None else 1
        frame_renders = keyframe_count(job.num_steps, k)
        total_renders = frame_renders + (len(job.gt_steps) if renderer is not None else 0)
        with DatWriter(dat, cam.height, cam.width, flip=job.flip) as writer:
            if quality_record is not None:
                parts = q.simulate(sim, source.scaled(on_device), 0, job.num_steps)
            else:
                frames = source.frames(0, job.num_steps, job.keyframe_every, device=on_device)
                parts = sim.stream(frames, keyframe_every=job.keyframe_every, final=True)
            try:
                for part in parts:
                    take = min(part.num_steps, job.num_steps - written)
                    if take <= 0:
                        break
                    writer.write(part.slice(0, take))
                    written += take
                    if progress:
                        progress(job.name, min(keyframe_count(written, k), frame_renders), total_renders)
            except ValueError as exc:
                raise source.rendered_frames_error(exc) from exc
        if twin_writer is not None:
            twin_writer.close()
            twin_writer = None
        t_frames = time.perf_counter() - t0

        def ground_truth() -> Iterator[tuple[int, np.ndarray]]:
            for i, step in enumerate(job.gt_steps):
                yield step, source.ground_truth(step)
                if progress and renderer is not None:
                    progress(job.name, frame_renders + i + 1, total_renders)
            source.check_lit()  # before the scene folder appears: write_scene removes what it wrote

        described = _without_prefix(source.describe(), str(work), "<built from the job's seed>")
        meta = {"job": job.to_dict(), "job_digest": job.digest, "inputs": [i.to_dict() for i in inputs],
                "camera": job.camera, "seed": job.seed,
                "height": cam.height, "width": cam.width,
                "windows": [list(w) for w in job.windows], "light_power_factor": job.light_power_factor,
                "source": described, "subject_illuminance_lux": subject_illuminance_lux(described),
                "subject_illuminance": subject_illuminance_kind(described),
                "settings": job.settings or None,
                "simulator": sim.describe(num_steps=written),
                "quality": quality_record}
        if twin_dat is not None:  # which camera made each stream: the dataset record says so
            meta["twin"] = {"file": TWIN_SPIKES, "camera": sim.twin.camera.to_dict(),
                            "simulator": sim.twin.describe(num_steps=twin_written)}
        write_scene(root, job.name, dat, ground_truth(), meta, flip=job.flip, twin=twin_dat)
    finally:
        if twin_writer is not None:  # not closed: the run failed before its stream was whole
            twin_writer.abort()
        shutil.rmtree(work, ignore_errors=True)
    total = time.perf_counter() - t0
    size = sum(p.stat().st_size for p in inside_root(root, job.name).rglob("*") if p.is_file())
    renders = int(renderer.stats["renders"]) if renderer is not None else 0  # probes, sub-steps and ground truth included
    return {"name": job.name, "seconds": total, "frames_and_spikes_seconds": t_frames, "bytes": size, "renders": renders,
            "subject_illuminance_lux": meta["subject_illuminance_lux"], "subject_illuminance": meta["subject_illuminance"]}


__all__ = ["run_job"]
