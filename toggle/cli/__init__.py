"""The ``toggle`` command line: one sub-command per module in this package.

Each command module defines ``add_parser(subparsers)``; a module may also
define ``add_plot_parser(plot_subparsers)`` to add a ``toggle plot <kind>``
figure. Values are SI inside; the tables convert to mm and degrees.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from toggle.kinematics import AssemblyError
from toggle.params import ParameterError

#: Command modules, in the order ``toggle --help`` lists them.
COMMANDS = ("kinematics", "tolerance", "clamp", "synthesize", "study", "asymmetry", "calibrate",
            "tables", "build_fmu", "plan", "plot")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="toggle", description="Double-toggle mold/die clamp: model, analysis and tools."
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"toggle.cli.{name}").add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``toggle`` script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except (ParameterError, AssemblyError, ValueError) as exc:
        print(f"toggle {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
