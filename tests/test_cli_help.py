"""Every help text of both command lines, as a user reads it: no reStructuredText markup, no
Python values for defaults, no promise of a list that is not there, and what it says about
the presets true of them (issue 40: stale help)."""

from __future__ import annotations

import argparse
import re
from collections.abc import Iterator

import pytest

import hil.cli.main
import toggle_cli
from toggle.params import load_preset

MARKUP = ("``", ":func:", ":mod:", ":class:", ":meth:", "(default: [])",
          "(default: None)", "(default: ())")


def _helps(parser: argparse.ArgumentParser, name: str) -> Iterator[tuple[str, str]]:
    yield name, parser.format_help()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield from _helps(sub, f"{name} {sub_name}")


HELPS = dict([*_helps(toggle_cli.build_parser(), "toggle"),
              *_helps(hil.cli.main.build_parser(), "hil")])


def test_every_command_has_help() -> None:
    assert len(HELPS) > 30 and "toggle plot linkage" in HELPS and "hil run" in HELPS


@pytest.mark.parametrize("command", sorted(HELPS))
def test_the_help_is_plain_and_true(command: str) -> None:
    text = " ".join(HELPS[command].split())
    assert not [m for m in MARKUP if m in text], text
    assert not re.search(r"\.\. [a-z-]+::", text), text  # a directive
    for said in re.finditer(r"listed below", text):
        assert text[said.end():].strip(), text  # something is listed after it
    for preset in re.findall(r"(\w+) has no \[dynamics\]", text):
        assert load_preset(preset).dynamics is None, (command, preset)
