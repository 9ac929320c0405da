"""`spikesim generate` and `spikesim verify`: build LLR, RLLR or a user's own dataset from scene
XML, and check one against its manifest.

A dataset is a list of `SceneJob`s, each a plain, JSON-serialisable description of one scene
folder (spikesim/dataset.py documents the layout). A job is run by one process from start to end
and its folder appears only when complete, with the checksums of its files, so generation is
resumable: a complete folder whose recorded job equals the planned one and whose files match its
own checksums is skipped; a damaged one is rebuilt; one from other parameters needs --overwrite.
One run at a time writes an output folder (a lock inside it), and nothing is written, deleted or
read outside it. Jobs run in a local process pool by default (pipelines/generate_pool.py), or as
Ray tasks writing to a shared path; pipelines/generate_jobs.py runs one job.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import os
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipelines.argtypes import add_device_argument, existing_file, nonnegative_int, positive_float, positive_int
from pipelines.generate_jobs import _FrameSource, run_job  # noqa: F401  (_FrameSource: tests patch it here)
from pipelines.generate_lock import output_lock
from spikesim._drjit import resolve_device
from spikesim.dataset import (MANIFEST, META, SATURATION_WARN_FRACTION, SATURATION_Y, check_scene, check_scene_name,
                              holds_only_scene_files, inside_root, read_manifest, remove_inside, scene_folders,
                              scene_saturation, write_manifest)

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
    or {"type": "random", "index": int, "scene_seed": int, "lamps_lux": [lo, hi]} (an RLLR random
    scene, built from the seed; lamps_lux absent: the range before the saturation study)."""
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
        check_scene_name(self.name)
        if self.quality is not None:
            from spikesim.quality import QualitySettings
            QualitySettings.from_name(self.quality)  # validates the name
        if self.num_steps < 1:
            raise ValueError(f"job {self.name}: num_steps must be >= 1")
        if not 0 < self.light_power_factor <= 1e6 or not np.isfinite(self.light_power_factor):
            raise ValueError(f"job {self.name}: light_power_factor={self.light_power_factor} must be in (0, 1e6]")
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


def scene_seed(dataset_seed: int, scene: str, light: str) -> int:
    """The seed of one scene (renderer and sensor) from the dataset seed and the scene's identity
    alone, so a scene has the same bytes whichever other scenes are planned with it. The name is
    hashed with sha256 (Python's hash() changes between processes) and mixed with the dataset seed
    by NumPy's SeedSequence."""
    digest = hashlib.sha256(f"{scene}\0{light}".encode()).digest()
    words = [int.from_bytes(digest[i:i + 4], "little") for i in range(0, 16, 4)]
    return int(np.random.SeedSequence([int(dataset_seed), *words]).generate_state(1)[0])


def bundled_scene(name: str) -> str:
    """The bundled LLR scene called `name` (case-insensitive), or a ValueError: LLR scene names are
    names, and a path means the user's own scene, which `generate scene --xml` builds."""
    from scenes import SCENES
    if any(c in name for c in "/\\") or name.startswith(".") or name.lower().endswith(".xml"):
        raise ValueError(f"{name!r} is a path, not an LLR scene name ({', '.join(SCENES)}); "
                         "to build your own scene, use generate scene --xml PATH")
    if name.lower() not in SCENES:
        raise ValueError(f"unknown scene {name!r}: the LLR scenes are {', '.join(SCENES)}; "
                         "to build your own scene, use generate scene --xml PATH")
    return name.lower()


def plan_llr(preset: Preset, seed: int = 0, camera: Any | None = None, scenes: list[str] | None = None,
             lights: tuple[str, ...] = ("normal", "low"), quality: str | None = None) -> list[SceneJob]:
    wins, centres = llr_windows(preset.llr_windows)
    jobs = []
    for scene in (preset.llr_scenes if scenes is None else [bundled_scene(s) for s in scenes]):
        for light in lights:
            name = f"{scene}_{light}"
            s = scene_seed(seed, scene, light)
            jobs.append(SceneJob(name=name, source={"type": "scene", "scene": scene, "light": light},
                                 camera=_camera_dict(preset, camera), render=_render_dict(preset, s),
                                 num_steps=wins[-1][1], gt_steps=centres, windows=wins, seed=s,
                                 keyframe_every=preset.keyframe_every, quality=quality))
    return jobs


def plan_rllr(preset: Preset, seed: int = 0, camera: Any | None = None, count: int | None = None,
              source: str = "random", quality: str | None = None) -> list[SceneJob]:
    """RLLR: random scenes, each darkened by a random factor in (0, 1) (paper, "RLLR"). A random
    scene's job records its lamps' range (scenes.random_scene.LAMPS_LUX), so scenes built with
    another range are not taken for finished ones."""
    from scenes.random_scene import LAMPS_LUX
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
    n = preset.rllr_scenes if count is None else count
    gt = tuple(range(0, preset.rllr_steps, preset.rllr_gt_stride))
    jobs = []
    for i in range(n):
        factor = float(rng.uniform(0.0, 1.0))
        while factor == 0.0:  # (0, 1): open at 0
            factor = float(rng.uniform(0.0, 1.0))
        name = f"rllr_{i:04d}"
        s = scene_seed(seed, name, source)
        src = ({"type": "random", "index": i, "scene_seed": s, "lamps_lux": list(LAMPS_LUX)} if source == "random"
               else {"type": "pattern", "peak_y": 0.3, "pattern_seed": s})
        jobs.append(SceneJob(name=name, source=src, camera=_camera_dict(preset, camera),
                             render=_render_dict(preset, s), num_steps=preset.rllr_steps, gt_steps=gt,
                             light_power_factor=factor, seed=s, keyframe_every=preset.keyframe_every,
                             quality=quality if source == "random" else None))
    return jobs


def plan_user(xml: str, light: str, preset: Preset, num_windows: int | None = None, seed: int = 0,
              motion: str | None = None, lights: str | None = None, camera: Any | None = None,
              light_power_factor: float = 1.0, name: str | None = None, quality: str | None = None) -> list[SceneJob]:
    wins, centres = llr_windows(preset.llr_windows if num_windows is None else num_windows)
    xml_path = Path(xml).resolve()
    if name is None:
        name = f"{xml_path.parent.name}_{light}"
        try:
            check_scene_name(name)
        except ValueError:
            raise ValueError(f"scene name {name!r} (from the XML's folder and the light) is not a plain folder "
                             "name (letters, digits and _.+-); give one with --name") from None
    src = {"type": "scene", "scene": str(xml_path), "light": light,
           "motion": str(Path(motion).resolve()) if motion else None, "lights": str(Path(lights).resolve()) if lights else None}
    s = scene_seed(seed, xml_path.parent.name, light)
    return [SceneJob(name=name, source=src, camera=_camera_dict(preset, camera),
                     render=_render_dict(preset, s), num_steps=wins[-1][1], gt_steps=centres, windows=wins,
                     light_power_factor=light_power_factor, seed=s, keyframe_every=preset.keyframe_every,
                     quality=quality)]


# ---- resumable generation --------------------------------------------------------------------------
def scene_state(job: SceneJob, root: Path, full: bool = False) -> tuple[str, list[str]]:
    """What the output holds for `job`, and why if it is damaged:

    'todo'    no folder yet
    'done'    complete, the same job, every file matching the checksums recorded when it was
              written (sizes only unless `full`: then every sha256)
    'stale'   complete, from other parameters (rebuilt only with --overwrite)
    'damaged' a file missing, truncated, altered (with `full`), meta.json or the record lost
    'foreign' something the generator did not write (never deleted)
    """
    folder = inside_root(root, job.name)  # a symlink leading out of the root is refused here
    given = root / job.name
    if not given.exists() and not given.is_symlink():
        return "todo", []
    if given.is_symlink() or not folder.is_dir() or not holds_only_scene_files(folder):
        return "foreign", []
    try:
        digest = json.loads((folder / META).read_text()).get("job_digest")
    except (OSError, ValueError, AttributeError):
        digest = None  # missing or unreadable: the checksum record says which
    if digest is not None and digest != job.digest:
        return "stale", []
    problems = check_scene(root, job.name, checksums=full)
    if not problems and digest is None:
        problems = [f"{job.name}/{META}: records no job"]
    return ("damaged", problems) if problems else ("done", [])


def job_status(job: SceneJob, root: Path, full: bool = False) -> str:
    """'todo', 'done', 'stale', 'damaged' or 'foreign' (see `scene_state`)."""
    return scene_state(job, Path(root), full)[0]


def _jobs_to_run(jobs: list[SceneJob], root: Path, overwrite_stale: bool, full: bool) -> list[SceneJob]:
    """The jobs whose scene is missing or damaged (and, with `overwrite_stale`, from other
    parameters); their old folders are removed, but only once every folder has been looked at, so
    a refusal (a folder it did not write, other parameters) leaves everything as it was."""
    states = {job.name: scene_state(job, root, full) for job in jobs}
    for name, (state, _) in states.items():
        if state == "foreign":
            raise FileExistsError(f"{root / name} exists but is not a scene folder this generator wrote "
                                  "(it holds other files or is a link); move it away or choose another output folder")
        if state == "stale" and not overwrite_stale:
            raise FileExistsError(f"{root / name} was generated with other parameters; "
                                  "use --overwrite to rebuild it, or another output folder")
    for name, (state, problems) in states.items():
        if state == "damaged":
            log.warning("%s is damaged (%s); rebuilding it", name, "; ".join(problems[:3]))
        if state in ("stale", "damaged"):
            remove_inside(root, name)
    return [job for job in jobs if states[job.name][0] != "done"]


def _passing_scenes(root: Path, planned: list[str], full: bool) -> list[str]:
    """The scenes the manifest may list: every planned one (each must pass), and any other scene
    folder under the root that passes its own check (others are left out, with a warning)."""
    for name in planned:
        if problems := check_scene(root, name):
            raise RuntimeError(f"{name} failed its check right after it was generated: {'; '.join(problems[:3])}")
    others = []
    for name in scene_folders(root):
        if name in planned:
            continue
        if problems := check_scene(root, name, checksums=full):
            log.warning("%s is not planned here and fails its check (%s): left out of the manifest",
                        name, "; ".join(problems[:3]))
        else:
            others.append(name)
    return planned + others


def generate(jobs: list[SceneJob], root: str | Path, workers: int | None = None, ray_address: str | None = None,
             info: dict[str, Any] | None = None, overwrite_stale: bool = False, show_progress: bool = True,
             check: bool = False, command: str | None = None, device: str = "auto") -> dict[str, Any]:
    """Run the jobs that are not done yet, then write the manifest from the scenes that pass their
    checks. `check` hashes every file of the finished scenes (default: sizes only). Returns a report.

    The output root is locked for the run (`command` is recorded for a second run's error); an
    existing manifest.json that this package did not write is refused, not overwritten."""
    root = Path(root)
    names = [j.name for j in jobs]
    if len(set(names)) != len(names):
        raise ValueError("two jobs share a scene name")
    if workers is not None and workers < 1:
        raise ValueError(f"workers={workers}: needs at least 1 (None: one per core)")
    root.mkdir(parents=True, exist_ok=True)
    with output_lock(root, command or shlex.join(sys.argv)):
        if (root / MANIFEST).exists() or (root / MANIFEST).is_symlink():
            read_manifest(root)
        todo = _jobs_to_run(jobs, root, overwrite_stale, check)
        log.info("%d scene(s) planned, %d already complete, %d to generate in %s",
                 len(jobs), len(jobs) - len(todo), len(todo), root)
        results: list[dict[str, Any]] = []
        t0 = time.perf_counter()
        if todo:
            from pipelines.generate_pool import generate_local, generate_ray
            if ray_address is not None:
                results = generate_ray(todo, root, ray_address, show_progress, device)
            else:
                if workers is None:  # one process per core; one process feeds a GPU best
                    workers = 1 if resolve_device(device) == "cuda" else min(len(todo), os.cpu_count() or 1)
                results = generate_local(todo, root, workers, show_progress, device)
        manifest = write_manifest(root, {**(info or {}), "jobs": {j.name: j.digest for j in jobs}},
                                  scenes=_passing_scenes(root, names, check))
    saturation = {name: scene_saturation(root, name) for name in names}
    _warn_saturated(saturation)
    return {"root": str(root), "generated": results, "skipped": len(jobs) - len(todo),
            "seconds": time.perf_counter() - t0, "manifest": str(manifest), "saturation": saturation}


def _warn_saturated(saturation: dict[str, float | None]) -> None:
    """A warning for each scene whose ground truth lies above the sensor's saturation in more than
    SATURATION_WARN_FRACTION of its pixels: targets no spike stream can show (model/data.py clips
    them; docs/model.md)."""
    for name, fraction in saturation.items():
        if fraction is not None and fraction > SATURATION_WARN_FRACTION:
            log.warning("%s: %.1f %% of its ground-truth pixels are above the sensor's saturation (y > %g spike "
                        "per step), more than %g %%: its light is brighter than the camera can show",
                        name, 100 * fraction, SATURATION_Y, 100 * SATURATION_WARN_FRACTION)


# ---- command line ---------------------------------------------------------------------------------
def _llr_scene(text: str) -> str:
    """argparse type: a bundled LLR scene name."""
    try:
        return bundled_scene(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _plain_name(text: str) -> str:
    """argparse type: a plain name (a light, a scene folder), never a path."""
    try:
        return check_scene_name(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a plain name (letters, digits and _.+-, "
                                         "not starting with a dot)") from None


# Options that only some kinds take: given to another kind, they would be silently ignored.
_ONLY_FOR = {
    "scenes": ("llr",), "count": ("rllr",), "pattern": ("rllr",), "steps": ("rllr",), "gt_stride": ("rllr",),
    "windows": ("llr", "scene"), "xml": ("scene",), "motion": ("scene",), "lights": ("scene",),
    "light": ("scene",), "light_power_factor": ("scene",), "name": ("scene",),
}


def _refuse_options_for_other_kinds(args: argparse.Namespace) -> None:
    for dest, kinds in _ONLY_FOR.items():
        if args.kind not in kinds and getattr(args, dest) not in (None, False):
            flag = "--" + dest.replace("_", "-")
            raise ValueError(f"{flag} applies to generate {' and '.join(kinds)}, not generate {args.kind}")


def _preset_from_args(args: argparse.Namespace) -> Preset:
    """The preset with every option given on the command line applied (None: not given)."""
    fields = {"height": "height", "width": "width", "spp": "spp", "gt_spp": "gt_spp", "keyframe_every": "keyframe_every",
              "steps": "rllr_steps", "gt_stride": "rllr_gt_stride", "windows": "llr_windows"}
    given = {f: getattr(args, a) for a, f in fields.items() if getattr(args, a) is not None}
    return dataclasses.replace(PRESETS[args.preset], **given)


def run(args: argparse.Namespace) -> int:
    from spikesim.camera import SpikeCamera

    _refuse_options_for_other_kinds(args)
    if args.kind == "scene" and args.xml is None:
        raise ValueError("generate scene needs --xml (and usually --motion, --lights, --light)")
    preset = _preset_from_args(args)
    device = resolve_device(args.device)  # a GPU that is not here fails before anything is written
    camera = SpikeCamera.from_file(args.camera) if args.camera is not None else None
    if args.kind == "llr":
        jobs = plan_llr(preset, seed=args.seed, camera=camera, scenes=args.scenes, quality=args.quality)
    elif args.kind == "rllr":
        jobs = plan_rllr(preset, seed=args.seed, camera=camera, count=args.count,
                         source="pattern" if args.pattern else "random", quality=args.quality)
    else:
        jobs = plan_user(str(args.xml), args.light or "normal", preset, seed=args.seed,
                         motion=None if args.motion is None else str(args.motion),
                         lights=None if args.lights is None else str(args.lights), camera=camera,
                         light_power_factor=1.0 if args.light_power_factor is None else args.light_power_factor,
                         name=args.name, quality=args.quality)
    report = generate(jobs, args.out, workers=args.workers, ray_address=args.ray,
                      info={"kind": args.kind, "preset": dataclasses.asdict(preset), "seed": args.seed},
                      overwrite_stale=args.overwrite, show_progress=not args.quiet, check=args.check,
                      command="spikesim " + shlex.join(sys.argv[1:]), device=device)
    saturation = report["saturation"]
    for r in report["generated"]:
        print(f"  {r['name']}: {r['seconds']:.1f} s, {r['bytes'] / 1e6:.2f} MB, "
              f"{_percent(saturation.get(r['name']))} of ground-truth pixels saturated")
    print(f"{args.out}: {len(report['generated'])} scene(s) generated, {report['skipped']} already complete, "
          f"{report['seconds']:.1f} s; manifest {report['manifest']}")
    print(saturation_summary(saturation))
    return 0


def _percent(fraction: float | None) -> str:
    return "n/a" if fraction is None else f"{100 * fraction:.2f} %"


def saturation_summary(saturation: dict[str, float | None]) -> str:
    """One line on the ground truth above the sensor's saturation, over the dataset's scenes."""
    known = {k: v for k, v in saturation.items() if v is not None}
    if not known:
        return "ground truth above saturation: not recorded (scenes written before it was)"
    over = sorted((k for k, v in known.items() if v > SATURATION_WARN_FRACTION), key=lambda k: -known[k])
    worst = max(known, key=lambda k: known[k])
    text = (f"ground truth above saturation (y > {SATURATION_Y:g}): mean {_percent(float(np.mean(list(known.values()))))} "
            f"of pixels over {len(known)} scene(s), most {_percent(known[worst])} ({worst}); "
            f"{len(over)} scene(s) above {100 * SATURATION_WARN_FRACTION:g} %")
    return text + (f": {', '.join(over[:10])}{' ...' if len(over) > 10 else ''}" if over else "")


VERIFY_INTACT, VERIFY_DAMAGED, VERIFY_EXTRAS = 0, 1, 3
VERIFY_EPILOG = (f"exit status: {VERIFY_INTACT} intact; {VERIFY_DAMAGED} damaged (a listed file missing, truncated "
                 "or altered, or a listed path outside the root, which is not read); 2 bad input (no dataset, a "
                 f"malformed manifest); {VERIFY_EXTRAS} intact with extra files (files the manifest does not list, "
                 "such as debris of an interrupted run: not damage)")


def run_verify(args: argparse.Namespace) -> int:
    from spikesim.dataset import check_dataset
    found = check_dataset(args.root, checksums=not args.quick)
    for line in found.problems + found.extras:
        print(line)
    if found.problems:
        state, status = f"{len(found.problems)} problem(s)", VERIFY_DAMAGED
    elif found.extras:
        state, status = f"intact with {len(found.extras)} extra file(s)", VERIFY_EXTRAS
    else:
        state, status = "intact", VERIFY_INTACT
    extras = f", {len(found.extras)} extra file(s)" if found.problems and found.extras else ""
    print(f"{args.root}: {found.scenes} scene(s), {state}{extras}")
    return status


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("generate", help="generate LLR, RLLR or a user dataset (resumable, parallel)")
    p.add_argument("kind", choices=["llr", "rllr", "scene"])
    p.add_argument("--preset", choices=sorted(PRESETS), default="small")
    p.add_argument("-o", "--out", type=Path, required=True)
    p.add_argument("--seed", type=nonnegative_int, default=0,
                   help="dataset seed; each scene's seed derives from it, the scene's name and its light")
    p.add_argument("--scenes", nargs="+", type=_llr_scene, help="LLR scenes by name (default: the preset's)")
    p.add_argument("--count", type=positive_int, help="RLLR scenes (default: the preset's)")
    p.add_argument("--pattern", action="store_true", help="RLLR from the built-in pattern instead of random 3D scenes")
    p.add_argument("--xml", type=existing_file, help="scene XML (generate scene)")
    p.add_argument("--motion", type=existing_file, help="motion file (default: motion.json beside the XML)")
    p.add_argument("--lights", type=existing_file, help="lights file (default: lights.json beside the XML)")
    p.add_argument("--light", type=_plain_name, help="lighting condition in the lights file (default: normal)")
    p.add_argument("--name", type=_plain_name, help="scene folder name (generate scene; default: XML folder_light)")
    p.add_argument("--light-power-factor", type=positive_float, help="scale every light's power (default 1)")
    p.add_argument("--windows", type=positive_int, help="41-step windows per scene (llr, scene)")
    p.add_argument("--steps", type=positive_int, help="steps per RLLR scene (paper 1000)")
    p.add_argument("--gt-stride", type=positive_int, help="RLLR ground truth every this many steps (paper 1)")
    p.add_argument("--gt-spp", type=positive_int, help="samples per pixel of ground-truth renders")
    p.add_argument("--camera", type=existing_file, help="camera config file")
    p.add_argument("--height", type=positive_int)
    p.add_argument("--width", type=positive_int)
    p.add_argument("--spp", type=positive_int)
    p.add_argument("--keyframe-every", type=positive_int)
    p.add_argument("--quality", choices=["draft", "balanced", "reference"],
                   help="render/sensor knobs from spikesim.quality (measured presets; docs/tradeoff.md); "
                        "overrides --spp/--keyframe-every and the variant")
    p.add_argument("--workers", type=positive_int, help="local processes (default: one per core; one with a GPU)")
    add_device_argument(p)
    p.add_argument("--ray", metavar="ADDRESS", help="run on a Ray cluster ('auto', an address, or 'local')")
    p.add_argument("--overwrite", action="store_true", help="rebuild scenes generated with other parameters")
    p.add_argument("--check", action="store_true",
                   help="before skipping a finished scene, check every file's sha256 against the checksums recorded "
                        "when it was written (default: sizes only, which catches deleted and truncated files); "
                        "damaged scenes are rebuilt")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)
    v = sub.add_parser("verify", help="check a dataset against its manifest", epilog=VERIFY_EPILOG,
                       description="Check every file the manifest lists (size and sha256), reading only inside the "
                                   "dataset root, and list files the manifest does not.")
    v.add_argument("root", type=Path)
    v.add_argument("--quick", action="store_true", help="sizes only, no checksums")
    v.set_defaults(func=run_verify)
