"""Benchmark: cold plan (problem construction + solve) and warm re-plan, N = 200, full model.

Cold: a new ClampPlanner for chang2021 (plant functions, NLP, IPOPT instance) and a solve
from the polynomial guess. Warm: the same planner re-plans a 2 % longer or shorter stroke
from the previous solution (primal and dual), as after a small change of the request.
Prints medians over several runs with iteration counts; targets 0.3 s cold and 20 ms warm.
Run: python benchmarks/bench_planner.py [--runs 5] [--intervals 200]
"""

from __future__ import annotations

import argparse
import statistics
import time

from controllers.limits import drive_limits
from controllers.planner import ClampPlanner, plan_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--intervals", type=int, default=200)
    parser.add_argument("--duration", type=float, default=3.0)
    args = parser.parse_args()
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    cold, cold_iter, warm, warm_iter, solve_only = [], [], [], [], []
    for _ in range(args.runs):
        tic = time.perf_counter()
        planner = ClampPlanner(cfg, limits, intervals=args.intervals)
        plan = planner.solve(args.duration, warm=False)
        cold.append(time.perf_counter() - tic)
        solve_only.append(plan.solve_time)
        cold_iter.append(plan.iterations)
        planner.solve(args.duration * 1.02)  # creates the warm-start IPOPT instance once
        for factor in (0.98, 1.0, 1.02):
            tic = time.perf_counter()
            replan = planner.solve(args.duration * factor)
            warm.append(time.perf_counter() - tic)
            warm_iter.append(replan.iterations)
    med = statistics.median
    print(f"chang2021, N = {args.intervals}, duration {args.duration} s, "
          f"peak {plan.peak_force:.4f} N")
    print(f"cold plan (construction + solve): {med(cold) * 1e3:8.1f} ms median "
          f"(IPOPT alone {med(solve_only) * 1e3:.1f} ms, {med(cold_iter):.0f} iterations)")
    print(f"warm re-plan:                     {med(warm) * 1e3:8.1f} ms median "
          f"({med(warm_iter):.0f} iterations; includes predicting the 1 ms samples)")


if __name__ == "__main__":
    main()
