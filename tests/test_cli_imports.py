"""The ``toggle`` command line loads what the invoked command needs, not every command's
dependencies: parsing a light command's arguments in a fresh process leaves numpy, SciPy,
CasADi and the planner unloaded, and the parsers built for one command line say what the
whole parser says."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from toggle_cli import build_parser

#: Modules a light command's start-up must not load (a third of a second of CPU together;
#: the command modules themselves, toggle_cli.plan too, are light and all load).
HEAVY = ("numpy", "scipy", "casadi", "matplotlib", "controllers", "fmu_src", "toggle.kinematics")

#: Parses the command line given after ``-c`` as ``toggle`` does (its --help exits), then
#: prints the heavy modules loaded by then as JSON on the last line.
PROBE = ("import json, sys\n"
         "from toggle.args import join_negative_numbers, parse_command_line\n"
         "import toggle_cli\n"
         "argv = join_negative_numbers(sys.argv[1:])\n"
         "try:\n"
         "    parse_command_line(toggle_cli.build_parser(words=argv), argv)\n"
         "except SystemExit:\n"
         "    pass\n"
         f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))\n")


def _loaded(argv: list[str]) -> list[str]:
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True,
                         check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", [["kinematics", "--help"], ["kinematics", "--json"],
                                  ["plot", "kinematics"], ["cache"], ["--help"]])
def test_a_light_command_line_parses_without_the_heavy_modules(argv: list[str]) -> None:
    assert _loaded(argv) == []


def test_the_plans_help_loads_the_planner_its_options_need() -> None:
    """The probe sees a load: plan's defaults and choices are the planner's (CasADi)."""
    assert {"casadi", "controllers"} <= set(_loaded(["plan", "--help"]))


def _helps(parser: argparse.ArgumentParser, words: tuple[str, ...] = ()
           ) -> dict[tuple[str, ...], str]:
    """The --help text of ``parser`` and of every sub-command under it, by its words."""
    out = {words: parser.format_help()}
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for name, sub in action.choices.items():
                out.update(_helps(sub, (*words, name)))
    return out


def test_a_command_lines_parser_helps_as_the_whole_parser_does() -> None:
    """Built for the words of one command line, each sub-command that line names has the
    arguments and help it has in the full parser (``toggle completion``'s)."""
    whole = _helps(build_parser())
    assert len(whole) > 20
    for words, text in whole.items():
        assert _helps(build_parser(words=list(words)))[words] == text, words


#: Parses a ``hil`` command line as the ``hil`` script does (its --help and --version exit),
#: then prints the heavy modules loaded by then.
HIL_PROBE = ("import json, sys\n"
             "from toggle.args import join_negative_numbers, parse_command_line\n"
             "import hil.cli.main as cli\n"
             "argv = join_negative_numbers(sys.argv[1:])\n"
             "try:\n"
             "    parse_command_line(cli.build_parser(), argv)\n"
             "except SystemExit:\n"
             "    pass\n"
             f"print(json.dumps([m for m in {HEAVY + ('fmpy', 'hil.host.backends')!r} "
             "if m in sys.modules]))\n")


@pytest.mark.parametrize("argv", [["--version"], ["--help"], ["run", "--help"],
                                  ["emulate", "--help"], ["rig", "status", "--help"],
                                  ["rsm", "--help"], ["run", "--cycles", "2"]])
def test_hil_parses_its_command_lines_without_the_heavy_modules(argv: list[str]) -> None:
    """``hil --version`` and every ``hil COMMAND --help`` as fast as ``toggle``'s: the
    parser and its defaults come without numpy, SciPy, CasADi, fmpy or the back-ends (1.2-1.3 s
    of imports before); each command loads them when it runs."""
    out = subprocess.run([sys.executable, "-c", HIL_PROBE, *argv], capture_output=True,
                         text=True, check=True).stdout
    assert json.loads(out.strip().splitlines()[-1]) == []


def test_a_plan_loads_no_scipy_optimize() -> None:
    """``toggle plan`` in a fresh process: its roots are toggle.roots' Brent (scipy's to the
    bit, tests/test_roots.py), so neither it nor the job processes a trade-off or a robust
    plan spawns pay scipy.optimize's 0.27 s import (issue 45: a third of the 0.45 s a
    planning process spent before its first solve)."""
    probe = ("import json, sys\n"
             "from toggle_cli import main\n"
             "main(['plan', '--intervals', '40', '--duration', '3', '--json'])\n"
             "print(json.dumps(sorted(m for m in sys.modules if m.startswith('scipy'))))\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True).stdout
    assert json.loads(out.strip().splitlines()[-1]) == []
