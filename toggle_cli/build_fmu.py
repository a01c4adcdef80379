"""``toggle build-fmu``: write ToggleClamp.fmu (FMI 2.0 Co-Simulation) of one preset into
the build folder that ``hil run`` takes its FMU from (:func:`fmu_src.build.build_folder`:
the checkout's build/, or build/ of the current folder where the project is installed).

``--native`` writes the native FMU instead: the plant generated to C, no Python at run
time (:mod:`fmu_src.native_build`), for FMI 2.0 or 3.0 (``--fmi-version``), Co-Simulation,
Model Exchange or both (``--interface``); ToggleClampNative.fmu by default (2, cs).
The last line names the FMU (``results in DIR/ (ToggleClamp.fmu)``).
"""

from __future__ import annotations

import argparse

from toggle.args import path
from toggle.files import check_writable, check_writable_dir, note_written
from toggle.params import load_preset


def run(args: argparse.Namespace) -> int:
    """Build the FMU asked for through the public API (:func:`fmu_src.build_fmu`), after
    the checks that name the command's options."""
    from fmu_src import build_fmu, fmu_file_name
    from fmu_src.build import build_folder

    if not args.native and (args.fmi_version, args.interface) != (2, "cs"):
        raise ValueError("--fmi-version 3 and --interface me|both need --native (the "
                         "pythonfmu FMU is FMI 2.0 Co-Simulation)")
    out = args.out if args.out is not None else build_folder()
    load_preset(args.preset)  # an unreadable or invalid preset: told before the build
    check_writable_dir(out, "--out")  # before the build, not after it
    name = fmu_file_name(args.native, args.fmi_version, args.interface)
    check_writable(out / name, "--out")  # an existing FMU: only with --force
    note_written(build_fmu(out, args.preset, native=args.native, fmi_version=args.fmi_version,
                           interface=args.interface, overwrite=True))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build-fmu", help="build the FMI 2.0 Co-Simulation FMU that hil run runs",
                       description="Build ToggleClamp.fmu of a preset into the build folder, "
                                   "where hil run takes it from (hil run without --preset "
                                   "runs the FMU built last, with its preset).")
    p.add_argument("--out", type=path, default=None, metavar="DIR",
                   help="folder of the FMU (default: the build folder hil run reads: the "
                        "checkout's build/ when run from a checkout, else ./build)")
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
