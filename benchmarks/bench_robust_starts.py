"""Benchmark: what the late S-curve starts buy a robust plan (issue 45).

``ClampPlanner.best`` tries the polynomial guess and then late S-curves stretched 1, 1.1
and 1.25 times (``controllers.stroke_solver.LATE_STARTS``): on the nominal clamp a late
start wins the peak by 0.4 % (chang2021 at 3.1 s). A robust plan (the clamp with an
erroneous variant, ``toggle plan --robust``) judges the worst peak over both, and its
lower bound is the nominal clamp's, so it never stopped early and ran all four starts, the
late ones three quarters of its solving. This solves each start on its own for two
presets, six sets of dimensional errors and three durations (0.8, 1 and 1.3 times the
default) and prints the
worst peak from the polynomial start, the best of the late ones, what the late starts gain
over the polynomial (in % of the best) and the seconds each took; ``late_starts()`` skips
them for a robust peak where the largest gain stays within ``GAP``.

Run: python benchmarks/bench_robust_starts.py
"""

from __future__ import annotations

import argparse
import time

from controllers.api import robust_planner
from controllers.planner import default_duration, planner_for
from controllers.stroke_problem import objective_weights
from controllers.stroke_solver import GAP, LATE_STARTS
from toggle_cli import plan_setup

ERRORS = (["--delta-r8", "0.25mm"], ["--delta-r8=-0.25mm"], ["--delta-r8", "0.1mm"],
          ["--delta-r3", "0.3mm"], ["--delta-r6=-0.3mm"],
          ["--delta-r8", "0.25mm", "--delta-r3", "0.2mm", "--delta-r6=-0.2mm"])
PRESETS = ("chang2021", "lin2003_sm55")
STRETCHES = (0.8, 1.0, 1.3)


def _args(preset: str, errors: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    plan_setup.add_plan_arguments(parser)
    return parser.parse_args(["--preset", preset, "--robust", *errors])


def main() -> None:
    weights = objective_weights("peak")
    print(f"{'preset':13} {'errors':38} {'T (s)':>6} {'poly (N)':>10} {'late (N)':>10} "
          f"{'gain %':>7} {'poly s':>7} {'late s':>7}")
    gains, times = [], [0.0, 0.0]
    for preset in PRESETS:
        for errors in ERRORS:
            args = _args(preset, errors)
            cfg, limits = plan_setup.plant_and_limits(args, errors=False)
            zone = plan_setup.protection_zone(args)
            nominal = planner_for(cfg, limits, args.contact_speed, args.intervals,
                                  protection=zone)
            for stretch in STRETCHES:
                duration = default_duration(nominal) * stretch
                try:
                    planner = robust_planner(cfg, limits,
                                             plan_setup.dimensional_errors(args), duration,
                                             args.contact_speed, args.intervals, zone)[0]
                except ValueError as exc:  # an erroneous clamp that has no toggle
                    print(f"{preset:13} {' '.join(errors):38} {duration:6.3f} {exc}")
                    continue
                peaks, spent = [], [0.0, 0.0]
                for late in (None, *LATE_STARTS):
                    tic = time.perf_counter()
                    guess = None if late is None else planner._late_guess(duration, late)
                    plan, ok = planner._run(weights, (duration, duration),
                                            planner.force_limit, "peak", None, False, guess)
                    spent[late is not None] += time.perf_counter() - tic
                    peaks.append(planner.worst_peak(plan) if ok else float("inf"))
                gain = (peaks[0] / min(peaks) - 1) * 100
                gains.append(gain)
                times = [t + s for t, s in zip(times, spent)]
                print(f"{preset:13} {' '.join(errors):38} {duration:6.3f} {peaks[0]:10.5g} "
                      f"{min(peaks[1:]):10.5g} {gain:7.3f} {spent[0]:7.2f} {spent[1]:7.2f}",
                      flush=True)
    print(f"{len(gains)} cases: the late starts gained at most {max(gains):.3f} % "
          f"(GAP {GAP * 100:g} %), in {times[1]:.1f} s of solving against the polynomial "
          f"start's {times[0]:.1f} s")


if __name__ == "__main__":
    main()
