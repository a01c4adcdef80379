"""Benchmark: cold plan (problem construction + solve), warm re-plan, N = 200, full model.

Cold: a new ClampPlanner for chang2021 (its functions loaded from the disk cache of
compiled code, controllers.compiled; the NLP and IPOPT instance built) and a solve from the
polynomial guess, with new planner objects every run (nothing built is reused in the
process, though the operating system keeps the shared library mapped); then the same in new
processes (imports excluded), where the IPOPT plugin is loaded too. First-ever: a new
process with an empty cache directory (TOGGLE_CACHE_DIR), which builds the functions
symbolically and compiles them (one run). Warm: the same planner re-plans a 2 % longer or
shorter stroke from the previous solution (primal and dual). Mold: a planner for another
mold height (+-0.1 mm of contact position) on the same built problem re-plans from the
previous solution. Limits: planners with another top speed (+-5 %) or pin friction (+-10 %)
on the same built problem (these are parameters of the compiled problem: no rebuild, no
compile) re-plan from the previous solution. Drive: the same with another rotor inertia
(x2), torque-speed curve (x0.8) or platen mass (+10 %), also parameters. Best: the multi-
start plan (ClampPlanner.best) and minimum time under a 15.0 N force limit (continuation in
the limit), on new planners over the loaded problem. Medians over several runs with
iteration counts, each also as a ratio to the baseline measured in the same run: the cold
plan with the cache filled. Targets 0.3 s cold and 20 ms warm.
Run: python benchmarks/bench_planner.py [--runs 5] [--intervals 200]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace

from controllers.limits import drive_limits
from controllers.planner import ClampPlanner
from controllers.plans import plan_config


def _timed(fn, *args, **kwargs):
    tic = time.perf_counter()
    result = fn(*args, **kwargs)
    return time.perf_counter() - tic, result


def cold(intervals: int, duration: float) -> dict[str, float]:
    """One cold plan on new objects: construction, solve, total (s) and iterations."""
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    tic = time.perf_counter()
    planner = ClampPlanner(cfg, limits, intervals=intervals)
    planner.problem.solver(False, energy=False)
    build = time.perf_counter() - tic
    plan = planner.solve(duration, warm=False)
    return {"total": time.perf_counter() - tic, "build": build, "ipopt": plan.solve_time,
            "iterations": plan.iterations, "peak": plan.peak_force}


def _in_new_process(args: argparse.Namespace, cache: str | None) -> dict[str, float]:
    """:func:`cold` in a new Python process (optionally with another cache directory)."""
    env = dict(os.environ, TOGGLE_COMPILE="wait",  # the first-ever plan compiles first
               **({"TOGGLE_CACHE_DIR": cache} if cache else {}))
    out = subprocess.run([sys.executable, __file__, "--child", "--intervals",
                          str(args.intervals), "--duration", str(args.duration)],
                         env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--intervals", type=int, default=200)
    parser.add_argument("--duration", type=float, default=3.0)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(cold(args.intervals, args.duration)))
        return
    with tempfile.TemporaryDirectory() as empty:
        first = _in_new_process(args, empty)
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    colds = [cold(args.intervals, args.duration) for _ in range(args.runs)]
    fresh = [_in_new_process(args, None) for _ in range(args.runs)]
    times: dict[str, list[float]] = {"warm": [], "mold": [], "limits": [], "drive": [],
                                     "best": [], "min_time": []}
    iters: dict[str, list[int]] = {"warm": [], "mold": [], "limits": [], "drive": []}
    mech, drive = cfg.mechanism, cfg.mechanism.drive
    rotor = cfg.with_(mechanism=replace(mech, drive=replace(
        drive, rotor_inertia=2 * drive.rotor_inertia)))
    platen = cfg.with_(mechanism=replace(mech, dynamics=replace(
        mech.dynamics, platen=1.1 * mech.dynamics.platen)))
    weaker = replace(limits, torque=0.8 * limits.torque)
    for _ in range(args.runs):
        planner = ClampPlanner(cfg, limits, intervals=args.intervals)
        plan = planner.solve(args.duration, warm=False)
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
        for changed in (replace(limits, velocity=limits.velocity * 1.05),
                        replace(limits, velocity=limits.velocity * 0.95)):
            other = ClampPlanner(cfg, changed, problem=planner.problem)
            elapsed, replan = _timed(other.solve, args.duration)
            times["limits"].append(elapsed)
            iters["limits"].append(replan.iterations)
        for mu in (cfg.friction * 1.1, cfg.friction * 0.9):
            other = ClampPlanner(cfg.with_(mu=mu), limits, problem=planner.problem)
            elapsed, replan = _timed(other.solve, args.duration)
            times["limits"].append(elapsed)
            iters["limits"].append(replan.iterations)
        for other_cfg, other_limits in ((rotor, limits), (cfg, weaker), (platen, limits)):
            other = ClampPlanner(other_cfg, other_limits, problem=planner.problem)
            elapsed, replan = _timed(other.solve, args.duration)
            times["drive"].append(elapsed)
            iters["drive"].append(replan.iterations)
    for _ in range(max(1, args.runs // 2)):
        fresh_planner = ClampPlanner(cfg, limits, problem=planner.problem)
        fresh_planner.lower_bound()  # computed once per planner, timed apart
        elapsed, best = _timed(fresh_planner.best, args.duration)
        times["best"].append(elapsed)
        fresh_planner = ClampPlanner(cfg, limits, problem=planner.problem)
        fresh_planner.lower_bound()
        elapsed, fastest = _timed(fresh_planner.minimum_time, 15.0, warm=False)
        times["min_time"].append(elapsed)
    bound_time, bound = _timed(ClampPlanner(cfg, limits, problem=planner.problem).lower_bound)

    def med(runs: list[dict[str, float]], key: str) -> float:
        return statistics.median(run[key] for run in runs)

    baseline = med(colds, "total")

    def ratio(seconds: float) -> str:
        return f"{seconds / baseline:6.2f}x baseline"

    print(f"chang2021, N = {args.intervals}, duration {args.duration} s, "
          f"peak {plan.peak_force:.4f} N")
    for label, runs in (("cold plan, cache filled:       ", colds),
                        ("cold plan, new process:        ", fresh)):
        print(f"{label}{med(runs, 'total') * 1e3:8.1f} ms median, {ratio(med(runs, 'total'))} "
              f"(construction {med(runs, 'build') * 1e3:.1f} ms, IPOPT "
              f"{med(runs, 'ipopt') * 1e3:.1f} ms, {med(runs, 'iterations'):.0f} iterations)")
    print(f"cold plan, first-ever:         {first['total']:8.2f} s (construction with "
          f"compilation {first['build']:.2f} s, IPOPT {first['ipopt'] * 1e3:.1f} ms; one run, "
          "empty cache)")
    for key, label in (("warm", "warm re-plan (duration +-2 %): "),
                       ("mold", "warm re-plan (mold +-0.1 mm):  "),
                       ("limits", "re-plan (v_max +-5 %, mu +-10 %):"),
                       ("drive", "re-plan (J_m, curve, platen):  ")):
        m = statistics.median(times[key])
        print(f"{label}{m * 1e3:8.1f} ms median, {ratio(m)} "
              f"({statistics.median(iters[key]):.0f} iterations, no rebuild)")
    print(f"peak lower bound {bound:.4f} N:       {bound_time * 1e3:8.1f} ms, {ratio(bound_time)}")
    m = statistics.median(times["best"])
    print(f"best of several starts:        {m * 1e3:8.1f} ms median, {ratio(m)} "
          f"(peak {best.peak_force:.4f} N vs {plan.peak_force:.4f} N from one cold start)")
    m = statistics.median(times["min_time"])
    print(f"minimum time under 15.0 N:     {m * 1e3:8.1f} ms median, {ratio(m)} "
          f"({fastest.duration:.4f} s, peak {fastest.peak_force:.4f} N at 1 ms)")
    print("(new processes: Python and library imports excluded; the 1 ms samples through the "
          "plant, Plan.samples, are computed when first asked for; not included)")


if __name__ == "__main__":
    main()
