"""The `spikesim` command line: one program, one subcommand per pipeline stage."""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from pipelines.argtypes import CommandParsers
from spikesim.errors import UnavailableError
from spikesim.signals import TERMINATED_STATUS, Terminated, sigterm_raises

# (module, what it adds); a module whose optional dependencies are missing is skipped with a note.
_SUBCOMMANDS = (
    "pipelines.demo",
    "pipelines.simulate_cmd",
    "pipelines.inspect_cmd",
    "pipelines.bench",
    "pipelines.golden_stats",
    "pipelines.camera_cmd",
    "pipelines.calibrate_cmd",
    "pipelines.generate",
    "pipelines.render_cmd",
    "pipelines.train",
    "pipelines.evaluate",
    "pipelines.gates_cmd",
    "pipelines.pick_cmd",
    "pipelines.export",
    "pipelines.compare",
    "pipelines.reconstruct",
    "pipelines.panel",
    "pipelines.tradeoff",
    "pipelines.sweep",
    "pipelines.gpu_campaign.cmd",
)


# The subcommand each module registers, so that a command imports only its own module (the
# model's pull in torch, ~2 s) unless the full list is asked for.
_COMMAND_MODULE = {
    "demo": "pipelines.demo", "simulate": "pipelines.simulate_cmd", "inspect": "pipelines.inspect_cmd",
    "bench": "pipelines.bench", "golden": "pipelines.golden_stats", "camera": "pipelines.camera_cmd", "calibrate": "pipelines.calibrate_cmd", "generate": "pipelines.generate",
    "verify": "pipelines.generate", "render": "pipelines.render_cmd", "train": "pipelines.train",
    "evaluate": "pipelines.evaluate", "gates": "pipelines.gates_cmd", "pick-checkpoint": "pipelines.pick_cmd", "export": "pipelines.export", "compare": "pipelines.compare", "reconstruct": "pipelines.reconstruct", "tradeoff": "pipelines.tradeoff",
    "panel": "pipelines.panel", "sweep": "pipelines.sweep", "gpu-campaign": "pipelines.gpu_campaign.cmd",
}


EXIT_STATUSES = """exit status:
  0    success
  2    bad input or a missing resource (a file, a GPU, memory): one line names the flag or file
  1    an unexpected error, shown with its traceback: a bug, please report it
       (`verify` and `golden` also return 1 when their check finds problems, listed above it)
  130  interrupted (Ctrl-C)
  143  terminated (SIGTERM): stopped as Ctrl-C stops it"""


def installed_version() -> str:
    """The version of the installed distribution (its metadata, so a wheel and a checkout agree
    with pyproject.toml); a checkout run without installing says so instead."""
    from importlib import metadata
    try:
        return metadata.version("spikesim")
    except metadata.PackageNotFoundError:
        return "unknown (not installed: pip install .)"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; with `command`, only that command's module is imported, and with "--version"
    none (the version needs no pipeline, and torch takes seconds to load)."""
    parser = argparse.ArgumentParser(prog="spikesim", description=__doc__, epilog=EXIT_STATUSES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    parser.add_argument("--version", action="version", version=f"%(prog)s {installed_version()}",
                        help="print the installed version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    modules = [_COMMAND_MODULE[command]] if command in _COMMAND_MODULE else _SUBCOMMANDS
    if command == "--version":
        modules = ()
    for name in modules:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith(name):
                continue
            raise
        module.add_parser(CommandParsers(sub))
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command and return its exit status (see EXIT_STATUSES); argparse's refusals of bad
    arguments are returned as their status too, so that callers in-process get a number."""
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    name = f"spikesim {command}" if command in _COMMAND_MODULE else "spikesim"
    try:
        # every command follows the toolkit's SIGTERM rule: stopped as Ctrl-C stops it, so its
        # clean-up runs (round fourteen: SIGTERM to `compare` left its lock and said nothing)
        with sigterm_raises():
            return _run(argv, command)
    except Terminated as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        return TERMINATED_STATUS
    except KeyboardInterrupt:  # also while the command's modules load (torch takes seconds)
        print(f"{name}: interrupted", file=sys.stderr)
        return 130


def _run(argv: list[str], command: str | None) -> int:
    parser = build_parser("--version" if command is None and "--version" in argv else command)
    try:
        args, extras = parser.parse_known_args(argv)
        if extras:  # refused by the command's own parser, so that the message names the command
            _command_parser(parser, args.command).error(f"unrecognized arguments: {' '.join(extras)}")
    except SystemExit as exc:  # --help (0) or a refused argument (2), already printed
        return exc.code if isinstance(exc.code, int) else 2
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    try:
        return int(args.func(args) or 0)
    except (ValueError, KeyError, OSError, MemoryError, UnavailableError) as exc:
        # Bad input or a missing resource: one clear line, no traceback (use -v for one).
        if args.verbose:
            raise
        print(f"spikesim {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2


def _command_parser(parser: argparse.ArgumentParser, command: str | None) -> argparse.ArgumentParser:
    """The parser of subcommand `command` (the top-level parser if there is none)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return action.choices[command]
    return parser


def _one_line(exc: BaseException) -> str:
    """The message of an expected failure, naming the file for OS errors (permission, a directory
    where a file was expected, a full disk)."""
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}"
    text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    if isinstance(exc, MemoryError):
        text = f"out of memory: {text}" if text else "out of memory"
    return " ".join(text.split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
