"""``toggle tables``: the simulated rig against seed 000's Tables 3-8, optionally refitted.

Without ``--fit`` the shipped (calibrated) model is compared with every table. With
``--fit PARAM ...`` those parameters (at most six) are fitted on the rows of
``--speeds`` and the ``--statistics`` chosen, the stroke reading too when "stroke" is
among them; the fitted values print with one standard error. Every row prints with
its residual in units of the printed 3 sigma and the issue's verdict (stroke within
0.05 mm; forces within 25 % or 3 sigma, delta_r8 = 0 within 3 sigma). ``--out DIR``
writes one figure per statistic (measured mean +- 3 sigma against the simulated rig), as
every other command's ``--out``; ``--plot DIR``, its old name, still works and says so.
"""

from __future__ import annotations

import argparse
import sys

from toggle.args import path
from toggle.files import check_writable, check_writable_dir
from toggle_cli.common import (
    MM,
    SPEED,
    add_arguments_later,
    add_json_argument,
    add_preset_argument,
    mechanism,
    print_json,
)


def run(args: argparse.Namespace) -> int:
    from toggle.rig_calibration import (
        SHIPPED_FIT_SPEEDS,
        STAT_LABELS,
        STATISTICS,
        RigModel,
        Row,
        calibrate_rig,
        compare_tables,
        load_paper_tables,
        plot_tables,
        simulate_tables,
    )

    labels = {**STAT_LABELS, "stroke": "S"}
    _take_old_plot_option(args)
    if args.out is not None:
        check_writable_dir(args.out, "--out")  # before the simulation, not after it
        for stat in STATISTICS:  # plot_tables draws every statistic
            check_writable(args.out / f"tables_{stat}.png", "--out")
    tables = load_paper_tables()
    nominal = mechanism(args)
    model, fit = RigModel(), None
    if args.fit or args.speeds is not None or args.statistics is not None:
        # --speeds and --statistics choose the rows of a fit: never silently unused
        fit = calibrate_rig(tables, nominal, args.speeds or SHIPPED_FIT_SPEEDS, args.fit,
                            args.statistics or STATISTICS)
        model = fit.model
    simulated = simulate_tables(tables, nominal, model)
    rows = compare_tables(tables, simulated)
    fitted_speeds = set(fit.speeds) if fit else set(SHIPPED_FIT_SPEEDS)
    fitted_stats = set(fit.statistics) if fit else set(STATISTICS)

    def role(r: Row) -> str:
        """"fitted" if the row informed the model shown: a row of this refit, or of the
        shipped calibration (Tables 3-4, 6-7) for what a refit leaves (the force parameters
        not refitted; the reading, unless the stroke is refitted, which replaces it)."""
        if r.speed in fitted_speeds and r.statistic in fitted_stats:
            return "fitted"
        reading_refit = fit is not None and "stroke" in fit.statistics
        shipped = r.speed in SHIPPED_FIT_SPEEDS and not (r.statistic == "stroke"
                                                          and reading_refit)
        return "fitted" if shipped else "predicted"

    figures = [] if args.out is None else plot_tables(
        tables, nominal, model, args.out,
        {(r.statistic, r.speed) for r in rows if role(r) == "fitted"})
    if args.json:  # stdout is the JSON alone: the figures are listed in it
        print_json({
            "figures": [str(p) for p in figures],
            "fitted": fit.values if fit else {},
            # null: at a limit, or not identified (print_json writes no NaN or inf)
            "std_error": fit.std_error if fit else {},
            "at_limit": list(fit.at_limit) if fit else [],
            "reading": model.reading.__dict__, "as_built": model.as_built,
            "dynamics": model.dynamics,
            "reading_std_error": fit.stroke_std_error if fit else {},
            "fit_speeds": sorted(fitted_speeds),
            "fit_statistics": sorted(fitted_stats),
            "rows": [{**r._asdict(), "in_three_sigma": r.in_sigma, "holds": r.holds(),
                      "role": role(r)}
                     for r in rows]})
        return 0
    if fit:
        print(f"{nominal.name}: fitted on {', '.join(f'{s * MM:g}' for s in fit.speeds)} mm/s, "
              f"statistics {', '.join(labels[s] for s in fit.statistics)}")
        for name, value in fit.values.items():
            if name in fit.at_limit:
                print(f"  {name} = {value:.5g} (SI; at a limit of the model, held there: "
                      "no standard error)")
            else:
                print(f"  {name} = {value:.5g} +- {fit.std_error[name]:.2g} (SI, 1 s.e.)")
        for name, err in fit.stroke_std_error.items():
            print(f"  reading {name} = {getattr(model.reading, name):.5g} +- {err:.2g} (SI)")
    print(f"{'stat':>9} {'v mm/s':>7} {'dr8 mm':>7} {'measured':>18} {'simulated':>10} "
          f"{'res/3s':>7} {'rel %':>7}  role       verdict")
    for r in rows:
        scale = MM if r.statistic == "stroke" else 1.0
        print(f"{labels[r.statistic]:>9} {r.speed * MM:7g} {r.error * MM:7.2f} "
              f"{r.measured * scale:9.3f} +-{r.three_sigma * scale:7.3f} "
              f"{r.simulated * scale:10.3f} {r.in_sigma:+7.1f} {100 * r.relative:+7.1f}  "
              f"{role(r):10} {'holds' if r.holds() else 'MISSES'}")
    print("as-built errors of the rig (m): "
          + ", ".join(f"{n} = {v:.4g}" for n, v in model.as_built.items()))
    print("the rig's dynamics beyond its preset (SI): "
          + ", ".join(f"{n} = {v:.4g}" for n, v in model.dynamics.items()))
    held = sum(r.holds() for r in rows)
    print(f"{held} of {len(rows)} rows hold (units: mm for S, N for forces)")
    return 0


def _fittable(name: str) -> str:
    """A --fit name (the list, with the as-built errors of each dimension, is in --help)."""
    from toggle.rig_calibration import FORCE_FITTABLE

    if name not in FORCE_FITTABLE:
        raise argparse.ArgumentTypeError(f"{name!r} is not fittable (see toggle tables --help)")
    return name


def _take_old_plot_option(args: argparse.Namespace) -> None:
    """``--plot DIR``, the old name of ``--out DIR``: taken, with a note on stderr (as git
    does with a renamed option); both at once are refused."""
    if args.old_plot is None:
        return
    if args.out is not None:
        raise ValueError("give --out DIR alone (--plot is its old name)")
    print("toggle tables: --plot is deprecated; use --out DIR", file=sys.stderr)
    args.out = args.old_plot


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tables",
                       help="the simulated rig against seed 000 Tables 3-8 (fit, predict, plot)")
    add_arguments_later(p, _add_arguments)
    p.set_defaults(handler=run, checks_outputs=True)


def _add_arguments(p: argparse.ArgumentParser) -> None:
    """The options, whose choices are :mod:`toggle.rig_calibration`'s."""
    from toggle.rig_calibration import FORCE_FITTABLE, MAX_FORCE_FITTED, STATISTICS

    add_preset_argument(p, accepts=("chang2021",),
                        why="the paper's tables were measured on the chang2021 rig")
    p.add_argument("--fit", nargs="+", type=_fittable, metavar="PARAM",
                   default=[], help=f"refit at most {MAX_FORCE_FITTED} of: "
                                    f"{', '.join(FORCE_FITTABLE)}")
    p.add_argument("--speeds", type=SPEED, nargs="+", default=None,
                   help="speeds (m/s) whose rows are fitted (default 5e-3 15e-3 m/s); a refit")
    p.add_argument("--statistics", nargs="+", choices=STATISTICS, default=None,
                   metavar="STAT",
                   help=f"statistics fitted (default all: {', '.join(STATISTICS)}); a "
                        "refit: the forces need --fit, 'stroke' alone refits the reading")
    p.add_argument("--out", type=path, default=None, metavar="DIR",
                   help="write one PNG per statistic into DIR, named on the last line")
    p.add_argument("--plot", type=path, default=None, dest="old_plot", help=argparse.SUPPRESS)
    add_json_argument(p)
