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


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_no_flag_that_turns_something_off_shows_default_true(name: str) -> None:
    """--no-flip (store_false) used to read "rows stored top-down (default: True)": backwards."""
    text = " ".join(COMMANDS[name].format_help().split())
    assert "(default: True)" not in text
    if "--no-flip " in text and name != "evaluate":  # evaluate's says "default as recorded, else bottom-up"
        assert "rows stored bottom-up (flip)" in text


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_device_help_names_only_flags_the_command_has(name: str) -> None:
    parser = COMMANDS[name]
    device = next((a for a in parser._actions if "--device" in a.option_strings), None)
    if device is not None and "--backend" in (device.help or ""):
        assert any("--backend" in a.option_strings for a in parser._actions), name


def test_render_has_quiet() -> None:
    assert any("--quiet" in a.option_strings for a in COMMANDS["render"]._actions)
