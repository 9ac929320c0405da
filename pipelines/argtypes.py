"""Argument types for the command line: a bad value is refused by the parser with a message
that names the flag (argparse adds it), never silently treated as "not given".

Use them as `type=` in `add_argument`; argparse turns the `ArgumentTypeError` into
`spikesim CMD: error: argument --flag: <message>` and exit status 2.
"""
from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from spikesim.camera import CAMERA_PRESETS


def _number(text: str, kind: type) -> float | int:
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None


def positive_int(text: str) -> int:
    """An integer >= 1 (a count, a size, a step)."""
    v = _number(text, int)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return v


#: The y a PNG's white may stand for (export --rate, evaluate --spikezoo --rate): a level is 1/255 of
#: it, so a rate far above the saturation's y = 1 makes every image black (1e300 did, rc 0) and one
#: below 1e-6 every lit pixel white.
PNG_RATE_RANGE = (1e-6, 1.0)


def png_rate(text: str) -> float:
    """--rate: the y of a ground-truth PNG's white, in PNG_RATE_RANGE."""
    v = positive_float(text)
    lo, hi = PNG_RATE_RANGE
    if not lo <= v <= hi:
        raise argparse.ArgumentTypeError(f"must be a y in {lo:g}..{hi:g} (the saturation, y = 1, at most; "
                                         f"Spike-Zoo's REDS use 0.6), got {text}")
    return v


def window_steps(text: str) -> int:
    """--window: an odd number of readout steps >= 1, so that a window has a centre step (its
    ground truth's; model.reconstruct takes the same rule)."""
    v = positive_int(text)
    if v % 2 == 0:
        raise argparse.ArgumentTypeError(f"must be an odd number of steps (a window's centre is its ground-truth "
                                         f"step; 41 for the shipped networks), got {text}")
    return v


def float_in(lo: float, hi: float, what: str):
    """argparse type: a number in [lo, hi] (a chance, a percentile), the error naming `what`."""
    def parse(text: str) -> float:
        v = _number(text, float)
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"must be {what} from {lo:g} to {hi:g}, got {text}")
        return v
    parse.__name__ = what.split()[-1]
    return parse


def readout_period_s(text: str) -> float:
    """argparse type: a readout period a spike camera can have (spikesim.camera.READOUT_PERIOD_RANGE_S);
    --readout-period-s 1e9 printed a 6-million-year stream at 0 Hz (round seven)."""
    from spikesim.camera import READOUT_PERIOD_RANGE_S
    lo, hi = READOUT_PERIOD_RANGE_S
    v = _number(text, float)
    if not lo <= v <= hi:
        raise argparse.ArgumentTypeError(f"must be a readout period from {lo:g} to {hi:g} s (10 MHz to 1 Hz; "
                                         f"spike cameras read out every 25e-6 s), got {text}")
    return v


def bounded_count(limit: int, what: str):
    """argparse type: an integer in 1..limit (a count whose plan is held in memory at once)."""
    def parse(text: str) -> int:
        v = positive_int(text)
        if v > limit:
            raise argparse.ArgumentTypeError(f"at most {limit:,} {what}, got {text}")
        return v
    parse.__name__ = "count"
    return parse


#: The most steps (and the widest keyframe spacing) a simulation takes: the sensor kernels count
#: steps in 32 bits (spikesim.sensor_drjit passes them as UInt32), so a step number, plus a
#: keyframe spacing, must stay below 2**32. --keyframe-every 5000000000 crashed the llvm backend
#: inside Dr.Jit and --steps 1e23 ran until the disk was full (round ten). 2**31 - 1 steps of even a
#: 16 x 24 sensor is a 100 GB stream, 15 hours at the 25 us readout.
MAX_SENSOR_STEPS = 2 ** 31 - 1


def sensor_steps(text: str) -> int:
    """--steps, --keyframe-every of a simulation: an integer in 1..MAX_SENSOR_STEPS."""
    v = positive_int(text)
    if v > MAX_SENSOR_STEPS:
        shown = text if len(text) <= 24 else f"a {len(text)}-digit number"
        raise argparse.ArgumentTypeError(f"at most {MAX_SENSOR_STEPS:,} (2**31 - 1: the sensor counts steps in 32 "
                                         f"bits), got {shown}")
    return v


def nonnegative_int(text: str) -> int:
    """An integer >= 0 (an index, a start step, a seed)."""
    v = _number(text, int)
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text}")
    return v


#: The largest seed: torch seeds its generators with a 64-bit integer (a 30-digit seed failed deep
#: inside training with "Overflow when unpacking long long"); NumPy takes any.
MAX_SEED = 2 ** 63 - 1


def seed_int(text: str) -> int:
    """A seed: an integer in 0..MAX_SEED."""
    v = nonnegative_int(text)
    if v > MAX_SEED:
        raise argparse.ArgumentTypeError(f"a seed is at most 2**63 - 1 = {MAX_SEED}, got {len(str(v))} digits")
    return v


def positive_float(text: str) -> float:
    """A finite number > 0 (a rate, a gamma, a scale)."""
    v = _number(text, float)
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return v


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    v = _number(text, float)
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return v


def existing_file(text: str) -> Path:
    """A path to a readable regular file (not a directory)."""
    p = Path(text)
    if not p.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a directory, expected a file")
    if not p.is_file():  # a FIFO or device would block or never end
        raise argparse.ArgumentTypeError(f"{text}: not a regular file")
    try:
        with open(p, "rb"):
            pass
    except OSError as exc:
        raise argparse.ArgumentTypeError(f"{text}: cannot be read ({exc.strerror})") from None
    return p


def config_file(text: str) -> Path:
    """A readable JSON or TOML config file (the format follows the suffix, spikesim.config_io)."""
    p = existing_file(text)
    if p.suffix.lower() not in (".json", ".toml"):
        raise argparse.ArgumentTypeError(f"{text}: expected a .json or .toml file")
    return p


def camera_spec(text: str) -> str | Path:
    """--camera: a built-in camera (realistic, measured, noiseless, scsim) or a JSON/TOML camera config file."""
    return text if text in CAMERA_PRESETS else config_file(text)


def load_camera(spec: str | Path | None):
    """The SpikeCamera a --camera value names (None: the realistic one)."""
    from spikesim.camera import SpikeCamera

    if spec is None:
        return SpikeCamera.realistic()
    if spec in CAMERA_PRESETS:
        return SpikeCamera.preset(spec)
    return SpikeCamera.from_file(spec)


def output_file(text: str) -> Path:
    """A file to write: not an existing folder, and in a folder that exists or can be made."""
    p = Path(text)
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a directory, expected a file name")
    _check_writable_parent(p)
    return p


def output_file_in(default_name: str):
    """argparse type: a file to write, or a folder to write `default_name` in (an existing folder,
    or a name ending in "/"), as the commands whose -o is a folder take it. The file's suffix is
    `default_name`'s: a camera file given as -o was overwritten with a PNG or JSON (round seven)."""
    suffix = Path(default_name).suffix

    def parse(text: str) -> Path:
        p = Path(text)
        if p.is_dir() or text.endswith(("/", "\\")):
            return output_file(str(p / default_name))
        if p.suffix.lower() != suffix:
            raise argparse.ArgumentTypeError(f"{text}: this writes a {suffix} file; name it *{suffix} (or give a folder)")
        return output_file(text)
    parse.__name__ = "output file"  # argparse names the type in its errors
    return parse


def output_dir(text: str) -> Path:
    """A folder to write in: an existing folder, or one that can be made (not an existing file)."""
    p = Path(text)
    try:
        if p.exists() and not p.is_dir():
            raise argparse.ArgumentTypeError(f"{text}: exists and is not a directory")
        _check_writable_parent(p)
    except OSError as exc:  # a name too long for the file system, a path through a file
        raise argparse.ArgumentTypeError(f"{text[:80]}{'...' if len(text) > 80 else ''}: {exc.strerror}") from None
    return p


def _check_writable_parent(p: Path) -> None:
    """The nearest existing ancestor of `p` must be a folder we may write in, so that the run
    fails now rather than after its work."""
    for parent in p.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f"{p}: {parent} is a file, not a directory")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise argparse.ArgumentTypeError(f"{p}: cannot write in {parent}")
            return


def bundled_scene(text: str) -> str:
    """The name of a bundled scene (ball, car, cook, fan, rotate), lower-cased; never a path."""
    from scenes import SCENES

    name = text.lower()
    if name not in SCENES:
        raise argparse.ArgumentTypeError(f"{text!r} is not a bundled scene; expected one of {', '.join(SCENES)}")
    return name


#: The largest light power factor a run takes (spikesim.generation.plan.SceneJob checks the same).
MAX_LIGHT_POWER_FACTOR = 1e6


def light_power_factor(text: str) -> float:
    """--light-power-factor: a finite number in (0, MAX_LIGHT_POWER_FACTOR]."""
    v = positive_float(text)
    if v > MAX_LIGHT_POWER_FACTOR:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_LIGHT_POWER_FACTOR:g}, got {text}")
    return v


class StoreOnce(argparse.Action):
    """argparse action: a flag given once; a second value is refused, not silently taken instead of
    the first (round eight: calibrate --dark A --dark B fitted B alone)."""

    def __call__(self, parser, namespace, values, option_string=None):  # noqa: D102
        if getattr(namespace, self.dest, None) is not None:
            parser.error(f"argument {option_string}: given twice ({getattr(namespace, self.dest)} and {values}); "
                         "give it once")
        setattr(namespace, self.dest, values)


def add_light_power_factor_argument(parser: argparse.ArgumentParser) -> None:
    """The --light-power-factor flag of every command that renders a user scene (generate, render,
    simulate --scene): one definition, one meaning, one help text."""
    parser.add_argument("--light-power-factor", type=light_power_factor, default=None,
                        help=f"scale every light's power by this factor, in (0, {MAX_LIGHT_POWER_FACTOR:g}] (default 1): "
                             "the frames and ground truth are those of the dimmed (or brightened) scene, and the lux "
                             "recorded (meta.json, render.json, the stream's sidecar) includes it")


DEVICE_HELP = ("where Mitsuba renders{sensor}: llvm (the CPU), cuda (a GPU), or auto (the GPU when there is one)"
               "{frames}")
#: What --device says of the sensor: a command with --backend runs it there only with --backend auto; a
#: command without one always runs it there; `render` runs none.
_FRAMES = "; frames stay on that device and only packed spikes leave it"
_DEVICE_SENSOR = {"backend": (" and, with --backend auto, the sensor runs", _FRAMES),
                  "always": (" and the sensor runs", _FRAMES), "none": ("", "")}


def add_device_argument(parser: argparse.ArgumentParser, sensor: str = "always") -> None:
    """The --device flag of every command that renders (one definition, one help text); `sensor`
    says where the command's sensor runs: "backend" (as its --backend says), "always" (there),
    "none" (it has none)."""
    from spikesim._drjit import DEVICE_CHOICES
    text, frames = _DEVICE_SENSOR[sensor]
    parser.add_argument("--device", choices=DEVICE_CHOICES, default="auto",
                        help=DEVICE_HELP.format(sensor=text, frames=frames))


__all__ = ["add_device_argument", "add_light_power_factor_argument", "light_power_factor", "positive_int", "nonnegative_int", "positive_float", "nonnegative_float", "existing_file",
           "config_file", "output_file", "output_dir", "bundled_scene"]


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Every command's help: descriptions as written, and each option's default appended unless
    its help already states one or it has none worth showing (None, False: a flag that is off;
    a flag that turns something off, whose True would read backwards: its help says the default)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (default in (None, False, argparse.SUPPRESS) or "default" in text or "%(default)" in text
                or not action.option_strings or isinstance(action, argparse._StoreFalseAction)):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else "%(default)s"
        return f"{text} (default: {shown})"


class CommandParsers:
    """The `add_subparsers` action, made to give every command the project's HelpFormatter."""

    def __init__(self, action: "argparse._SubParsersAction") -> None:
        self._action = action

    def add_parser(self, name: str, **kwargs) -> argparse.ArgumentParser:
        kwargs["formatter_class"] = HelpFormatter
        return self._action.add_parser(name, **kwargs)


def add_threads_argument(parser: argparse.ArgumentParser) -> None:
    """`--threads`, the same in every command that runs torch on the CPU (model.threads)."""
    parser.add_argument("--threads", type=cpu_threads, default=0,
                        help="torch CPU threads, 0 to 1024 (default 0: the cores not busy now, from the load "
                             "average; threads that share a busy core stall each other)")


def horizon_arg(text: str) -> int | str:
    """argparse type of --horizon: "trained", "all" or a number of windows >= 1."""
    if text in ("trained", "all"):
        return text
    try:
        return positive_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"expected 'trained', 'all' or a number of windows >= 1, got {text!r}") from None


def add_horizon_arguments(parser: argparse.ArgumentParser) -> None:
    """`--horizon` and `--horizon-stride`: how a network runs over a stream longer than its training
    sequences (model.methods.ModelMethod, model.streaming.horizon_reconstruct)."""
    parser.add_argument("--horizon", type=horizon_arg, default="trained",
                        help="windows a network's recurrence runs over at once: 'trained' (default: its training "
                             "sequences', 5 for the shipped networks; a longer stream is run in overlapping pieces "
                             "of that many windows), a number, or 'all' (the whole stream at once, exact chunked "
                             "streaming; how every figure before horizon inference was made)")
    parser.add_argument("--horizon-stride", type=positive_int, default=None,
                        help="frames taken from each piece, at most the horizon (default: the horizon less 2, "
                             "so every frame has a window of context on each side; 1 centres every frame, about "
                             "1.8 times the cost, for +0.01-0.06 dB on validation; docs/model.md, "
                             "\"Horizon inference\")")


def cpu_threads(text: str) -> int:
    """argparse type: 0 (choose) to model.threads.MAX_THREADS torch CPU threads: --threads 99999
    exhausted the process limit and crashed (a segmentation fault, round nine)."""
    from model.threads import MAX_THREADS as MAX_CPU_THREADS
    v = nonnegative_int(text)
    if v > MAX_CPU_THREADS:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_CPU_THREADS} threads (this machine has "
                                         f"{os.cpu_count()} cores), got {text}")
    return v
