"""The `spikesim` command line: one program, one subcommand per pipeline stage."""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

# (module, what it adds); a module whose optional dependencies are missing is skipped with a note.
_SUBCOMMANDS = (
    "pipelines.demo",
    "pipelines.simulate_cmd",
    "pipelines.inspect_cmd",
    "pipelines.bench",
    "pipelines.golden_stats",
    "pipelines.generate",
    "pipelines.render_cmd",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="spikesim", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _SUBCOMMANDS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith(name):
                continue
            raise
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, FileExistsError, KeyError) as exc:
        # Bad input: one clear line, no traceback (use -v for one).
        if args.verbose:
            raise
        print(f"spikesim {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
