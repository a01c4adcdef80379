"""``toggle plot <kind>``: PNG figures; each command module may add its own kind."""

from __future__ import annotations

import argparse
import importlib

from toggle_cli import COMMANDS


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plot", help="write figures (PNG; linkage also a GIF): "
                                    "'toggle plot --help' lists the kinds",
                       description="Write a figure into the --out folder (default figures), "
                                   "named on the last line.")
    kinds = p.add_subparsers(dest="kind", required=True, metavar="KIND")
    for name in COMMANDS:
        module = importlib.import_module(f"toggle_cli.{name}")
        if hasattr(module, "add_plot_parser"):
            module.add_plot_parser(kinds)
    p.description += f" Kinds: {', '.join(kinds.choices)}."
