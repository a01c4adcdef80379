"""Helpers shared by the command modules: preset option, JSON and tables."""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from toggle.params import Mechanism, load_preset, preset_names

MM = 1e3  # metres to millimetres, for tables only


def add_preset_argument(parser: argparse.ArgumentParser, default: str = "chang2021") -> None:
    parser.add_argument(
        "--preset", default=default,
        help=f"shipped preset ({', '.join(preset_names())}) or a TOML file (default {default})",
    )


def add_json_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--json", action="store_true", help="print machine-readable JSON (SI units)"
    )


def add_out_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--out`` folder of a ``toggle plot`` figure."""
    parser.add_argument("--out", type=Path, default=Path("figures"), help="output folder")


def mechanism(args: argparse.Namespace) -> Mechanism:
    return load_preset(args.preset)


def print_json(payload: Any) -> None:
    print(json.dumps(payload, indent=2, sort_keys=False))


def deg(rad: float) -> float:
    return math.degrees(rad)


def table(headers: Sequence[str], rows: Iterable[Sequence[Any]], fmt: str = "{:>12.4f}") -> str:
    """A plain text table; floats use ``fmt``, anything else is right-aligned text."""
    def cell(v: Any) -> str:
        return fmt.format(v) if isinstance(v, float) else f"{v!s:>12}"
    lines = ["".join(f"{h:>12}" for h in headers)]
    lines += ["".join(cell(v) for v in row) for row in rows]
    return "\n".join(lines)
