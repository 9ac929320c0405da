"""`spikesim sweep`: reconstruction quality against light level, from 0.1 lx to past saturation.

    spikesim sweep --methods tfp tfi tfp:205 lrrep -o out/sweep                 # the LLR five, 64 x 100
    spikesim sweep --xml my/scene.xml --light normal --methods tfp lrrep -o out/mine
    spikesim sweep --height 250 --width 400 --levels 13 --methods tfp lrrep -o out/sweep_full

Each scene is rendered once under its light (`normal` by default), and the light is then set to
each level: light transport is linear in the lamps' power, so the frames and the ground truth scale
by level / (the light's illuminance at the subject), with no re-render. Each level is simulated
with the same camera (one seed: the same fixed pattern at every level, as one sensor), every method
reconstructs every window, and each is scored against the ground truth clipped at the sensor's
saturation (model/data.py), as `evaluate` scores.

Writes <out>/sweep.csv (scene, lux, method, every metric), <out>/sweep.md (aligned PSNR and SSIM
by level, mean over scenes) and, with matplotlib, <out>/sweep.png: one line per method, the
saturation edge marked. The saturation edge of a scene is the level at which the 99th percentile of
its ground truth reaches one spike per step, the brightest light at which the stream still tells
99 % of the pixels apart; the plot marks the median over the scenes.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from pipelines.argtypes import seed_int, add_threads_argument, camera_spec, load_camera, positive_float, positive_int
from spikesim.dataset import SATURATION_Y

RESULT_FILES = ("sweep.csv", "sweep.md", "sweep.png", "sweep.json")
#: The reported metrics, in the order of the tables (model.metrics.METRICS keys).
HEADLINE = ("psnr_aligned", "ssim_aligned")
DEFAULT_METHODS = ("tfp", "tfi", "tfp:205", "lrrep")
#: Every metric a row keeps: the headline pair first, then the plain, 8-bit and light-normalised ones.
METRIC_KEYS = HEADLINE + ("ssim", "psnr", "psnr_8bit", "ssim_8bit", "psnr_norm", "ssim_norm")
WINDOW = 41
#: Saturation is reached where this percentile of the ground truth reaches y = 1.
SATURATION_PERCENTILE = 99.0
#: The frame size and samples of a sweep where neither a flag, nor --xml's film and sampler, nor a
#: camera file sets them: the demo's 64 x 100, 2 spp per step, a 32-spp ground truth.
SWEEP_DEFAULTS = {"height": 64, "width": 100, "spp": 2, "gt_spp": 32}
#: A scene's rendered frames are held in memory (one render, every level scales it): at most this.
MAX_FRAMES_BYTES = 4 << 30


@dataclass
class RenderedScene:
    """One scene rendered once at its light: y frames for every step, ground truth at the window
    centres, and the light's illuminance at the subject (lx)."""

    name: str
    frames: np.ndarray
    ground_truth: dict[int, np.ndarray]
    subject_lux: float
    subject_lux_kind: str = "direct, computed at the light file's subject"
    """What subject_lux is (spikesim.render.SceneRenderer.subject_illuminance)."""

    @property
    def saturation_lux(self) -> float:
        """The level (lx at the subject) where the SATURATION_PERCENTILE of the ground truth
        reaches y = 1 (linear in the light: level / subject_lux scales y)."""
        p = float(np.percentile(np.concatenate([g.ravel() for g in self.ground_truth.values()]), SATURATION_PERCENTILE))
        return self.subject_lux * SATURATION_Y / p if p > 0 else math.inf


@dataclass
class LevelScene:
    """A RenderedScene simulated at one light level, as the model's Scene protocol (model/data.py)."""

    name: str
    spikes_all: np.ndarray
    gt: dict[int, np.ndarray]
    num_steps: int = 0
    height: int = 0
    width: int = 0
    gt_steps: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.num_steps, self.height, self.width = self.spikes_all.shape
        self.gt_steps = sorted(self.gt)

    def spikes(self, start: int, stop: int) -> np.ndarray:
        return self.spikes_all[start:stop]

    def ground_truth(self, step: int) -> np.ndarray:
        return self.gt[step]


#: The light levels a sweep takes, lx at the subject: a moonless night's 1e-4 lx to 1e6 lx, ten
#: times direct sunlight. Beyond them a scene's y scale underflows float32 to all-zero frames
#: (--lux-min 1e-42 scored "inf" dB) or overflows it, and every frame is black or saturated anyway.
SWEEP_LUX_RANGE = (1e-4, 1e6)
#: Levels per sweep: each is a whole simulation and scoring of every scene.
MAX_LEVELS = 200


def light_levels(lux_min: float, lux_max: float, levels: int) -> np.ndarray:
    """`levels` log-spaced illuminances (lx) from lux_min to lux_max."""
    lo, hi = SWEEP_LUX_RANGE
    if not (0 < lux_min < lux_max and math.isfinite(lux_max)):
        raise ValueError(f"light levels: expected 0 < --lux-min < --lux-max, got {lux_min} and {lux_max}")
    if not (lo <= lux_min and lux_max <= hi):
        raise ValueError(f"light levels: --lux-min {lux_min:g} and --lux-max {lux_max:g} must lie in {lo:g}-{hi:g} lx "
                         "(beyond, frames underflow or overflow float32 and every frame is black or saturated)")
    if not 2 <= levels <= MAX_LEVELS:
        raise ValueError(f"--levels {levels}: a sweep takes 2 to {MAX_LEVELS} light levels")
    return np.geomspace(lux_min, lux_max, levels)


def render_scene(scene: str, light: str, camera: Any, num_windows: int, spp: int, gt_spp: int, seed: int,
                 motion: str | None = None, lights: str | None = None, name: str | None = None,
                 progress: bool = False) -> RenderedScene:
    """Render every step of `num_windows` windows and the ground truth at their centres, once."""
    from spikesim.render import SceneRenderer
    from spikesim.render_settings import RenderSettings

    renderer = SceneRenderer(scene, light=light, motion=motion, lights=lights, camera=camera,
                             settings=RenderSettings(spp=spp, gt_spp=gt_spp, seed=seed))
    lux, kind = renderer.subject_illuminance()
    if lux is None or not lux > 0:
        why = ("the camera's view centre hits nothing, or an emitter" if lux is None else
               f"the illuminance there is {lux:.3g} lx ({kind})")
        raise ValueError(f"{scene}: light {light!r} has no subject to meter ({why}; a lights.json can name one with "
                         "'subject'), so the sweep's light levels are not defined")
    n = num_windows * WINDOW
    need = n * camera.height * camera.width * 4
    if need > MAX_FRAMES_BYTES:
        raise ValueError(f"--windows {num_windows} at {camera.height} x {camera.width}: the rendered frames would take "
                         f"{need / 2**30:.1f} GiB of memory (at most {MAX_FRAMES_BYTES / 2**30:.0f}); use fewer windows or "
                         "a smaller frame")
    frames = np.empty((n, camera.height, camera.width), dtype=np.float32)
    it = renderer.frames(0, n)
    if progress:
        from tqdm import tqdm
        it = tqdm(it, total=n, desc=f"render {name or Path(scene).stem}", unit="step", leave=False)
    for i, f in enumerate(it):
        frames[i] = f
    gts = {c: np.asarray(renderer.ground_truth(c), dtype=np.float32)
           for c in (i * WINDOW + WINDOW // 2 for i in range(num_windows))}
    from spikesim.render.scene_checks import check_lit
    # as generate refuses it: a black truth scored inf dB and SSIM 1 at every level (round six)
    check_lit(renderer.files.xml, max(float(g.max()) for g in gts.values()), len(gts), renderer.lighting)
    return RenderedScene(name or Path(scene).stem, frames, gts, float(lux), kind)


def simulate_level(rendered: RenderedScene, lux: float, camera: Any, seed: int, backend: str = "auto") -> LevelScene:
    """The scene's stream at `lux` at the subject: frames and ground truth scaled by lux /
    subject_lux (linear light transport), simulated by `camera` with `seed`."""
    from spikesim.simulate import Simulator

    factor = np.float32(lux / rendered.subject_lux)
    stream = Simulator(camera, backend=backend, seed=seed).run(f * factor for f in rendered.frames)
    gts = {c: np.clip(g * factor, 0.0, None) for c, g in rendered.ground_truth.items()}
    return LevelScene(f"{rendered.name}@{lux:.4g}lx", stream.unpack(), gts)


def sweep(rendered: Sequence[RenderedScene], levels: Sequence[float], methods: Sequence[Any], camera: Any,
          seed: int = 0, backend: str = "auto", progress: bool = False) -> list[dict[str, Any]]:
    """Every method at every level on every scene: one row per (scene, lux, method) with every
    metric of model.metrics.METRICS (mean over the scene's windows)."""
    from model.evaluation import evaluate_scene

    rows = []
    total = len(rendered) * len(levels)
    for k, (sc, lux) in enumerate((sc, lux) for sc in rendered for lux in levels):
        level = simulate_level(sc, float(lux), camera, seed, backend)
        # every frame one value once clipped at saturation (a scene saturated all over): any constant scores
        # a perfect fit, so every method read inf dB and SSIM 1, in bold (round six); the scores are undefined
        flat = all(float(np.ptp(np.clip(g, 0.0, SATURATION_Y))) == 0.0 for g in level.gt.values())
        for score in evaluate_scene(level, methods, WINDOW):
            rows.append({"scene": sc.name, "lux": float(lux), "method": score.method, "frames": score.frames,
                         "mean_y": float(np.mean([g.mean() for g in level.gt.values()])),
                         "saturated": bool(lux >= sc.saturation_lux), "ground_truth_constant": flat,
                         **{m: (math.nan if flat else score.value(m)) for m in METRIC_KEYS}})
        if progress:
            best = max(rows[-len(methods):], key=lambda r: r["psnr_aligned"])
            print(f"[sweep] {k + 1}/{total} {sc.name} at {lux:.3g} lx: best {best['method']} "
                  f"{best['psnr_aligned']:.2f} dB aligned", file=sys.stderr)
    return rows


def summary(rows: Sequence[dict[str, Any]], metric: str) -> dict[str, dict[float, float]]:
    """{method: {lux: mean of `metric` over the scenes}}."""
    out: dict[str, dict[float, list[float]]] = {}
    for r in rows:
        out.setdefault(r["method"], {}).setdefault(r["lux"], []).append(r[metric])
    def mean(v: list[float]) -> float:  # a scene whose truth is constant at a level has no score there
        finite = [x for x in v if math.isfinite(x)]
        return float(np.mean(finite)) if finite else math.nan
    return {m: {lux: mean(v) for lux, v in sorted(d.items())} for m, d in out.items()}


def losing_levels(rows: Sequence[dict[str, Any]], method: str, saturation_lux: float) -> list[float]:
    """The levels below saturation where `method`'s mean aligned PSNR is not the best of all methods."""
    table = summary(rows, "psnr_aligned")
    if method not in table:
        return []
    out = []
    for lux, value in table[method].items():
        if lux < saturation_lux and any(t[lux] > value for m, t in table.items() if m != method):
            out.append(lux)
    return out


def markdown(rows: Sequence[dict[str, Any]], methods: Sequence[str], saturation_lux: float) -> str:
    lines = [f"Mean over {len({r['scene'] for r in rows})} scene(s); saturation edge (median over scenes, where "
             f"the {SATURATION_PERCENTILE:g}th percentile of y reaches 1): {saturation_lux:.4g} lx.", ""]
    for metric, label, fmt in (("psnr_aligned", "aligned PSNR (dB)", "{:.2f}"), ("ssim_aligned", "aligned SSIM", "{:.4f}")):
        table = summary(rows, metric)
        luxes = sorted(next(iter(table.values())))
        lines += [f"**{label}**", "", "| lux | " + " | ".join(methods) + " |",
                  "|---|" + "---|" * len(methods)]
        for lux in luxes:
            vals = [table[m][lux] for m in methods]
            best = max((v for v in vals if math.isfinite(v)), default=None)
            cells = ["n/a" if not math.isfinite(v) else ("**" + fmt.format(v) + "**") if v == best else fmt.format(v)
                     for v in vals]
            mark = " (saturated)" if lux >= saturation_lux else ""
            lines.append(f"| {lux:.3g}{mark} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def plot(rows: Sequence[dict[str, Any]], methods: Sequence[str], saturation_lux: float, path: Path,
         title: str) -> Path:
    """Aligned PSNR and aligned SSIM against lux (log axis), a line per method, the saturation edge marked."""
    from spikesim._optional import require
    require("matplotlib", "plot", "the sweep plot")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from spikesim.outputs import atomic_write_with

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, (metric, label) in zip(axes, (("psnr_aligned", "aligned PSNR (dB)"), ("ssim_aligned", "aligned SSIM"))):
        table = summary(rows, metric)
        for m in methods:
            luxes = sorted(table[m])
            ax.plot(luxes, [table[m][x] for x in luxes], marker="o", ms=3, label=m)
        if math.isfinite(saturation_lux):
            ax.axvline(saturation_lux, color="k", ls="--", lw=1)
            ax.text(saturation_lux, ax.get_ylim()[0], " saturation", rotation=90, va="bottom", ha="right", fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel("illuminance at the subject (lx)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    atomic_write_with(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)
    return path


@dataclass
class SweepResult:
    """What a sweep measured: a row per (scene, level, method), the record sweep.json keeps (levels,
    saturation, scenes, camera, settings, the levels each method does not lead), and the tables."""

    rows: list[dict[str, Any]]
    record: dict[str, Any]
    markdown: str


def run_sweep(scenes: Sequence[str] = ("ball", "car", "cook", "fan", "rotate"), methods: Sequence[str] = DEFAULT_METHODS,
              levels: Sequence[float] | None = None, light: str = "normal", camera: Any = None, windows: int = 5,
              spp: int = 2, gt_spp: int = 32, seed: int = 0, backend: str = "auto", out: str | Path | None = None,
              draw_plot: bool = True, progress: bool = False) -> SweepResult:
    """The sweep as a library function (a notebook runs it without argparse): each scene (a bundled
    name or a scene XML) rendered once under `light`, simulated at every level (lx at the subject;
    default light_levels()'s nine from 0.1 to 3000), every method scored; with `out`, sweep.csv,
    .md, .json and .png written there (atomically; a link refused before the work)."""
    from model.methods import method_from_spec
    from spikesim.generation import bundled_scene
    from spikesim.outputs import atomic_write_json, atomic_write_text, output_folder, writable
    from spikesim.render.scene_files import SceneFiles

    # the library's own checks, as the command's parser makes them (round seven: [] raised StopIteration after
    # the renders, "ball" was read as its letters, a level of -1 failed after rendering naming no level)
    for name, given in (("scenes", scenes), ("methods", methods)):
        if isinstance(given, (str, bytes)) or not isinstance(given, Sequence) or not given:
            raise ValueError(f"{name}: expected a non-empty list, got {given!r}")
    if levels is not None:
        if isinstance(levels, (str, bytes)):
            raise ValueError(f"levels: expected lux values, got {levels!r}")
        try:
            levels = [float(v) for v in levels]
        except (TypeError, ValueError):
            raise ValueError(f"levels: expected lux values, got {levels!r}") from None
        lo, hi = SWEEP_LUX_RANGE
        if not levels or not all(lo <= v <= hi for v in levels):
            raise ValueError(f"levels: expected at least one level, each in {lo:g}-{hi:g} lx, got {levels}")
    if camera is not None and not all(hasattr(camera, k) for k in ("height", "width", "replace")):
        raise TypeError(f"camera: expected a SpikeCamera (e.g. SpikeCamera.preset({camera!r})), got {type(camera).__name__}")
    levels = np.asarray(light_levels(0.1, 3000.0, 9) if levels is None else levels, dtype=np.float64)
    seen = [s for i, s in enumerate(scenes) if s in scenes[:i]]
    if seen:
        raise ValueError(f"scenes: {', '.join(dict.fromkeys(seen))} given twice (each scene is scored once)")
    method_objs = [method_from_spec(s, WINDOW) for s in methods]
    names = [m.name for m in method_objs]
    if len(set(names)) != len(names):
        raise ValueError(f"method names must be unique, got {names}; name them with label=spec")
    from spikesim.camera import SpikeCamera
    camera = camera if camera is not None else SpikeCamera.realistic(height=64, width=100)
    if min(camera.height, camera.width) < 11:  # before the renders, not after them (round six)
        raise ValueError(f"a {camera.height} x {camera.width} frame: the aligned SSIM's 11 x 11 window needs frames of "
                         "at least 11 x 11 (--height, --width)")
    if out is not None:
        out = Path(out)
        for name in RESULT_FILES:
            writable(out, name)  # a link where results go: refused before the work
        from spikesim.dataset import check_outside_datasets
        check_outside_datasets(out)  # tables written into a dataset (round eleven)
    ours: list[str] = []
    with contextlib.ExitStack() as held:
        from spikesim.signals import sigterm_raises
        # SIGTERM as Ctrl-C: it left the scene's textures in a temporary folder and the lock in -o (round eleven)
        held.enter_context(sigterm_raises())
        if out is not None:  # the folder is this run's until it ends: two sweeps wrote a mix of each other's tables
            from spikesim.generation.lock import output_lock
            held.enter_context(output_folder(out))
            held.enter_context(output_lock(out, "sweep", what="sweep run"))
            from spikesim.outputs import check_results_owned
            ours = check_results_owned(out, RESULT_FILES, "sweep")  # a user's sweep.md is refused, not replaced (round eight)
        sources = []
        for s in scenes:
            if str(s).lower().endswith(".xml"):
                SceneFiles.resolve(str(s))  # a missing file is named before rendering
                sources.append((str(s), Path(s).parent.name))
            else:
                sources.append((bundled_scene(s), s))
        rendered = []
        for i, (scene, name) in enumerate(sources):
            rendered.append(render_scene(scene, light, camera, windows, spp, gt_spp, seed + i, name=name,
                                         progress=progress and sys.stderr.isatty()))
            if progress:
                r = rendered[-1]
                print(f"[sweep] rendered {name}: {r.subject_lux:.4g} lx at the subject under {light!r} "
                      f"({r.subject_lux_kind}), "
                      f"saturation edge {r.saturation_lux:.4g} lx", file=sys.stderr)
        rows = sweep(rendered, levels, method_objs, camera, seed=seed, backend=backend, progress=progress)
        saturation = float(np.median([r.saturation_lux for r in rendered]))
        md = markdown(rows, names, saturation)
        record = {"levels_lux": levels.tolist(), "saturation_lux": saturation,
                  "scenes": {r.name: {"subject_lux": r.subject_lux, "subject_lux_is": r.subject_lux_kind,
                                       "saturation_lux": r.saturation_lux} for r in rendered},
                  "methods": names, "camera": camera.to_dict(), "windows": windows, "spp": spp,
                  "gt_spp": gt_spp, "seed": seed, "light": light,
                  "not_best_below_saturation": {m: losing_levels(rows, m, saturation) for m in names}}
        if out is not None:
            from spikesim.outputs import results_writing
            written = [name for name in RESULT_FILES if draw_plot or name != "sweep.png"]
            # checked again (a file the user put there while it ran: round ten); the earlier run's
            # results removed first (a --no-plot rerun drops the old plot: round ten) and each new one
            # recorded as it is written, so a sweep stopped while plotting leaves only its own tables,
            # which the rerun replaces (round twelve: refused, beside the last run's plot)
            with results_writing(out, written, "sweep", stale=ours):
                buf = io.StringIO(newline="")
                w = csv.DictWriter(buf, fieldnames=list(rows[0]))
                w.writeheader()
                w.writerows(rows)
                atomic_write_text(writable(out, "sweep.csv"), buf.getvalue())
                atomic_write_text(writable(out, "sweep.md"), md)
                atomic_write_json(writable(out, "sweep.json"), record, indent=1)
                if draw_plot:
                    plot(rows, names, saturation, writable(out, "sweep.png"),
                         f"{', '.join(r.name for r in rendered)} at {camera.height} x {camera.width}, {windows} windows")
        return SweepResult(rows, record, md)


def run(args: argparse.Namespace) -> int:
    """The command: a thin parser over run_sweep."""
    from model.threads import set_cpu_threads

    set_cpu_threads(args.threads)
    levels = light_levels(args.lux_min, args.lux_max, args.levels)
    if args.xml is not None and args.scenes:
        raise ValueError("give --scenes (bundled scenes) or --xml (your own), not both")
    scenes = [str(args.xml)] if args.xml is not None else (args.scenes or ["ball", "car", "cook", "fan", "rotate"])
    from spikesim.generation.settings import resolve_command_settings
    # the frame size and samples, each with its origin: the defaults, then (for --xml) the scene's film and
    # sampler, a camera file's size, then the flags, as render and generate scene decide them
    resolved = resolve_command_settings(args.xml, SWEEP_DEFAULTS, camera=args.camera, flags={
        "--height": {"height": args.height}, "--width": {"width": args.width}, "--spp": {"spp": args.spp},
        "--gt-spp": {"gt_spp": args.gt_spp}})
    values = resolved.values
    if not args.quiet:
        print("[sweep] settings: " + ", ".join(f"{k} {values[k]} ({resolved.origins[k]})" for k in SWEEP_DEFAULTS),
              file=sys.stderr)
    camera = load_camera(args.camera or "realistic").replace(height=values["height"], width=values["width"])
    result = run_sweep(scenes, args.methods, levels, light=args.light, camera=camera, windows=args.windows,
                       spp=values["spp"], gt_spp=values["gt_spp"], seed=args.seed, backend=args.backend, out=Path(args.out),
                       draw_plot=not args.no_plot, progress=not args.quiet)
    if args.json:
        from spikesim.config_io import standard_json
        print(standard_json({**result.record, "rows": result.rows}, indent=1))  # no Infinity: strict readers refuse it
    else:
        print(result.markdown)
        print(f"[sweep] wrote {args.out}/sweep.csv, sweep.md, sweep.json" + ("" if args.no_plot else ", sweep.png"),
              file=sys.stderr)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    from spikesim.simulate import BACKENDS

    p = sub.add_parser("sweep", help="reconstruction quality against light level (0.1 lx to past saturation)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", nargs="+", help="bundled scenes (default: the LLR five, ball car cook fan rotate)")
    p.add_argument("--xml", type=Path, help="your own scene XML instead (with its lights.json and motion.json)")
    p.add_argument("--light", default="normal", help="the lighting condition the levels scale (default: normal)")
    p.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS),
                   help="methods as in evaluate (default: tfp tfi tfp:205 lrrep)")
    p.add_argument("--lux-min", type=positive_float, default=0.1, help="dimmest level, lx at the subject (0.1)")
    p.add_argument("--lux-max", type=positive_float, default=3000.0,
                   help="brightest level, lx at the subject (3000: past the saturation of the LLR scenes)")
    p.add_argument("--levels", type=positive_int, default=9, help="log-spaced light levels (9)")
    p.add_argument("--height", type=positive_int, help="frame rows (default: --xml's film or a camera file's, else 64, "
                                                        "the demo's)")
    p.add_argument("--width", type=positive_int, help="frame columns (default: --xml's film or a camera file's, else 100)")
    p.add_argument("--windows", type=positive_int, default=5, help="41-step windows per scene (5)")
    p.add_argument("--spp", type=positive_int, help="samples per pixel of each step's render (default: --xml's sampler, "
                                                     "else 2)")
    p.add_argument("--gt-spp", type=positive_int, help="samples per pixel of the ground truth (default 32)")
    p.add_argument("--camera", type=camera_spec, default=None,
                   help="realistic, measured, noiseless, scsim or a camera file, whose height and width are used "
                        "(default: realistic)")
    p.add_argument("--backend", choices=BACKENDS, default="auto", help="sensor implementation (default: auto)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the renders and the sensor")
    p.add_argument("-o", "--out", type=Path, required=True, help="folder for sweep.csv, sweep.md, sweep.json, sweep.png")
    p.add_argument("--no-plot", action="store_true", help="no sweep.png (no matplotlib needed)")
    add_threads_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--json", action="store_true", help="print the record and every row as JSON")
    p.set_defaults(func=run)
