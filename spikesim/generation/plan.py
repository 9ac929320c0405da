"""Planning a dataset: presets, scene jobs and their seeds.

A dataset is a list of `SceneJob`s, each a plain, JSON-serialisable description of one scene
folder (spikesim/dataset.py documents the layout); spikesim.generation.run runs them.
"""
from __future__ import annotations

import math

import dataclasses
import functools
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spikesim.dataset import check_scene_name
from spikesim.render_settings import HoldsRenderSettings, RenderSettings, check_samples

WINDOW = 41  # the reconstruction window (paper, section "Implementation Details")
#: Job sources whose frames are computed, not rendered: the built-in pattern and the photo scenes
#: (scenes/photo_pan.py). They have no samples per pixel, no render time and no quality rule.
UNRENDERED_SOURCES = ("pattern", "photo")


# ---- presets --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Preset(HoldsRenderSettings):
    """Dataset sizes and render settings. `paper` is the published size; `small` runs in minutes
    on a 2-core CPU (the demo and the tests use it). `replace` takes render knobs (spp, gt_spp,
    variant, keyframe_every) and sizes alike."""

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
    """Ground truth every this many steps in RLLR (1 = every step, as the paper), on the centres of
    41-step windows (rllr_gt_steps)."""
    render: RenderSettings = RenderSettings()
    """spp, gt_spp, variant ("auto" = mono when the lights share one spectrum, else spectral) and
    keyframe_every; a job sets its own seed and the resolution (height, width)."""

    def __post_init__(self) -> None:
        for f in ("height", "width", "llr_windows", "rllr_steps", "rllr_gt_stride"):
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"preset {self.name}: {f}={v!r} must be a positive integer")
        if self.rllr_scenes < 0:
            raise ValueError(f"preset {self.name}: rllr_scenes must be >= 0")

    def values(self) -> dict[str, Any]:
        """Every setting by name, render knobs included (what `replace` takes)."""
        own = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("name", "render")}
        return {**own, **{k: getattr(self.render, k) for k in PRESET_RENDER_KNOBS}}

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, **self.values(), "llr_scenes": list(self.llr_scenes)}


#: The render knobs a preset sets; seed and resolution are each job's.
PRESET_RENDER_KNOBS = ("spp", "gt_spp", "variant", "keyframe_every")


PRESETS: dict[str, Preset] = {
    "paper": Preset("paper", 250, 400, llr_windows=21, llr_scenes=("ball", "car", "cook", "fan", "rotate"),
                    rllr_scenes=100, rllr_steps=1000),
    "small": Preset("small", 64, 100, llr_windows=3, llr_scenes=("ball", "fan"), rllr_scenes=3, rllr_steps=164,
                    rllr_gt_stride=41, render=RenderSettings(spp=2, gt_spp=16)),
}


# ---- jobs -----------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def resolved_quality(name: str) -> Any:
    """A quality preset by name (spikesim.quality.QualitySettings.from_name), resolved once: the
    estimate, the job and its run read the same object."""
    from spikesim.quality import QualitySettings
    return QualitySettings.from_name(name)


@dataclass(frozen=True)
class SceneJob:
    """Everything that determines one scene folder, bit for bit."""

    name: str
    source: dict[str, Any]
    """{"type": "scene", "scene": name-or-xml, "motion": path|None, "lights": path|None, "light": str}
    or {"type": "pattern", "peak_y": float} (the built-in pattern, no renderer)
    or {"type": "photo", "index": int, "scene_seed": int, "peak_y": float, "photo_set": str,
    "encoding": str} (a video-like photo scene, scenes/photo_pan.py, no renderer)
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
    twin: bool = False
    """Also write the noise-free twin's stream (spikesim.simulate.twin_camera) on the same frames.
    Part of the identity only when on, so every job made before it keeps its digest."""
    settings: dict[str, Any] = dataclasses.field(default_factory=dict, compare=False)
    """Each setting's value and where it came from (spikesim.generation.settings), recorded in
    meta.json; not part of the job's identity (`to_dict`, `digest`): the same values from another
    origin make the same scene."""
    inputs: dict[str, str] | None = None
    """What the scene is made from, each by its sha256 (or a version, for code): the XML, motion
    and light files and the meshes and textures the XML references; a random scene's generator;
    the code (spikesim.generation.inputs.job_inputs). Computed from `source` when not given, so
    the identity of every job covers the content of its files, not only their names."""

    def __post_init__(self) -> None:
        check_scene_name(self.name)
        if self.inputs is None:
            from spikesim.generation.inputs import identities, job_inputs
            object.__setattr__(self, "inputs", identities(job_inputs(self.source, self.quality)))
        if self.quality is not None:
            resolved_quality(self.quality)  # validates the name
        try:  # the checks every render setting gets, before any folder is locked or worker started
            settings = RenderSettings.from_dict({**self.render, "keyframe_every": self.keyframe_every})
            if self.source.get("type") not in UNRENDERED_SOURCES:
                for what in ("spp", "gt_spp"):
                    check_samples(getattr(settings, what), self.camera["height"], self.camera["width"], what)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"job {self.name}: {exc}") from None
        if self.num_steps < 1:
            raise ValueError(f"job {self.name}: num_steps must be >= 1")
        if not 0 < self.light_power_factor <= 1e6 or not np.isfinite(self.light_power_factor):
            raise ValueError(f"job {self.name}: light_power_factor={self.light_power_factor} must be in (0, 1e6]")
        bad = [s for s in self.gt_steps if not 0 <= s < self.num_steps]
        if bad:
            raise ValueError(f"job {self.name}: ground-truth steps {bad[:5]} outside [0, {self.num_steps})")
        if not self.gt_steps:  # --steps 10 --gt-stride 41 wrote scenes every reader refused later (round seven)
            raise ValueError(f"job {self.name}: no ground-truth step in its {self.num_steps} steps (ground truth sits on "
                             f"{WINDOW}-step window centres, step {WINDOW // 2} first at stride {WINDOW}): give more "
                             "--steps or a smaller --gt-stride")

    @property
    def quality_settings(self) -> Any:
        """The job's quality preset (spikesim.quality.QualitySettings), resolved once per name and
        process (resolved_quality); None without one. Every stage of a job reads it here."""
        return None if self.quality is None else resolved_quality(self.quality)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        del d["settings"]
        d["gt_steps"] = list(self.gt_steps)
        d["windows"] = [list(w) for w in self.windows]
        d["inputs"] = dict(sorted(self.inputs.items()))
        if not self.twin:
            del d["twin"]
        return d

    def parameters(self) -> dict[str, Any]:
        """The job without its inputs: what the user chose (`--overwrite` replaces a scene made
        with other parameters; a scene whose inputs changed is rebuilt without it)."""
        d = self.to_dict()
        del d["inputs"]
        return d

    @property
    def digest(self) -> str:
        """The job's identity: its parameters and the content of everything it is made from."""
        return _digest(self.to_dict())

    @property
    def legacy_digest(self) -> str:
        """The digest a scene written before the inputs were part of the identity records: the
        parameters alone (spikesim.generation.run accepts such a scene when the file hashes it
        recorded still match)."""
        return _digest(self.parameters())


def _digest(d: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


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


#: How RLLR draws each scene's darkening factor: "uniform" in (0, 1) (the paper's), or
#: "log-uniform" in [LOG_DARKENING_MIN, 1), which puts as many scenes in each decade of light as in
#: the brightest: with the 30-250 lx lamps, 0.15-250 lx at the subject instead of a 10 % chance of
#: going below 25 lx (what a budgeted model needs to see of the low light it is judged on); or
#: "none" (factor 1: test pairs made as another simulator makes them, content "reds-like").
DARKENINGS = ("uniform", "log-uniform", "none")
LOG_DARKENING_MIN = 0.005


def darkening_factor(rng: np.random.Generator, darkening: str = "uniform") -> float:
    """One RLLR scene's light power factor (DARKENINGS)."""
    if darkening == "log-uniform":
        return float(10.0 ** rng.uniform(np.log10(LOG_DARKENING_MIN), 0.0))
    if darkening == "none":
        return 1.0
    if darkening != "uniform":
        raise ValueError(f"darkening={darkening!r}; expected one of {DARKENINGS}")
    factor = float(rng.uniform(0.0, 1.0))
    while factor == 0.0:  # (0, 1): open at 0
        factor = float(rng.uniform(0.0, 1.0))
    return factor


def rllr_gt_steps(num_steps: int, stride: int) -> tuple[int, ...]:
    """Steps with ground truth in an RLLR scene: every `stride` steps, placed on the centres of
    the 41-step windows that start at step 0 (20, 61, 102, ... for stride 41), since training
    takes K windows centred on ground-truth steps (model/data.py). At the windows' edges (0, 41,
    ...) the first one is unusable and a 164-step scene gave one K=3 sample instead of two."""
    return tuple(range((WINDOW // 2) % stride, num_steps, stride))


#: What RLLR's random scenes are made of: "procedural" (scenes/random_scene.py, value noise,
#: stripes, checkers and discs at 30-250 lx; the content of the first shipped model) or "natural"
#: (scenes/natural_scene.py: dead leaves and package photographs, camera motion, 20-1000 lx) or
#: "photo" (scenes/photo_pan.py: a photograph filling the frame, the camera panning across it and
#: objects crossing in front, as a video frame is; computed, not rendered, so exact ground truth).
CONTENTS = ("procedural", "natural", "photo", "reds-like")
#: "reds-like": test pairs made the way Spk2ImgNet's simulator makes its REDS data (the shared
#: sample's conventions, docs/model.md): photo scenes of pictures no training scene uses
#: (scenes/photo_pan.HELD_OUT_PHOTOS), the picture's 8-bit grey value as intensity, y = 0.6 x
#: intensity (REDS_LIKE_PEAK_Y); give it `--darkening none --camera noiseless`.
REDS_LIKE_PEAK_Y = 0.6
#: The smallest side of a scene at a reduced pixel scale: the training crop (32) must fit.
MIN_SCALED_SIDE = 32


def scaled_size(height: int, width: int, scale: float) -> tuple[int, int]:
    """The frame of a scene rendered at `scale` times the preset's pixels along each side, with the
    same field of view: the same scene seen by a sensor with fewer, larger pixels."""
    if not (isinstance(scale, (int, float)) and 0 < scale <= 1):
        raise ValueError(f"pixel scale {scale!r}: expected a number in (0, 1]")
    if scale == 1:
        return height, width  # the preset's own frame, whatever its size
    h, w = round(height * scale), round(width * scale)
    if min(h, w) < MIN_SCALED_SIDE:
        raise ValueError(f"pixel scale {scale:g} makes {height} x {width} into {h} x {w}: below {MIN_SCALED_SIDE} "
                         "pixels a side, smaller than a training crop")
    return h, w


def plan_rllr(preset: Preset, seed: int = 0, camera: Any | None = None, count: int | None = None,
              source: str = "random", quality: str | None = None, darkening: str = "uniform",
              content: str = "procedural", scales: tuple[float, ...] = (1.0,),
              lamps_lux: tuple[float, float] | None = None, peak_y: float | None = None,
              still_share: float = 0.0) -> list[SceneJob]:
    """RLLR: random scenes, each darkened by a random factor (paper, "RLLR": uniform in (0, 1);
    DARKENINGS for the other choice). A random scene's job records its lamps' range
    (scenes.random_scene.LAMPS_LUX), so scenes built with another range are not taken for finished
    ones; the factor is part of each job, so a dataset drawn another way is never taken for this one.
    `content` picks the scene builder (CONTENTS); with more than one of `scales` each scene draws
    its pixel scale from them (scaled_size), from a random stream of its own so the darkening
    factors and scenes of a one-scale plan are unchanged. `lamps_lux` replaces the content's lamp
    range (lux at the subject, before darkening). `peak_y` replaces a photo scene's white level
    (expected spikes per step before darkening; scenes.photo_pan.PHOTO_PEAK_Y): above 1, bright
    surfaces saturate, and the scene's mean reaches video brightness (REDS-like pairs: mean y 0.22).
    `still_share`: the chance that a photo scene's camera stands still (scenes.photo_pan); recorded
    in its job only when above 0, so every earlier plan is unchanged."""
    from scenes.random_scene import LAMPS_LUX
    if darkening not in DARKENINGS:
        raise ValueError(f"darkening={darkening!r}; expected one of {DARKENINGS}")
    if content not in CONTENTS:
        raise ValueError(f"content={content!r}; expected one of {CONTENTS}")
    if peak_y is not None:
        if not (isinstance(peak_y, (int, float)) and math.isfinite(peak_y) and 0 < peak_y <= 100):
            raise ValueError(f"peak_y={peak_y!r}: expected a white level in (0, 100] spikes per step")
        if content != "photo":
            raise ValueError("peak_y sets the white level of photo content (--content photo)")
    if not (isinstance(still_share, (int, float)) and 0.0 <= still_share <= 1.0):
        raise ValueError(f"still_share={still_share!r}: expected a chance in [0, 1]")
    if still_share > 0 and content != "photo":
        raise ValueError("still_share is the chance that a photo scene's camera stands still (--content photo)")
    if source != "random" and content != "procedural":
        raise ValueError("content applies to random scenes, not the built-in pattern")
    if lamps_lux is not None:
        lo, hi = (float(v) for v in lamps_lux)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise ValueError(f"lamps_lux={lamps_lux!r}: expected 0 < low <= high, finite (lux at the subject)")
        if source != "random":
            raise ValueError("lamps_lux applies to random scenes, not the built-in pattern")
    scales = tuple(float(v) for v in scales)
    if not scales:
        raise ValueError("scales: give at least one pixel scale")
    for v in scales:
        scaled_size(preset.height, preset.width, v)  # validates
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
    scale_rng = np.random.default_rng(np.random.SeedSequence([seed, 11]))
    n = preset.rllr_scenes if count is None else count
    gt = rllr_gt_steps(preset.rllr_steps, preset.rllr_gt_stride)
    jobs = []
    for i in range(n):
        factor = darkening_factor(rng, darkening)
        name = f"rllr_{i:04d}"
        s = scene_seed(seed, name, source)
        if source != "random":
            src = {"type": "pattern", "peak_y": 0.3, "pattern_seed": s}
        elif content == "photo":
            from scenes.photo_pan import PHOTO_PEAK_Y
            src = {"type": "photo", "index": i, "scene_seed": s, "peak_y": float(peak_y or PHOTO_PEAK_Y),
                   "photo_set": "train",
                   "encoding": "linear", **({"still_share": float(still_share)} if still_share > 0 else {})}
        elif content == "reds-like":
            src = {"type": "photo", "index": i, "scene_seed": s, "peak_y": REDS_LIKE_PEAK_Y, "photo_set": "heldout",
                   "encoding": "srgb"}
        elif content == "natural":
            from scenes.natural_scene import NATURAL_LAMPS_LUX
            src = {"type": "random", "index": i, "scene_seed": s, "lamps_lux": list(NATURAL_LAMPS_LUX),
                   "content": "natural"}
        else:
            src = {"type": "random", "index": i, "scene_seed": s, "lamps_lux": list(LAMPS_LUX)}
        if lamps_lux is not None and src["type"] != "photo":
            src["lamps_lux"] = [float(v) for v in lamps_lux]
        scale = scales[0] if len(scales) == 1 else float(scale_rng.choice(scales))
        h, w = scaled_size(preset.height, preset.width, scale)
        cam = _camera_dict(preset, camera)
        cam.update(height=h, width=w)
        render = _render_dict(preset, s)
        render["resolution"] = [h, w]
        jobs.append(SceneJob(name=name, source=src, camera=cam,
                             render=render, num_steps=preset.rllr_steps, gt_steps=gt,
                             light_power_factor=factor, seed=s, keyframe_every=preset.keyframe_every,
                             quality=quality if src["type"] not in UNRENDERED_SOURCES else None))
    return jobs


def power_label(factor: float) -> str:
    """A light power factor as short text that names it exactly: `g` format where that reads back
    as the same number, else Python's shortest exact form (0.1234567 and 0.1234568 must differ)."""
    text = f"{factor:g}"
    return text if float(text) == factor else repr(float(factor))


def user_scene_name(xml: str | Path, light: str, motion: str | Path | None = None, lights: str | Path | None = None,
                    light_power_factor: float = 1.0) -> str:
    """The dataset name of a user's scene: `<folder>_<light>` for a folder's scene.xml with its own
    motion.json and lights.json at full power. Any other variant adds what differs (the XML's,
    motion file's and lights file's names, `x<factor>`), so two variants of one scene in one output
    folder get different names, and a variant always gets the same one."""
    xml = Path(xml).resolve()
    parts = [xml.parent.name] + ([xml.stem] if xml.stem != "scene" else []) + [light]
    for given, default in ((motion, "motion.json"), (lights, "lights.json")):
        if given is not None and Path(given).resolve() != xml.parent / default:
            parts.append(Path(given).stem)
    if light_power_factor != 1.0:
        parts.append(f"x{power_label(light_power_factor)}")
    name = "_".join(parts)
    try:
        return check_scene_name(name)
    except ValueError:
        raise ValueError(f"scene name {name!r} (from the XML's folder, its files and the light) is not a plain "
                         "folder name (letters, digits and _.+-); give one with --name") from None


def plan_user(xml: str, light: str, preset: Preset, num_windows: int | None = None, seed: int = 0,
              motion: str | None = None, lights: str | None = None, camera: Any | None = None,
              light_power_factor: float = 1.0, name: str | None = None, quality: str | None = None,
              length: str = "windows") -> list[SceneJob]:
    """The job of a user's scene. Its length is `length`: "windows" (the preset's llr_windows, or
    `num_windows`, of 41 steps, ground truth at each centre, as LLR) or "steps" (the preset's
    rllr_steps, ground truth every rllr_gt_stride steps on the window centres, as RLLR)."""
    if length == "steps":
        wins, num_steps = (), preset.rllr_steps
        centres = rllr_gt_steps(num_steps, preset.rllr_gt_stride)
    elif length == "windows":
        wins, centres = llr_windows(preset.llr_windows if num_windows is None else num_windows)
        num_steps = wins[-1][1]
    else:
        raise ValueError(f"length={length!r}; expected 'windows' or 'steps'")
    xml_path = Path(xml).resolve()
    if name is None:
        name = user_scene_name(xml_path, light, motion, lights, light_power_factor)
    src = {"type": "scene", "scene": str(xml_path), "light": light,
           "motion": str(Path(motion).resolve()) if motion else None, "lights": str(Path(lights).resolve()) if lights else None}
    s = scene_seed(seed, xml_path.parent.name, light)
    return [SceneJob(name=name, source=src, camera=_camera_dict(preset, camera),
                     render=_render_dict(preset, s), num_steps=num_steps, gt_steps=centres, windows=wins,
                     light_power_factor=light_power_factor, seed=s, keyframe_every=preset.keyframe_every,
                     quality=quality)]
