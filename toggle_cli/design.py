"""``toggle design``: search the double-toggle family for a targets file (:mod:`design`).

Evaluates by default on a local Dask cluster (one worker per free core, at least two) where
the kernel's fair share of the cores gives it more than this process, or in this process on
one core or for a small search (design.runner.default_workers); on an existing cluster with
``--scheduler tcp://HOST:PORT``; in this process with ``--workers 0``. One progress bar
counts the whole search, with an ETA. Then each design on the front gets the motor's duty
from the planner: the minimum-time closing and opening strokes and the molding cycle with
the targets' dwells (RMS torque, energy, durations: about 1.4 s a design on an idle core, on
the same back-end, a bar of its own; ``--no-front-duty`` skips it).
Every evaluation is appended to OUT/evaluations.jsonl as it arrives: run the same command
again to resume. Writes OUT/pareto.csv, pareto.parquet, all.csv, presets/*.toml (each
takes ``--preset FILE`` in the other commands) and the figures front.png and parallel.png.
The search packages (dask, pymoo) are imported only when the command runs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from toggle.args import integer, path, positive
from toggle_cli.common import SEED, add_json_argument, declare_outputs, print_json

GENERATIONS = integer(1, 100_000, "must be a number of generations between 1 and 100000")
POPULATION = integer(4, 100_000, "must be a population between 4 and 100000")
WORKERS = integer(0, 4096, "must be a number of local workers between 0 and 4096")
DOE_SAMPLES = integer(1, 10_000_000, "must be a number of samples between 1 and 1e7")
DEFAULT_GENERATIONS, DEFAULT_POPULATION = 20, 40


def _doe(values: list[str]) -> tuple[str, int]:
    method, count = values
    if method not in ("lhs", "sobol"):
        raise argparse.ArgumentTypeError(f"--doe: method must be lhs or sobol, got {method!r}")
    try:
        return method, DOE_SAMPLES(count)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"--doe: {exc}") from None


class _DoeAction(argparse.Action):
    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        try:
            setattr(namespace, self.dest, _doe(list(values)))
        except argparse.ArgumentTypeError as exc:
            parser.error(str(exc))


def add_parser(sub: argparse._SubParsersAction) -> None:
    from design.targets import OBJECTIVES  # the registry only: no dask, no pymoo
    p = sub.add_parser("design", help="search clamp geometries for targets (Pareto set)",
                       description="Search the double-toggle family for the targets of a "
                       "TOML file and write the Pareto set, a preset of each design and "
                       "figures (docs/design.md).")
    p.add_argument("targets", type=path, help="targets TOML file (examples in "
                   f"design/examples/); objectives: {', '.join(OBJECTIVES)}")
    p.add_argument("--out", type=path, default=Path("design-out"), metavar="DIR",
                   help="results folder; a search of the same targets interrupted there is "
                        "resumed, a finished one's files are replaced only with --force")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                       help="an existing Dask scheduler (start one with `dask scheduler` and "
                            "workers with `dask worker tcp://HOST:PORT`); default: a local "
                            "cluster")
    p.add_argument("--connect-timeout", type=positive("time in s", 3600.0, unit="s"), default=10.0,
                   help="seconds to wait for the --scheduler before giving up")
    where.add_argument("--workers", type=WORKERS, default=None,
                       help="local worker processes (default: one per free core, or none "
                            "when at most one core is free or the search is under 200 "
                            "candidates; 0: no Dask, evaluate in this process)")
    p.add_argument("--doe", nargs=2, metavar=("lhs|sobol", "N"), action=_DoeAction,
                   default=None, help="a design of experiments of N candidates instead of "
                                      "the genetic algorithm")
    p.add_argument("--generations", type=GENERATIONS, default=None,
                   help=f"NSGA-II/III generations (default {DEFAULT_GENERATIONS})")
    p.add_argument("--population", type=POPULATION, default=None,
                   help=f"NSGA-II/III population (default {DEFAULT_POPULATION})")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the search (a seed replays)")
    p.add_argument("--no-figures", action="store_true", help="write no figures")
    p.add_argument("--no-front-duty", action="store_true",
                   help="do not plan the front's designs' strokes and molding cycles (the "
                        "motor's RMS torque and energy, about 1.4 s a design)")
    add_json_argument(p)
    # checked before the search (the evaluations.jsonl an interrupted search left is not)
    declare_outputs(p, "pareto.csv", "pareto.parquet", "all.csv", "front.png", "parallel.png")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """The search through the public API (:func:`design.search_designs`), reported."""
    from design import search_designs
    from design.targets import OBJECTIVES, load_targets
    from toggle.params import ParameterError

    if args.doe and (args.generations or args.population):
        raise ParameterError("--doe replaces the genetic algorithm: give it without "
                             "--generations and --population")
    targets = load_targets(args.targets)
    method, samples = args.doe or (None, 0)
    try:
        result = search_designs(targets, args.out,
                                generations=args.generations or DEFAULT_GENERATIONS,
                                population=args.population or DEFAULT_POPULATION,
                                doe=method, samples=samples, seed=args.seed,
                                scheduler=args.scheduler, workers=args.workers,
                                progress=not args.json, front_duty=not args.no_front_duty,
                                figures=not args.no_figures,
                                connect_timeout=args.connect_timeout)
    except KeyboardInterrupt:
        from design.store import FILE
        if (args.out / FILE).exists():  # written with the first evaluation received
            print(f"toggle design: the evaluations so far are kept in {args.out}; run the same "
                  "command again to resume", file=sys.stderr)
        else:
            print("toggle design: stopped before any evaluation finished; nothing was kept",
                  file=sys.stderr)
        raise
    files, placements = result.files, result.placements
    summary = {"evaluations": len(result.evaluations), "computed": result.computed,
               "feasible": len(result.feasible), "pareto": len(result.front),
               "files": {k: str(v) for k, v in files.items()},
               "references": [{"name": p.name, "status": p.status,
                               "dominated_by": p.dominated_by and p.dominated_by.key,
                               "margin": p.margin, "metrics": p.reference.metrics}
                              for p in placements]}
    if args.json:
        print_json(summary)
        return 0
    keys = targets.objectives
    print(f"{targets.origin}: {summary['evaluations']} designs ({result.computed} computed, "
          f"the rest from {args.out}), {summary['feasible']} feasible, "
          f"{summary['pareto']} in the Pareto set")
    sense = OBJECTIVES[keys[0]].sense
    best = sorted(result.front, key=lambda e: -sense * e.metrics[keys[0]])[:10]  # best first
    headers = ["design", *(OBJECTIVES[k].header for k in keys)]
    widths = [max(12, len(h)) for h in headers]
    print("  ".join(f"{h:>{w}}" for h, w in zip(headers, widths)))
    for e in best:  # SI values, as in pareto.csv
        cells = [e.key[:12], *(f"{e.metrics[k]:.6g}" for k in keys)]
        print("  ".join(f"{c:>{w}}" for c, w in zip(cells, widths)))
    for p in placements:
        by = (f" by design-{p.dominated_by.key[:12]}, every objective at least "
              f"{100 * p.margin:.3g} % better" if p.dominated_by else
              f" (design-{p.nearest.key[:12]} is {100 * p.shortfall:.3g} % short of "
              "dominating it)" if p.nearest else "")
        print(f"{p.name}: {p.status}{by}")
    return 0
