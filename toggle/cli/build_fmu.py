"""``toggle build-fmu``: write build/ToggleClamp.fmu (FMI 2.0 Co-Simulation)."""

from __future__ import annotations

import argparse
from pathlib import Path

from toggle.fmu_build import build_fmu


def run(args: argparse.Namespace) -> int:
    print(build_fmu(args.out))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build-fmu", help="build the FMI 2.0 Co-Simulation FMU into build/")
    p.add_argument("--out", type=Path, default=Path("build"), help="output folder (default build)")
    p.set_defaults(handler=run)
