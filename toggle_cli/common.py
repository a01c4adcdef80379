"""Helpers shared by the command modules: preset option, argument types, JSON and tables.

The argument types are :mod:`toggle.args`'s, so ``toggle`` and ``hil`` judge a value alike.
This module and the command modules' tops import nothing heavy (no numpy, SciPy, CasADi):
every command's parser is built on every command line, each command loads what it runs.
"""

from __future__ import annotations

import argparse
import math
import weakref
from collections.abc import Callable, Collection, Iterable, Sequence
from pathlib import Path
from typing import Any

from toggle.args import integer, length, number, path, positive
from toggle.params import HALVES, Mechanism, ParameterError, load_preset

MM = 1e3  # metres to millimetres, for tables only

#: Shipped presets that describe a clamp (the press dong2022 is synthesize's only).
CLAMP_PRESETS = ("chang2021", "lin2003_sm55", "li_micro")
SPEED = positive("crosshead speed in m/s", 1.0, unit="m/s")
#: A link-length error of the upper half (link 8), m.
LINK_ERROR = length(-5e-3, 5e-3, "must be a length error within 5 mm")
FRICTION = number(0.0, 1.0, "must be a friction coefficient between 0 and 1", "(1)")
POSITION = length(-1.0, 1.0, "must be a crosshead position within 1 m")
FORCE = positive("force in N", 1e9, unit="N")
SEED = integer(0, 2**32 - 1, "must be a seed between 0 and 2^32 - 1")
POINTS = integer(2, 100_000, "must be a count of points between 2 and 100000")
SAMPLES = integer(1, 100_000_000, "must be a number of samples between 1 and 1e8")
IT_GRADE = integer(1, 18, "must be an ISO 286 IT grade between 1 and 18")


#: Parsers whose arguments wait to be added (:func:`add_arguments_later`), with the functions
#: that add them.
_WAITING: weakref.WeakKeyDictionary[argparse.ArgumentParser,
                                    tuple[Callable[[argparse.ArgumentParser], None], ...]] = (
    weakref.WeakKeyDictionary())


def add_arguments_later(parser: argparse.ArgumentParser,
                        *adds: Callable[[argparse.ArgumentParser], None]) -> None:
    """``add(parser)`` for each of ``adds`` in turn adds the arguments of a (sub-)command
    whose declarations need a heavy module (a default or the choices from the planner:
    CasADi, SciPy): the command line adds them (:func:`add_waiting_arguments`) only where it
    names that command, so that the other commands start without loading the module. The
    parser itself (its name and one-line help, which ``toggle --help`` lists) is made at
    once."""
    _WAITING[parser] = adds


def add_waiting_arguments(parser: argparse.ArgumentParser,
                          words: Collection[str] | None = None) -> None:
    """The arguments :func:`add_arguments_later` kept back, of every sub-command of
    ``parser`` named in ``words`` (argparse picks a sub-command by its exact name: one not
    named there is not parsed) and of theirs; of all of them when ``words`` is None."""
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for name, sub in action.choices.items():
                if words is None or name in words:
                    for add in _WAITING.pop(sub, ()):
                        add(sub)
                    add_waiting_arguments(sub, words)


def add_preset_argument(parser: argparse.ArgumentParser, default: str = "chang2021",
                        accepts: Sequence[str] = CLAMP_PRESETS, why: str = "") -> None:
    """``--preset``, with the shipped presets this command accepts (and why others do not)."""
    family = "; a family takes family/group, e.g. li_micro/6" if "li_micro" in accepts else ""
    note = f"; {why}" if why else ""
    parser.add_argument(
        "--preset", default=default,
        help=f"shipped preset ({', '.join(accepts)}) or a TOML file{family}{note} "
             f"(default {default})",
    )


def add_json_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--json", action="store_true", help="print machine-readable JSON (SI units)"
    )


def add_out_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--out`` folder of a ``toggle plot`` figure."""
    parser.add_argument("--out", type=path, default=Path("figures"), metavar="DIR",
                        help="results folder, named on the last line (default figures)")


def declare_outputs(parser: argparse.ArgumentParser, *names: str) -> None:
    """The files a ``toggle plot`` kind writes into its ``--out`` folder (``str.format``
    fields from the arguments, e.g. ``"sensitivity_IT{it}_{tag}.png"``, ``{tag}`` the
    preset's :func:`preset_tag`): the command line checks them before the work
    (:func:`outputs`), and the command takes ``--force``."""
    parser.set_defaults(outputs=names, checks_outputs=True)


def preset_tag(preset: str) -> str:
    """A preset as part of a file name, so that figures of two presets sit side by side: a
    shipped name as it is (a family's group ``li_micro/6`` as ``li_micro-6``), a preset
    file by its stem (``design/presets/design-3f2a.toml``: ``design-3f2a``)."""
    path = Path(preset)
    return path.stem if path.suffix.lower() == ".toml" else preset.replace("/", "-")


def output(args: argparse.Namespace, name: str) -> Path:
    """``name`` (``str.format`` fields from the arguments, and ``{tag}``) under ``--out``."""
    fields = {**vars(args), "tag": preset_tag(getattr(args, "preset", None) or "")}
    return args.out / name.format(**fields)


def outputs(args: argparse.Namespace) -> list[Path]:
    """The output files a command declared with :func:`declare_outputs`, under ``--out``."""
    return [output(args, name) for name in getattr(args, "outputs", ())]


def mechanism(args: argparse.Namespace) -> Mechanism:
    """The ``--preset``, refused (ParameterError, exit 2) where its dimensions cannot make
    the double-toggle clamp it states, with the reason
    (:func:`toggle.kinematics.check_stroke`)."""
    from toggle.kinematics import AssemblyError, check_stroke

    mech = load_preset(args.preset)
    x_open = mech.clamp.x_open if mech.clamp is not None else None
    for half in HALVES:
        try:
            check_stroke(mech.half(half), x_open, label=f"{half} half")
        except AssemblyError as exc:
            raise ParameterError(f"preset {args.preset}: {exc}") from None
    return mech


def print_json(payload: Any) -> None:
    """Strict JSON on stdout: a non-finite number is null (:mod:`toggle.json_text`)."""
    from toggle.json_text import json_text

    print(json_text(payload))


def deg(rad: float) -> float:
    return math.degrees(rad)


def table(headers: Sequence[str], rows: Iterable[Sequence[Any]], fmt: str = "{:>12.4f}") -> str:
    """A plain text table; floats use ``fmt`` (``g`` when that would overflow the column),
    anything else is right-aligned text."""
    def cell(v: Any) -> str:
        if not isinstance(v, float):
            return f"{v!s:>12}"
        text = fmt.format(v)
        return text if len(text) <= 12 else f"{v:>12.5g}"
    lines = ["".join(f"{h:>12}" for h in headers)]
    lines += ["".join(cell(v) for v in row) for row in rows]
    return "\n".join(lines)
