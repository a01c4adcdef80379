"""``toggle tolerance``: asymmetry indices, sensitivities and Monte Carlo for an IT grade."""

from __future__ import annotations

import argparse
from dataclasses import asdict

from toggle.args import integer
from toggle.params import DIMENSIONS, HALVES, PAPER_NAMES
from toggle_cli.common import (
    IT_GRADE,
    MM,
    POSITION,
    SEED,
    add_json_argument,
    add_out_argument,
    add_preset_argument,
    declare_outputs,
    mechanism,
    output,
    print_json,
    table,
)


def run(args: argparse.Namespace) -> int:
    from controllers.progress import Progress, reporting
    from toggle import mechanical_errors
    from toggle.tolerance import monte_carlo

    mech = mechanism(args)
    errors = mechanical_errors(mech, args.it, x=args.x)  # the Monte Carlo below: its bar
    tol, rep = errors.tolerances, errors.report
    budgets = {"lower": rep.lower, "upper": rep.upper}
    names = PAPER_NAMES
    data = {
        "preset": mech.name,
        "it_grade": args.it,
        "x": rep.x,
        "dL_wor": rep.dL_wor,
        "dL_rss": rep.dL_rss,
        "dL_exact": rep.dL_exact,
        "sensitivities": {h: {names[h][k]: budgets[h].sensitivities[k] for k in DIMENSIONS}
                          for h in HALVES},
        "tolerances": {h: {names[h][k]: tol[h][k] for k in DIMENSIONS} for h in HALVES},
        "contributions": {h: {names[h][k]: budgets[h].contributions[k] for k in DIMENSIONS}
                          for h in HALVES},
        "worst": {h: budgets[h].worst for h in HALVES},
        "rss": {h: budgets[h].rss for h in HALVES},
    }
    if args.samples:
        with reporting(Progress("Monte Carlo", "sample", args.samples,
                                enabled=not args.json)) as progress:
            mc = monte_carlo(mech, tol, x=rep.x, samples=args.samples,
                             distribution=args.distribution, seed=args.seed,
                             progress=progress.advance)
        data["monte_carlo"] = asdict(mc)
    if args.json:
        print_json(data)
        return 0
    print(f"preset {mech.name}, IT{args.it}, x = {rep.x * MM:.4f} mm "
          "(lower half at its lower deviations, upper half at its upper deviations)")
    rows = []
    for k in DIMENSIONS:
        rows.append((f"{names['lower'][k]}/{names['upper'][k]}", tol["lower"][k] * MM,
                     budgets["lower"].sensitivities[k], budgets["lower"].contributions[k] * MM,
                     budgets["upper"].sensitivities[k], budgets["upper"].contributions[k] * MM))
    print(table(("dimension", "IT mm", "dL/dp low", "dL low mm", "dL/dp up", "dL up mm"), rows,
                fmt="{:>12.5f}"))
    print(f"\nworst-case: lower {rep.lower.worst * MM:.4f} mm, upper {rep.upper.worst * MM:.4f} mm")
    print(f"RSS:        lower {rep.lower.rss * MM:.4f} mm, upper {rep.upper.rss * MM:.4f} mm")
    print(f"dL_wor = {rep.dL_wor * MM:.4f} mm   dL_rss = {rep.dL_rss * MM:.4f} mm   "
          f"exact nonlinear = {rep.dL_exact * MM:.4f} mm")
    if args.samples:
        mc = data["monte_carlo"]
        print(f"\nMonte Carlo ({args.samples} samples, {args.distribution}):")
        rows = [(k, mc[k]["mean"] * MM, mc[k]["std"] * MM, mc[k]["percentiles"]["p0.135"] * MM,
                 mc[k]["percentiles"]["p99.865"] * MM) for k in ("lower", "upper", "asymmetry")]
        print(table(("output", "mean mm", "sigma mm", "p0.135 mm", "p99.865 mm"), rows,
                    fmt="{:>12.5f}"))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tolerance", help="mechanical-error analysis for an ISO IT grade")
    add_preset_argument(p)
    add_json_argument(p)
    p.add_argument("--it", type=IT_GRADE, default=10, help="ISO 286-1 IT grade (default 10)")
    p.add_argument("--x", type=POSITION, default=None,
                   help="input position, m (default: the lower half's toggle position)")
    p.add_argument("--samples", type=integer(0, 100_000_000, "must be 0 to 1e8 samples"),
                   default=0, help="add a Monte Carlo run of N samples (default 0: none)")
    p.add_argument("--distribution", choices=("normal", "uniform"), default="normal",
                   help="Monte Carlo distribution: normal with sigma = IT/3, or uniform over +-IT")
    p.add_argument("--seed", type=SEED, default=0, help="random seed of the Monte Carlo run")
    p.set_defaults(handler=run)


def plot(args: argparse.Namespace) -> int:
    from toggle.plots import plot_it_grades, plot_sensitivity

    mech = mechanism(args)
    plot_sensitivity(mech, args.it, output(args, "sensitivity_IT{it}_{tag}.png"))
    plot_it_grades(mech, output(args, "asymmetry_vs_it_{tag}.png"))
    return 0


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("tolerance", help="error curves of each half and δL vs IT (Figs 7-9)")
    add_preset_argument(p)
    p.add_argument("--it", type=IT_GRADE, default=10, help="IT grade of the error curves")
    add_out_argument(p)
    declare_outputs(p, "sensitivity_IT{it}_{tag}.png", "asymmetry_vs_it_{tag}.png")
    p.set_defaults(handler=plot)
