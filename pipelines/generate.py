"""`spikesim generate` and `spikesim verify`: the command line of dataset generation
(spikesim.generation plans and runs the jobs; a Python script can use it the same way) and of
the check of a dataset against its manifest."""
from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
from pathlib import Path

from pipelines.argtypes import (seed_int, add_device_argument, bounded_count, add_light_power_factor_argument, camera_spec, existing_file,
                                float_in, load_camera, positive_float, positive_int)
from spikesim._drjit import resolve_device
from spikesim.dataset import check_scene_name
from spikesim.generation.plan import CONTENTS, DARKENINGS, LOG_DARKENING_MIN
from spikesim.generation import (PRESETS, bundled_scene, generate, percent, plan_llr, plan_rllr, plan_user,
                                 saturation_summary)
from spikesim.signals import TERMINATED_STATUS as TERMINATED, Terminated
from spikesim.generation.settings import ResolvedSettings, resolve_settings
from spikesim.quality import QUALITIES

# ---- command line ---------------------------------------------------------------------------------
def _llr_scene(text: str) -> str:
    """argparse type: a bundled LLR scene name."""
    try:
        return bundled_scene(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _pixel_scale(text: str) -> float:
    """argparse type: a pixel scale in (0, 1]."""
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not 0 < v <= 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a pixel scale in (0, 1]")
    return v


def _plain_name(text: str) -> str:
    """argparse type: a plain name (a light, a scene folder), never a path."""
    try:
        return check_scene_name(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a plain name (letters, digits and _.+-, "
                                         "not starting with a dot)") from None


# Options that only some kinds take: given to another kind, they would be silently ignored.
_ONLY_FOR = {
    "scenes": ("llr",), "count": ("rllr",), "pattern": ("rllr",), "darkening": ("rllr",), "content": ("rllr",), "scales": ("rllr",), "lamps_lux": ("rllr",), "peak_y": ("rllr",), "still_share": ("rllr",), "steps": ("rllr", "scene"), "gt_stride": ("rllr", "scene"),
    "windows": ("llr", "scene"), "xml": ("scene",), "motion": ("scene",), "lights": ("scene",),
    "light": ("scene",), "light_power_factor": ("scene",), "name": ("scene",),
}


def _refuse_options_for_other_kinds(args: argparse.Namespace) -> None:
    for dest, kinds in _ONLY_FOR.items():
        if args.kind not in kinds and getattr(args, dest) not in (None, False):
            flag = "--" + dest.replace("_", "-")
            raise ValueError(f"{flag} applies to generate {' and '.join(kinds)}, not generate {args.kind}")
    if args.kind == "scene" and args.windows is not None and (args.steps is not None or args.gt_stride is not None):
        raise ValueError("--windows and --steps/--gt-stride are two ways to give a scene's length: windows of 41 steps "
                         "with ground truth at their centres, or a number of steps with ground truth every --gt-stride "
                         "steps (as RLLR); give one")


#: Options that set a preset's value: option dest -> the preset's field.
_PRESET_OPTIONS = {"height": "height", "width": "width", "spp": "spp", "gt_spp": "gt_spp",
                   "keyframe_every": "keyframe_every", "steps": "rllr_steps", "gt_stride": "rllr_gt_stride",
                   "windows": "llr_windows", "count": "rllr_scenes"}


def settings_from_args(args: argparse.Namespace) -> ResolvedSettings:
    """The preset, scene file, settings file, flags and quality, merged (spikesim.generation.settings)."""
    flags = {"--" + dest.replace("_", "-"): {field: getattr(args, dest)} for dest, field in _PRESET_OPTIONS.items()}
    return resolve_settings(args.kind, args.preset or "small", xml=args.xml, settings_file=args.render_settings,
                            flags=flags, quality=args.quality, camera=args.camera, preset_given=args.preset is not None)


def _estimate_only(args: argparse.Namespace, jobs: list, device: str, resolved: ResolvedSettings) -> int:
    """The plan's renders and time as `generate` would print them before starting, every job
    counted (what -o already holds is not looked at), and nothing written."""
    from spikesim.generation.estimate import estimate
    from spikesim.generation.run import local_workers
    est = estimate(jobs, local_workers(jobs, args.workers, device), device, calibrate_at=0,
                   sample_scenes=args.estimate_scenes)
    if args.json:
        print(json.dumps({"settings": resolved.table(), "estimate": {
            "renders": est.renders, "gt_renders": est.gt_renders, "seconds": est.seconds, "workers": est.workers,
            "scenes_read": est.motion_scenes, "samples": [list(p) for p in est.samples],
            "calibration": dataclasses.asdict(est.calibration) if est.calibration else None}}, indent=2, default=str))
    else:
        print(est.summary())
    return 0


def lamps_lux(text: str) -> float:
    """argparse type: an RLLR lamp level, lux at the subject, no brighter than a real light
    (spikesim.render.lights.MAX_ILLUMINANCE_LUX: direct sunlight); 1e30 passed the parser and then
    failed inside a scene's work folder."""
    from spikesim.render.lights import MAX_ILLUMINANCE_LUX
    value = positive_float(text)
    if value > MAX_ILLUMINANCE_LUX:
        raise argparse.ArgumentTypeError(f"{text} lx is brighter than any real light (at most {MAX_ILLUMINANCE_LUX:g} "
                                         "lx, direct sunlight)")
    return value


def run(args: argparse.Namespace) -> int:
    _refuse_options_for_other_kinds(args)
    if args.kind == "scene" and args.xml is None:
        raise ValueError("generate scene needs --xml (and usually --motion, --lights, --light)")
    resolved = settings_from_args(args)
    preset = resolved.preset
    device = resolve_device(args.device)  # a GPU that is not here fails before anything is written
    camera = load_camera(args.camera) if args.camera is not None else None
    if args.kind == "llr":
        jobs = plan_llr(preset, seed=args.seed, camera=camera, scenes=args.scenes, quality=args.quality)
    elif args.kind == "rllr":
        jobs = plan_rllr(preset, seed=args.seed, camera=camera, count=args.count,
                         source="pattern" if args.pattern else "random", quality=args.quality,
                         darkening=args.darkening or "uniform", content=args.content or "procedural",
                         scales=tuple(args.scales) if args.scales else (1.0,),
                         lamps_lux=None if args.lamps_lux is None else tuple(args.lamps_lux),
                         peak_y=args.peak_y, still_share=args.still_share or 0.0)
    else:
        jobs = plan_user(str(args.xml), args.light or "normal", preset, seed=args.seed,
                         motion=None if args.motion is None else str(args.motion),
                         lights=None if args.lights is None else str(args.lights), camera=camera,
                         light_power_factor=1.0 if args.light_power_factor is None else args.light_power_factor,
                         name=args.name, quality=args.quality, length="steps" if resolved.kind == "scene-steps" else "windows")
    if not args.json:
        print(resolved.summary())
    jobs = [dataclasses.replace(job, settings=resolved.table(), twin=args.twin) for job in jobs]
    if args.estimate_only:
        return _estimate_only(args, jobs, device, resolved)
    try:
        report = generate(jobs, args.out, workers=args.workers, ray_address=args.ray,
                          info={"kind": args.kind, "preset": preset.to_dict(), "seed": args.seed},
                          overwrite_stale=args.overwrite, show_progress=not args.quiet, check=args.check,
                          estimate_time=args.estimate_time, estimate_scenes=args.estimate_scenes,
                          command="spikesim " + shlex.join(sys.argv[1:]), device=device)
    except Terminated as exc:
        print(f"spikesim generate: {exc}: the scenes in progress were removed and finished ones kept; "
              "rerun the same command to continue", file=sys.stderr)
        return TERMINATED
    except KeyboardInterrupt:  # Ctrl-C: the same, said the same way (it used to say only "interrupted")
        print("spikesim generate: interrupted: the scenes in progress were removed and finished ones kept; "
              "rerun the same command to continue", file=sys.stderr)
        return 130
    saturation = report["saturation"]
    if args.json:
        print(json.dumps({"settings": resolved.table(), **report}, indent=2, default=str))
        return 0
    for r in report["generated"]:
        lux = r.get("subject_illuminance_lux")
        print(f"  {r['name']}: {r['seconds']:.1f} s, {r['bytes'] / 1e6:.2f} MB, "
              f"{percent(saturation.get(r['name']))} of ground-truth pixels saturated"
              + (f", {lux:.4g} lx at the subject" if lux is not None else "")
              + (" (metered: direct and indirect)" if str(r.get("subject_illuminance", "")).startswith("total") else "")
              + (f" (rebuilt: {r['rebuilt']})" if r.get("rebuilt") else ""))
    renders = sum(int(r.get("renders", 0)) for r in report["generated"])
    print(f"{args.out}: {len(report['generated'])} scene(s) generated, {report['skipped']} already complete, "
          f"{report['seconds']:.1f} s" + (f", {renders:,} renders (probes, motion-blur sub-steps and ground truth "
                                        "included)" if renders else "") + f"; manifest {report['manifest']}")
    if report["checked"] == "sizes" and report["skipped"]:
        print(f"{report['skipped']} finished scene(s) were checked by file size only (quick: catches deleted and "
              f"truncated files); --check also compares every file's sha256 and rebuilds what differs, "
              f"and spikesim verify {args.out} reports it")
    line = saturation_summary(saturation)
    if line is not None:
        print(line)
    return 0



VERIFY_INTACT, VERIFY_DAMAGED, VERIFY_EXTRAS = 0, 1, 3
VERIFY_EPILOG = (f"exit status: {VERIFY_INTACT} intact; {VERIFY_DAMAGED} damaged (a listed file missing, truncated "
                 "or altered, or a listed path outside the root, which is not read); 2 bad input (no dataset, a "
                 f"malformed manifest); {VERIFY_EXTRAS} intact with extra files (files the manifest does not list, "
                 "such as debris of an interrupted run: not damage)")


def run_verify(args: argparse.Namespace) -> int:
    from spikesim.dataset import DatasetBusyError, check_dataset, writer_of
    if (writer := writer_of(args.root)) is not None:  # it reported "intact with 1 extra file" mid-run (round seven)
        raise DatasetBusyError(f"{args.root}: a generate run is writing it now ({writer}); verify it when that run "
                               "has finished")
    found = check_dataset(args.root, checksums=not args.quick)
    status = VERIFY_DAMAGED if found.problems else (VERIFY_EXTRAS if found.extras else VERIFY_INTACT)
    if args.json:
        print(json.dumps({"root": str(args.root), "scenes": found.scenes, "problems": found.problems,
                          "extras": found.extras, "status": status}, indent=2))
        return status
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


#: The most RLLR scenes one command plans: a thousand times the paper's 100; a plan of 10^8 scenes
#: grew to 3.3 GB before any work.
MAX_RLLR_SCENES = 100_000


#: The most steps one scene may have: 2.5 s at 40 kHz, 1.25 GB of spikes at 400 x 250. A million
#: steps planned for 15 minutes before --estimate-only answered (round seven); a longer recording is
#: several scenes.
MAX_SCENE_STEPS = 100_000


def scene_steps(text: str) -> int:
    """--steps: a positive number of steps, at most MAX_SCENE_STEPS."""
    v = positive_int(text)
    if v > MAX_SCENE_STEPS:
        raise argparse.ArgumentTypeError(f"at most {MAX_SCENE_STEPS:,} steps a scene (2.5 s at 40 kHz), got {text}; "
                                         "a longer recording is several scenes")
    return v


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("generate", help="generate LLR, RLLR or a user dataset (resumable, parallel)")
    p.add_argument("kind", choices=["llr", "rllr", "scene"],
                   help="llr: the five LLR scenes; rllr: random 3D scenes, darkened; scene: your own --xml")
    p.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="dataset size: small (a quick check; the default) or paper (the paper's sizes); a user "
                        "scene given none keeps small's size with its ground truth at 64 spp, not small's grainy 16")
    p.add_argument("-o", "--out", type=Path, required=True, help="dataset root (resumable: rerun to continue)")
    p.add_argument("--seed", type=seed_int, default=0,
                   help="dataset seed; each scene's seed derives from it, the scene's name and its light")
    p.add_argument("--scenes", nargs="+", type=_llr_scene, help="LLR scenes by name (default: the preset's)")
    p.add_argument("--count", type=bounded_count(MAX_RLLR_SCENES, "scenes"),
                   help=f"RLLR scenes (default: the preset's; at most {MAX_RLLR_SCENES:,}: every job is planned at once)")
    p.add_argument("--darkening", choices=DARKENINGS,
                   help="how each RLLR scene's light power factor is drawn: uniform in (0, 1) (the paper's, the "
                        f"default), log-uniform in [{LOG_DARKENING_MIN}, 1) (as many scenes per decade of light) or none "
                        "(factor 1: test pairs)")
    p.add_argument("--content", choices=CONTENTS,
                   help="what RLLR's random scenes are made of: procedural (value noise, stripes, checkers, discs; "
                        "30-250 lx lamps; the default, the first shipped model's data) or natural (dead-leaves "
                        "textures, package photographs, image-textured cards, camera pans and shake; 20-1000 lx lamps), photo (a "
                        "photograph filling the frame, the camera panning across it, objects crossing in front, as in "
                        "a video; computed, not rendered: exact ground truth, seconds per scene) or reds-like (test "
                        "pairs as Spk2ImgNet's simulator makes REDS data, pictures no training scene uses; with "
                        "--darkening none --camera noiseless)")
    p.add_argument("--scales", type=_pixel_scale, nargs="+", metavar="S",
                   help="RLLR pixel scales: each scene is rendered at one of them, drawn at random, times the preset's "
                        "height and width with the same field of view (e.g. 1 0.5 0.25; default 1)")
    p.add_argument("--lamps-lux", type=lamps_lux, nargs=2, metavar=("LOW", "HIGH"),
                   help="RLLR lamps' illuminance at the subject before darkening, lux, drawn log-uniformly (default: "
                        "the content's, 30-250 procedural, 20-1000 natural)")
    p.add_argument("--still-share", type=float_in(0.0, 1.0, "a chance"), metavar="P",
                   help="photo content: the chance that a scene's camera stands still while objects cross (static "
                        "backgrounds, as LLR's; default 0: every camera moves)")
    p.add_argument("--peak-y", type=positive_float, metavar="Y",
                   help="photo content: white's expected spikes per step before darkening (default 0.8; above 1 bright "
                        "surfaces saturate and scenes reach video brightness)")
    p.add_argument("--pattern", action="store_true", help="RLLR from the built-in pattern instead of random 3D scenes")
    p.add_argument("--xml", type=existing_file, help="scene XML (generate scene)")
    p.add_argument("--motion", type=existing_file, help="motion file (default: motion.json beside the XML)")
    p.add_argument("--lights", type=existing_file, help="lights file (default: lights.json beside the XML)")
    p.add_argument("--light", type=_plain_name, help="lighting condition in the lights file (default: normal)")
    p.add_argument("--name", type=_plain_name, help="scene folder name (generate scene; default: <XML folder>_<light>, plus the XML's, motion "
                        "and lights files' names and x<factor> for other variants of the folder's scene)")
    add_light_power_factor_argument(p)
    p.add_argument("--windows", type=positive_int, help="41-step windows per scene (llr, scene)")
    p.add_argument("--steps", type=scene_steps,
                   help=f"steps per RLLR scene (paper 1000; at most {MAX_SCENE_STEPS:,}), or of a user scene instead of "
                        "--windows (default: the preset's RLLR steps once --gt-stride is given)")
    p.add_argument("--gt-stride", type=positive_int,
                   help="ground truth every this many steps of an RLLR scene (paper 1) or of a user scene given "
                        "--steps, on the centres of 41-step windows (stride 41: steps 20, 61, 102, ...; default: "
                        "the preset's RLLR stride)")
    p.add_argument("--gt-spp", type=positive_int, help="samples per pixel of a ground-truth image, spread over its motion-blur sub-step renders")
    p.add_argument("--camera", type=camera_spec,
                   help="realistic, measured (with the terms measured on a real recording), noiseless, scsim (SCSim's constants) or a JSON/TOML camera file (default: realistic); a file's height and "
                        "width are used above the preset and a scene's film, below --render-settings and the flags")
    p.add_argument("--render-settings", type=existing_file, metavar="FILE",
                   help="JSON/TOML file of render settings (spp, gt_spp, variant, keyframe_every, resolution); "
                        "above the preset and a scene's own film, below the flags")
    p.add_argument("--height", type=positive_int,
                   help="sensor and film rows (default: a user scene's film, else the preset's)")
    p.add_argument("--width", type=positive_int,
                   help="sensor and film columns (default: a user scene's film, else the preset's)")
    p.add_argument("--spp", type=positive_int,
                   help="samples per pixel of each frame render (default: a user scene's sampler, else the preset's)")
    p.add_argument("--keyframe-every", type=positive_int,
                   help="render every this many steps; the sensor interpolates (default: the preset's, 1)")
    p.add_argument("--quality", choices=list(QUALITIES),
                   help="render/sensor knobs from spikesim.quality (measured presets; docs/tradeoff.md; "
                        "fast: samples chosen by the scene's light, the paper LLR in under 10 minutes on 2 "
                        "cores); overrides --spp/--keyframe-every and the variant")
    p.add_argument("--twin", action="store_true",
                   help="also write each scene's noise-free twin stream (spikes_twin.dat: the same frames and "
                        "initial state, every noise term off; one more sensor pass, no more renders), for "
                        "self-supervised denoisers and noise studies")
    p.add_argument("--workers", type=positive_int, help="local processes (default: one per core; one with a GPU)")
    add_device_argument(p)
    p.add_argument("--ray", metavar="ADDRESS", help="run on a Ray cluster ('auto', an address, or 'local')")
    p.add_argument("--overwrite", action="store_true", help="rebuild scenes generated with other parameters")
    p.add_argument("--check", action="store_true",
                   help="before skipping a finished scene, check every file's sha256 against the checksums recorded "
                        "when it was written (default: sizes only, which catches deleted and truncated files); "
                        "damaged scenes are rebuilt")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    est = p.add_mutually_exclusive_group()
    est.add_argument("--estimate", dest="estimate_time", action="store_true", default=None,
                     help="calibrate and estimate the time before starting even for a small plan (default: for "
                          "plans of 2,000 renders or more; a few seconds)")
    est.add_argument("--no-estimate", dest="estimate_time", action="store_false",
                     help="start at once, without the calibration (default: calibrate for plans of 2,000 renders or more)")
    est.add_argument("--estimate-only", action="store_true",
                     help="print the plan's renders and time estimate and stop: nothing is generated or written "
                          "(every job counted, whatever -o holds)")
    p.add_argument("--estimate-scenes", type=positive_int, default=None, metavar="N",
                   help="scenes the estimate reads (motion, render speed and, with --quality fast, samples; "
                        "default 6, every scene with --quality fast; the others at their mean, with the spread "
                        "that leaves); more is slower and closer")
    p.add_argument("--json", action="store_true", help="print the settings and the run's report as JSON")
    p.set_defaults(func=run)
    v = sub.add_parser("verify", help="check a dataset against its manifest", epilog=VERIFY_EPILOG,
                       description="Check every file the manifest lists (size and sha256), reading only inside the "
                                   "dataset root, and list files the manifest does not.")
    v.add_argument("root", type=Path, help="dataset root (the folder holding manifest.json)")
    v.add_argument("--quick", action="store_true", help="sizes only, no checksums")
    v.add_argument("--json", action="store_true", help="print the problems and extra files as JSON")
    v.set_defaults(func=run_verify)
