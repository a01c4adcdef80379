"""Benchmark: cold plan (problem construction + solve), warm re-plan, N = 200, full model.

Cold: a new ClampPlanner for chang2021 (symbolic plant, per-node jets, NLP, IPOPT instance)
and a solve from the polynomial guess. Warm: the same planner re-plans a 2 % longer or
shorter stroke from the previous solution (primal and dual). Mold: a planner for another
mold height (+-0.1 mm of contact position) on the same built problem re-plans from the
previous solution. Medians over several runs with iteration counts; targets 0.3 s cold and
20 ms warm. The compiled per-node jets come from the disk cache (controllers.compiled);
the first run after a change of the model also compiles them (about a second).
Run: python benchmarks/bench_planner.py [--runs 5] [--intervals 200]
"""

from __future__ import annotations

import argparse
import statistics
import time

from controllers.limits import drive_limits
from controllers.planner import ClampPlanner, plan_config


def _timed(fn, *args, **kwargs):
    tic = time.perf_counter()
    result = fn(*args, **kwargs)
    return time.perf_counter() - tic, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--intervals", type=int, default=200)
    parser.add_argument("--duration", type=float, default=3.0)
    args = parser.parse_args()
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    times: dict[str, list[float]] = {"cold": [], "build": [], "ipopt": [], "warm": [],
                                     "mold": []}
    iters: dict[str, list[int]] = {"cold": [], "warm": [], "mold": []}
    for _ in range(args.runs):
        tic = time.perf_counter()
        planner = ClampPlanner(cfg, limits, intervals=args.intervals)
        planner.problem.solver(False)
        times["build"].append(time.perf_counter() - tic)
        plan = planner.solve(args.duration, warm=False)
        times["cold"].append(time.perf_counter() - tic)
        times["ipopt"].append(plan.solve_time)
        iters["cold"].append(plan.iterations)
        planner.solve(args.duration * 1.02)  # creates the warm-start IPOPT instance once
        for factor in (0.98, 1.0, 1.02):
            elapsed, replan = _timed(planner.solve, args.duration * factor)
            times["warm"].append(elapsed)
            iters["warm"].append(replan.iterations)
        for shift in (-1e-4, 1e-4, 0.0):
            moved = ClampPlanner(cfg.with_(x_contact=cfg.x_contact + shift), limits,
                                 problem=planner.problem)
            elapsed, replan = _timed(moved.solve, args.duration)
            times["mold"].append(elapsed)
            iters["mold"].append(replan.iterations)
    med = statistics.median
    print(f"chang2021, N = {args.intervals}, duration {args.duration} s, "
          f"peak {plan.peak_force:.4f} N")
    print(f"cold plan (construction + solve): {med(times['cold']) * 1e3:8.1f} ms median "
          f"(construction {med(times['build']) * 1e3:.1f} ms, IPOPT "
          f"{med(times['ipopt']) * 1e3:.1f} ms, {med(iters['cold']):.0f} iterations)")
    print(f"warm re-plan (duration +-2 %):    {med(times['warm']) * 1e3:8.1f} ms median "
          f"({med(iters['warm']):.0f} iterations)")
    print(f"warm re-plan (mold +-0.1 mm):     {med(times['mold']) * 1e3:8.1f} ms median "
          f"({med(iters['mold']):.0f} iterations, no rebuild)")
    print("(the 1 ms samples through the plant, Plan.samples, are computed when first asked "
          "for; not included)")


if __name__ == "__main__":
    main()
