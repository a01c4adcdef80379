"""The search's motor-duty objectives against the planner's default plan on several SM-55
designs.

``close_rms_torque`` and ``close_energy`` (:func:`design.timing.planned_duty`) are the
minimum-time plan's, planned at :data:`design.timing.DUTY_INTERVALS` intervals with the
problem's functions interpreted (no compile per candidate); ``close_time`` is the
phase-plane bound the search ranks by. This script runs a reduced SM-55 search
(``design/examples/sm55.toml``), takes designs spread along its front (by closing-time
bound) and the SM-55 itself, opens each to the targets' mold stroke (the comparison's rule,
:func:`design.placement.compare`), and for each prints the search's figures beside
``toggle plan --min-time --force-limit 1e5 --cycle`` with the targets' hold and ejection
dwells on the design's preset (200 intervals,
compiled: one compile per design, minutes on a loaded machine): its RMS torque, shaft
energy without regeneration (what ``close_energy`` is: the plan's electrical energy adds
the copper losses) and duration.

The tolerances, stated before the run: each design's change against the SM-55 by the
search's figure within ``TOLERANCE_PP`` percentage points of the planner's change, the two
ordering the designs alike (Kendall's tau printed), and for the duty (the same planner on a
coarser grid) the level within ``LEVEL`` of the planner's. Also printed: the stroke's
integral of the torque squared (its share of a molding cycle's RMS torque, which does not
depend on how the stroke's own duration divides it) and the bound against the plan's
duration (a bound: below it, levels not compared).

    .venv/bin/python benchmarks/bench_design_duty.py [--designs 7] [--generations 6]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import tempfile
from pathlib import Path

import numpy as np
from scipy.stats import kendalltau

from design.objectives import Evaluation, Evaluator
from design.output import write_preset
from design.placement import compare, reference_designs
from design.search import run_search
from design.targets import load_targets
from toggle_cli import main as toggle

ROOT = Path(__file__).resolve().parents[1]
TARGETS = ROOT / "design" / "examples" / "sm55.toml"
#: Largest difference of the search's and the planner's change against the SM-55,
#: percentage points, and largest relative difference of the duty's levels.
TOLERANCE_PP, LEVEL = 2.0, 0.01
PLAN = ["--min-time", "--force-limit", "1e5", "--json", "--cycle"]


def planned(preset: Path, hold: float, eject: float) -> dict:
    """The minimum-time plan's duty over the stroke and the molding cycle with the targets'
    dwells (``toggle plan ... --json --cycle --hold H --eject E``)."""
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        if toggle(["plan", "--preset", str(preset), *PLAN, "--hold", str(hold), "--eject",
                   str(eject)]) != 0:
            raise SystemExit(f"toggle plan --preset {preset} failed")
    result = json.loads(text.getvalue())
    duty, cycle = result["duty"], result["molding_cycle"]
    return {"close_rms_torque": duty["rms_torque"],
            "close_energy": duty["shaft_energy_without_regeneration"],
            "close_plan_time": duty["cycle_time"], "close_time": duty["cycle_time"],
            "cycle_rms_torque": cycle["rms_torque"],
            "cycle_energy": cycle["shaft_energy_without_regeneration"],
            "torque_squared": duty["torque_squared_integral"]}


def estimated(metrics: dict) -> dict:
    """The search's figures, and the integral of the torque squared they give (N^2 m^2 s:
    the stroke's share of a molding cycle's RMS torque, whatever the stroke's duration)."""
    keys = ("close_rms_torque", "close_energy", "close_plan_time", "close_time",
            "cycle_rms_torque", "cycle_energy")
    return {**{k: metrics[k] for k in keys},
            "torque_squared": metrics["close_rms_torque"] ** 2 * metrics["close_plan_time"]}


def spread(front: list[Evaluation], n: int) -> list[Evaluation]:
    """``n`` designs of the front spread evenly along their closing-time bound."""
    ordered = sorted(front, key=lambda e: e.metrics["close_time"])
    picks = np.unique(np.linspace(0, len(ordered) - 1, min(n, len(ordered))).round())
    return [ordered[int(i)] for i in picks]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--designs", type=int, default=7)
    parser.add_argument("--generations", type=int, default=6)
    parser.add_argument("--population", type=int, default=40)
    args = parser.parse_args()
    targets = load_targets(TARGETS)
    evaluator = Evaluator(targets)
    stroke = targets.targets["mold_open_stroke"]
    (sm55,) = reference_designs(targets).values()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        result = run_search(targets, Path(tmp) / "record", generations=args.generations,
                            population=args.population, seed=0, workers=0)
        chosen = spread(result.front, args.designs)
        print(f"{len(result.front)} designs on the front of a {args.generations} x "
              f"{args.population} search; {len(chosen)} taken, and the SM-55; load average "
              f"{os.getloadavg()[0]:.1f}", flush=True)
        for i, design in enumerate([None, *chosen]):
            des, ref, _, _ = compare(evaluator, sm55 if design is None else design.variables,
                                     sm55, stroke)
            name = "SM-55" if design is None else f"design-{des.key[:12]}"
            path = write_preset(Path(tmp) / f"d{i}.toml", targets, des, name=f"d{i}")
            plan = planned(path, targets.settings["hold"], targets.settings["eject"])
            rows.append((name, estimated(des.metrics), plan))
            print(f"  {name}: search {des.metrics['close_rms_torque']:.4g} N m "
                  f"{des.metrics['close_energy']:.4g} J, planner "
                  f"{plan['close_rms_torque']:.4g} N m {plan['close_energy']:.4g} J",
                  flush=True)
    base_search, base_plan = rows[0][1], rows[0][2]
    keys = ("close_rms_torque", "close_energy", "torque_squared", "close_plan_time",
            "close_time", "cycle_rms_torque", "cycle_energy")
    print("\n| design | " + " | ".join(f"{k} search | planner | change search | planner"
                                     for k in keys) + f" |\n{'|---' * (1 + 4 * len(keys))}|")
    worst = dict.fromkeys(keys, 0.0)
    for name, found, plan in rows:
        cells = []
        for k in keys:
            ce = 100 * (found[k] / base_search[k] - 1)
            cp = 100 * (plan[k] / base_plan[k] - 1)
            worst[k] = max(worst[k], abs(ce - cp))
            cells += [f"{found[k]:.4g}", f"{plan[k]:.4g}", f"{ce:+.2f} %", f"{cp:+.2f} %"]
        print(f"| {name} | " + " | ".join(cells) + " |")
    print()
    for k in worst:
        tau = kendalltau([r[1][k] for r in rows], [r[2][k] for r in rows]).statistic
        ratio = [r[1][k] / r[2][k] for r in rows]
        level = "" if k == "close_time" else (
            f" ({'within' if max(abs(r - 1) for r in ratio) <= LEVEL else 'OUTSIDE'} "
            f"{LEVEL:.0%})")
        print(f"{k}: largest difference of the changes {worst[k]:.2f} percentage points "
              f"({'within' if worst[k] <= TOLERANCE_PP else 'OUTSIDE'} {TOLERANCE_PP:g}); "
              f"Kendall tau {tau:.3f}; search over planner {min(ratio):.4f} to "
              f"{max(ratio):.4f}{level}")


if __name__ == "__main__":
    main()
