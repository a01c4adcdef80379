"""Benchmark: kinematics evaluations and exact Monte Carlo samples per second (one core).

Prints medians of several runs and the ratio against a baseline measured in the same
run (numpy evaluating one sqrt over the same array: the cost floor of any ufunc chain).
Run: python benchmarks/bench_kinematics.py
"""

from __future__ import annotations

import numpy as np
from timing import median_time

from toggle import load_preset
from toggle.kinematics import half_motion, half_pose, output_position
from toggle.tolerance import it_tolerances, monte_carlo


def main() -> None:
    mech = load_preset("chang2021")
    n = 1_000_000
    xs = np.linspace(-3e-3, 51e-3, n)
    positive = xs + 1.0
    base = median_time(lambda: np.sqrt(positive))
    pose = median_time(lambda: half_pose(xs, mech.lower))
    out = median_time(lambda: output_position(xs, mech.lower))
    motion = median_time(lambda: half_motion(xs[:100_000], mech.lower), runs=5) * 10
    scalar = median_time(lambda: [half_pose(0.02, mech.lower) for _ in range(1000)]) / 1000
    tol = it_tolerances(mech, 10)
    mc_n = 2_000_000
    mc = median_time(lambda: monte_carlo(mech, tol, samples=mc_n), runs=5)
    print(f"baseline numpy sqrt:           {n / base / 1e6:8.1f} M evaluations/s")
    print(f"half_pose (all angles), vector: {n / pose / 1e6:8.2f} M evaluations/s "
          f"({pose / base:.0f}x baseline)")
    print(f"output_position L(x), vector:  {n / out / 1e6:8.2f} M evaluations/s "
          f"({out / base:.0f}x baseline)")
    print(f"half_motion (AD derivatives):   {n / motion / 1e6:8.2f} M evaluations/s")
    print(f"half_pose, scalar float:        {scalar * 1e6:8.1f} us per call")
    print(f"Monte Carlo (16 dims, exact):  {mc_n / mc / 1e6:8.2f} M samples/s (target >= 2)")


if __name__ == "__main__":
    main()
