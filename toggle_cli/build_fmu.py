"""``toggle build-fmu``: write build/ToggleClamp.fmu (FMI 2.0 Co-Simulation) of one preset.

``--native`` writes the native FMU instead: the plant generated to C, no Python at run
time (:mod:`fmu_src.native_build`), for FMI 2.0 or 3.0 (``--fmi-version``), Co-Simulation,
Model Exchange or both (``--interface``); build/ToggleClampNative.fmu by default (2, cs).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from toggle.args import path
from toggle.files import check_writable, check_writable_dir
from toggle.params import load_preset


def run(args: argparse.Namespace) -> int:
    """Build the FMU asked for through the public API (:func:`fmu_src.build_fmu`), after
    the checks that name the command's options."""
    from fmu_src import build_fmu, fmu_file_name

    if not args.native and (args.fmi_version, args.interface) != (2, "cs"):
        raise ValueError("--fmi-version 3 and --interface me|both need --native (the "
                         "pythonfmu FMU is FMI 2.0 Co-Simulation)")
    load_preset(args.preset)  # an unreadable or invalid preset: told before the build
    check_writable_dir(args.out, "--out")  # before the build, not after it
    name = fmu_file_name(args.native, args.fmi_version, args.interface)
    check_writable(args.out / name, "--out")  # an existing FMU: only with --force
    print(build_fmu(args.out, args.preset, native=args.native, fmi_version=args.fmi_version,
                    interface=args.interface, overwrite=True))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build-fmu", help="build the FMI 2.0 Co-Simulation FMU into build/")
    p.add_argument("--out", type=path, default=Path("build"), metavar="DIR",
                   help="folder of the FMU (default build)")
    p.add_argument("--native", action="store_true",
                   help="build ToggleClampNative.fmu: generated C, no Python at run time")
    p.add_argument("--fmi-version", type=int, choices=(2, 3), default=2,
                   help="with --native: FMI 2.0 or 3.0 (default 2)")
    p.add_argument("--interface", choices=("cs", "me", "both"), default="cs",
                   help="with --native: Co-Simulation, Model Exchange or both in one FMU "
                        "(default cs); file ToggleClampNative[3][ME|CSME].fmu")
    p.add_argument("--preset", default="chang2021",
                   help="the preset the FMU is built for: its values are the parameters' start "
                        "values; it needs [dynamics] and [drive] (default chang2021)")
    p.set_defaults(handler=run, checks_outputs=True)
