"""The search's motor-duty estimates against the planner on several SM-55 designs.

``close_rms_torque`` and ``close_energy`` (:func:`design.timing.close_duty`) are read on the
closing-time bound's profile, not on a plan; the search weighs them in place of the planner
(docs/design.md). This script runs a reduced SM-55 search (``design/examples/sm55.toml``),
takes designs spread along its front (by closing-time bound) and the SM-55 itself, opens
each to the targets' mold stroke (the comparison's rule, :func:`design.placement.compare`),
and for each prints the estimates beside the minimum-time plan's RMS torque and shaft energy
without regeneration over the same stroke (what ``close_energy`` measures: the plan's
electrical energy adds the copper losses) (``toggle plan --min-time --force-limit 1e5``,
one compile per design: minutes on a loaded machine).

The tolerance, stated before the run: the search uses the estimates to rank designs, so
each design's change against the SM-55 by the estimate must be within
``TOLERANCE_PP`` percentage points of the planner's change, and the two must order the
designs alike (Kendall's tau printed). Levels are not compared (the bound's profile has no
jerk limit: its RMS torque is above the plan's). Also printed: the stroke's integral of the
torque squared (its share of a molding cycle's RMS torque, which does not depend on how
the stroke's own duration divides it) and the duration, by the same rule.

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
#: Largest difference between the estimate's and the planner's change against the SM-55,
#: percentage points (docs/design.md measured 0.02-0.03 on one design).
TOLERANCE_PP = 2.0
PLAN = ["--min-time", "--force-limit", "1e5", "--json"]


def planned(preset: Path) -> dict:
    """The minimum-time plan's duty over the stroke (``toggle plan ... --json``)."""
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        if toggle(["plan", "--preset", str(preset), *PLAN]) != 0:
            raise SystemExit(f"toggle plan --preset {preset} failed")
    duty = json.loads(text.getvalue())["duty"]
    return {"close_rms_torque": duty["rms_torque"],
            "close_energy": duty["shaft_energy_without_regeneration"],
            "close_time": duty["cycle_time"],
            "torque_squared": duty["torque_squared_integral"]}


def estimated(metrics: dict) -> dict:
    """The search's estimates, and the integral of the torque squared they imply (N^2 m^2 s:
    the stroke's share of a molding cycle's RMS torque, whatever the stroke's duration)."""
    return {"close_rms_torque": metrics["close_rms_torque"],
            "close_energy": metrics["close_energy"], "close_time": metrics["close_time"],
            "torque_squared": metrics["close_rms_torque"] ** 2 * metrics["close_time"]}


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
            plan = planned(path)
            rows.append((name, estimated(des.metrics), plan))
            print(f"  {name}: estimate {des.metrics['close_rms_torque']:.4g} N m "
                  f"{des.metrics['close_energy']:.4g} J, planner "
                  f"{plan['close_rms_torque']:.4g} N m {plan['close_energy']:.4g} J",
                  flush=True)
    base_est, base_plan = rows[0][1], rows[0][2]
    keys = ("close_rms_torque", "close_energy", "torque_squared", "close_time")
    print("\n| design | " + " | ".join(f"{k} est. | planner | change est. | planner"
                                     for k in keys) + f" |\n{'|---' * (1 + 4 * len(keys))}|")
    worst = dict.fromkeys(keys, 0.0)
    for name, est, plan in rows:
        cells = []
        for k in keys:
            ce = 100 * (est[k] / base_est[k] - 1)
            cp = 100 * (plan[k] / base_plan[k] - 1)
            worst[k] = max(worst[k], abs(ce - cp))
            cells += [f"{est[k]:.4g}", f"{plan[k]:.4g}", f"{ce:+.2f} %", f"{cp:+.2f} %"]
        print(f"| {name} | " + " | ".join(cells) + " |")
    print()
    for k in worst:
        tau = kendalltau([r[1][k] for r in rows], [r[2][k] for r in rows]).statistic
        ratio = [r[1][k] / r[2][k] for r in rows]
        print(f"{k}: largest difference of the changes {worst[k]:.2f} percentage points "
              f"({'within' if worst[k] <= TOLERANCE_PP else 'OUTSIDE'} {TOLERANCE_PP:g}); "
              f"Kendall tau {tau:.3f}; estimate over planner {min(ratio):.3f} to "
              f"{max(ratio):.3f}")


if __name__ == "__main__":
    main()
