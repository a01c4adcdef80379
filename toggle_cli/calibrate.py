"""``toggle calibrate``: fit the unequal-halves model to measured toggle forces.

Reads a table in the paper's shape (``toggle/data/chang2021_tables.toml`` by default:
F_TP mean and three-sigma band per speed and link-8 error, mm/s, mm, N as printed),
fits at most three parameters on the rows of the given speeds and prints the fitted
values (SI) and every row of the table side by side with the model.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import asdict

from toggle.args import path
from toggle.params import ParameterError, load_preset
from toggle_cli.common import (
    MM,
    SPEED,
    add_arguments_later,
    add_json_argument,
    add_preset_argument,
    mechanism,
    print_json,
    table,
)

#: Units of the fittable parameters, for the printed summary.
FITTED_UNITS = {"free_play": "m", "contact_stiffness": "N/m^1.5", "series_stiffness": "N/m",
                "drive_stiffness": "N/m", "mu": "(1)", "rate_strengthening": "(1)",
                "hersey_transition": "m/(s N)"}


def run(args: argparse.Namespace) -> int:
    from toggle.calibration import calibrate, compare, load_force_table, table_mechanism

    data = load_force_table(args.table)
    mech = mechanism(args)
    measured = table_mechanism(args.table)
    if measured is not None:
        rig = load_preset(measured)
        if (mech.lower, mech.upper) != (rig.lower, rig.upper):
            raise ParameterError(
                f"--preset {args.preset}: {args.table} was measured on {measured}, whose "
                f"links differ; give --preset {measured} or a table measured on your clamp")
    cal = calibrate(data, mech, tuple(args.speeds), fit=tuple(args.fit))
    rows = compare(data, mech, cal.params)
    fitted = {name: getattr(cal.params, name) for name in cal.fitted}
    if args.json:
        print_json({"fitted": fitted, "calibration_speeds": list(cal.speeds),
                    "rows": [{**r._asdict(), "within_three_sigma": r.within_band} for r in rows],
                    "params": {k: v for k, v in asdict(cal.params).items() if k != "pins"}})
        return 0
    print(f"{mech.name}: fitted on the rows at "
          f"{', '.join(f'{s * MM:g}' for s in cal.speeds)} mm/s of {args.table}")
    for name, value in fitted.items():
        print(f"  {name} = {value:.6g} {FITTED_UNITS.get(name, '(SI)')}")
    print(table(["v mm/s", "dr8 mm", "F_TP N", "+-3sigma N", "model N", "error N",
                 "error %", "in band"],
                [(r.speed * MM, r.error * MM, r.measured, r.three_sigma, r.model,
                  r.model - r.measured,
                  "n/a" if math.isnan(r.relative_error) else 100 * r.relative_error,
                  "yes" if r.within_band else "no") for r in rows],
                fmt="{:>12.2f}"))
    if any(math.isnan(r.relative_error) for r in rows):
        print("n/a: the measured F_TP is within its 3-sigma band of zero (the symmetric "
              "clamp), where a relative error means nothing; compare the error in N")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate",
                       help="fit the unequal-halves model to measured F_TP (seed 000 Tables 6-8)")
    add_arguments_later(p, _add_arguments)
    p.set_defaults(handler=run)


def _add_arguments(p: argparse.ArgumentParser) -> None:
    """The options, whose defaults and choices are :mod:`toggle.calibration`'s."""
    from toggle.calibration import FITTABLE, MAX_FITTED, PAPER_TABLES

    add_preset_argument(p, accepts=("chang2021",),
                        why="the paper's table was measured on the chang2021 rig")
    p.add_argument("--table", type=path, default=PAPER_TABLES,
                   help="TOML table in the paper's shape (default: seed 000 Tables 6-8)")
    p.add_argument("--speeds", type=SPEED, nargs="+", default=[5e-3, 15e-3],
                   help="speeds (m/s) whose rows are fitted (default 5e-3 15e-3 m/s)")
    p.add_argument("--fit", nargs="+", choices=FITTABLE, metavar="PARAM",
                   default=["free_play", "contact_stiffness", "hersey_transition"],
                   help=f"at most {MAX_FITTED} of: {', '.join(FITTABLE)} (default free_play "
                        "contact_stiffness hersey_transition)")
    add_json_argument(p)
