"""Argument types of the ``hil`` and ``toggle`` command lines: numbers in a range, paths,
negative values, help that shows defaults, and the answers every command shares.

argparse takes ``-0.5e-3`` for an option and ``float`` takes ``nan``; these types and the
argv rewrite make every bad value a one-line usage error (exit 2) naming its option.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: A negative number as the value of an option (argparse takes '-1e-3' for an option).
_NEGATIVE = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*(m|cm|mm|um|\u00b5m|\u03bcm)?$"
                       r"|^-(inf|nan)$", re.IGNORECASE)


def join_negative_numbers(argv: list[str]) -> list[str]:
    """``--opt -0.5e-3`` -> ``--opt=-0.5e-3``, so negative values in e-notation parse."""
    out: list[str] = []
    for token in argv:
        if (out and _NEGATIVE.match(token) and out[-1].startswith("--")
                and "=" not in out[-1]):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def number(lo: float, hi: float, what: str, unit: str = "") -> Callable[[str], float]:
    """argparse type: a finite float in [lo, hi]; ``unit`` (SI) is printed after the default
    in the help (:class:`HelpFormatter`)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not (math.isfinite(value) and lo <= value <= hi):
            raise argparse.ArgumentTypeError(f"{what}, got {text!r}")
        return value
    parse.__name__ = "number"
    parse.unit = unit  # type: ignore[attr-defined]  # read by HelpFormatter
    return parse


#: Length units a length option takes after its number, with their factor to metres.
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "\u00b5m": 1e-6, "\u03bcm": 1e-6}
_LENGTH = re.compile(r"^\s*(?P<number>.*?)\s*(?P<unit>[a-zA-Z\u00b5\u03bc]*)\s*$")

def length(lo: float, hi: float, what: str) -> Callable[[str], float]:
    """argparse type: a length in [lo, hi] m, in metres (``0.25e-3``) or with a unit
    (``0.25mm``, ``250um``, ``2.5 cm``, ``0.00025m``), as drives and CAD tools take it."""
    def parse(text: str) -> float:
        match = _LENGTH.match(text)
        unit = (match.group("unit") if match else "") or "m"
        if match is None or unit not in LENGTH_UNITS:
            raise argparse.ArgumentTypeError(
                f"not a length: {text!r} (a number in m, or with a unit: 0.25mm, 250um)")
        try:
            value = float(match.group("number")) * LENGTH_UNITS[unit]
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"not a length: {text!r} (a number in m, or with a unit: 0.25mm, 250um)"
            ) from None
        if not (math.isfinite(value) and lo <= value <= hi):
            raise argparse.ArgumentTypeError(f"{what}, got {text!r}")
        return value
    parse.__name__ = "length"
    parse.unit = "m"  # type: ignore[attr-defined]
    return parse


def positive(what: str, hi: float = 1e12, lo: float = 0.0, unit: str = ""
             ) -> Callable[[str], float]:
    """argparse type: a finite float in (lo, hi]; ``what`` names the quantity and its unit
    (``unit``, the SI unit alone, is printed after the default in the help)."""
    why = f"must be a {what} > {lo:g}" + (f" and <= {hi:g}" if hi < 1e12 else "")
    inner = number(lo, hi, why, unit)

    def parse(text: str) -> float:
        value = inner(text)
        if value <= lo:
            raise argparse.ArgumentTypeError(f"{why}, got {text!r}")
        return value
    parse.__name__ = "number"
    parse.unit = unit  # type: ignore[attr-defined]
    return parse


def integer(lo: int, hi: int, what: str) -> Callable[[str], int]:
    """argparse type: a whole number in [lo, hi] (the bound keeps a typo from running for days)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{what}, got {text!r}")
        return value
    parse.__name__ = "integer"
    return parse


PROBABILITY = number(0.0, 1.0, "must be a probability between 0 and 1")
TIME = number(0.0, 1e6, "must be a time >= 0 s", "s")


def path(text: str) -> Path:
    """argparse type: a non-empty path (an empty one would mean the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path")
    return Path(text)


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows ``(default: X)``, with the unit of a number option's type (``(default: 0 m)``),
    unless the help already says its default or there is none (None, False, an empty
    list)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text or not has_default(action) or not action.option_strings:
            return text
        unit = getattr(action.type, "unit", "")
        if unit and isinstance(action.default, (int, float)):
            return f"{text} (default: %(default)s {unit})"
        return super()._get_help_string(action)


def has_default(action: argparse.Action) -> bool:
    """Whether an option has a default worth showing (not None, False or an empty list)."""
    default = action.default
    return not (default is None or default is False
                or (isinstance(default, (list, tuple)) and not default))


def use_help_formatter(parser: argparse.ArgumentParser) -> None:
    """Give ``parser`` and all its sub-commands :class:`HelpFormatter`."""
    parser.formatter_class = HelpFormatter
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for sub in action.choices.values():
                use_help_formatter(sub)


def add_force_options(parser: argparse.ArgumentParser) -> None:
    """``--force`` on ``parser`` and every sub-command that checks its output files before
    the work (its ``checks_outputs`` default is true: :func:`toggle.files.check_writable`
    refuses an existing one unless ``--force``) and has none yet."""
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for sub in action.choices.values():
                add_force_options(sub)
    options = parser._option_string_actions  # noqa: SLF001
    if parser.get_default("checks_outputs") and "--force" not in options:
        parser.add_argument("--force", action="store_true",
                            help="replace output files that exist (without it they are "
                                 "refused before any work)")


def version() -> str:
    """The toggle-clamp version (the package's own: importlib.metadata takes a tenth of a
    second to load, a third of what ``toggle --version`` may take)."""
    from toggle import __version__

    return __version__


def remember_parsers(parser: argparse.ArgumentParser) -> None:
    """Every (sub-)command's parser as the default ``command_parser`` of its arguments, so
    that :func:`parse_command_line` can answer in the sub-command's own usage."""
    parser.set_defaults(command_parser=parser)
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for sub in action.choices.values():
                remember_parsers(sub)


def parse_command_line(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """``parser.parse_args(argv)``, but an unknown option is refused with the usage of the
    sub-command it was given to (argparse answers with the top level's: "usage: toggle
    [-h] [--version] COMMAND ...", which does not say what the sub-command takes)."""
    args, extra = parser.parse_known_args(argv)
    if extra:
        getattr(args, "command_parser", parser).error(
            f"unrecognized arguments: {' '.join(extra)}")
    return args


#: The shells ``COMMAND completion SHELL`` writes a script for.
SHELLS = ("bash", "zsh")


def add_completion(subparsers: Any, prog: str,
                   build_parser: Callable[[], argparse.ArgumentParser]) -> None:
    """``PROG completion bash|zsh``: print the shell completion script of the whole command
    line, generated from its parsers by shtab (a static script: no Python runs at <Tab>)."""
    text = (f"print the shell completion script of {prog} (bash: "
            f"`eval \"$({prog} completion bash)\"` in ~/.bashrc; zsh: save it as _{prog} "
            "in a folder of $fpath)")
    p = subparsers.add_parser("completion", help=f"print the {prog} shell completion script",
                              description=text)
    p.add_argument("shell", choices=SHELLS, help="the shell the script is for")
    p.set_defaults(handler=lambda args: _print_completion(build_parser(), args.shell))


def _print_completion(parser: argparse.ArgumentParser, shell: str) -> int:
    import shtab

    _complete_paths(parser, shtab.FILE)
    print(shtab.complete(parser, shell=shell))
    return 0


def _complete_paths(parser: argparse.ArgumentParser, how: dict[str, str]) -> None:
    """Every argument of type :func:`path` (in every sub-command) completes file names."""
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for sub in action.choices.values():
                _complete_paths(sub, how)
        elif action.type is path:
            action.complete = how  # type: ignore[attr-defined]  # shtab's attribute


def add_version(parser: argparse.ArgumentParser) -> None:
    """``--version``: the installed toggle-clamp version."""
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")


def quiet_broken_pipe() -> int:
    """Piped into ``head``: stop without a traceback (stdout's reader is gone)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    with contextlib.suppress(OSError, ValueError):  # in-process stdout has no descriptor
        os.dup2(devnull, sys.stdout.fileno())
    return 1
