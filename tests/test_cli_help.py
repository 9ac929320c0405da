"""The command line explains itself: every option of every command has help, and a default that
matters is shown."""
from __future__ import annotations

import argparse

import pytest

from pipelines.cli import build_parser
from pipelines.argtypes import HelpFormatter


def _commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


COMMANDS = _commands()


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_option_has_help_and_shows_its_default(name: str) -> None:
    parser = COMMANDS[name]
    assert parser.formatter_class is HelpFormatter
    text = parser.format_help()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        flag = "/".join(action.option_strings) or action.dest
        assert action.help and action.help.strip(), f"{name} {flag}: no help"
        if action.option_strings and action.default not in (None, False, argparse.SUPPRESS):
            rendered = HelpFormatter(name)._get_help_string(action)
            assert "default" in rendered, f"{name} {flag}: default {action.default!r} not shown"
    assert "(default: (default" not in text


def test_defaults_are_not_stated_twice() -> None:
    for name, parser in COMMANDS.items():
        for action in parser._actions:
            rendered = HelpFormatter(name)._get_help_string(action) if action.help else ""
            assert rendered.count("default") <= 2, (name, action.option_strings, rendered)
