"""Benchmark: the tolerance Monte Carlo's kernel, compiled against numpy, on one core.

Both kernels evaluate the exact nonlinear output of both halves for the same sampled
dimensions (toggle.kinematics.output_position: numpy's ufunc chain, the baseline
measured in this run, and the C that CasADi generates from it, toggle.mc_kernel). A
"sample" is one draw of all 16 dimensions, i.e. both halves. Also shown: where the time
of a whole monte_carlo() call goes (numpy's random draws, the kernel, the statistics)
and its rate both ways. Medians of several runs of the process's CPU time (user and
system: on a shared machine the wall clock counts the other processes' turns too); the
process is pinned to CPU 0, so one core.
Run: python benchmarks/bench_monte_carlo.py
"""

from __future__ import annotations

import os

os.sched_setaffinity(0, {0})  # one core, before numpy starts any thread pool

import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from unittest import mock  # noqa: E402

import numpy as np  # noqa: E402
import timing  # noqa: E402

from toggle import load_preset, mc_kernel  # noqa: E402
from toggle.kinematics import output_position, toggle_position  # noqa: E402
from toggle.params import HALVES  # noqa: E402
from toggle.tolerance import Statistics, _draw, it_tolerances, monte_carlo  # noqa: E402

CHUNK = 65_536  # monte_carlo's default chunk
POOL = 8  # distinct chunks of draws the kernels evaluate in turn


def median_time(fn: Callable[[], object], runs: int) -> float:
    """CPU seconds of this process, the median after a warm-up call."""
    return timing.median_time(fn, runs, clock=time.process_time, warm_up=True)


def report(n: int, runs: int) -> None:
    """Print the rates for n samples."""
    mech = load_preset("chang2021")
    tol = it_tolerances(mech, 10)
    x = toggle_position(mech.lower)
    kernel = mc_kernel.load()
    if kernel is None:
        raise SystemExit("no C compiler: nothing to compare")
    nominal = {h: np.array(mech.half(h).as_tuple()) for h in HALVES}
    sizes = [min(CHUNK, n - s) for s in range(0, n, CHUNK)]
    rng = np.random.default_rng(0)  # a pool of chunks, used in turn (the memory stays small)
    pool = [{h: _draw(rng, tol[h], CHUNK, "normal") for h in HALVES} for _ in range(POOL)]

    def kernels(evaluate: Callable[[str, np.ndarray, np.ndarray], object]) -> None:
        for i, size in enumerate(sizes):
            for h in HALVES:
                scale, draws = pool[i % POOL][h]
                evaluate(h, scale, draws[:, :size])

    def numpy_kernel() -> None:
        kernels(lambda h, scale, draws: output_position(
            x, list(nominal[h][:, None] + scale[:, None] * draws)))

    def compiled_kernel() -> None:
        kernels(lambda h, scale, draws: kernel.outputs(x, nominal[h], scale, draws))

    def draws_only() -> None:
        rng = np.random.default_rng(0)
        for size in sizes:
            for h in HALVES:
                _draw(rng, tol[h], size, "normal")

    values = np.random.default_rng(1).standard_normal(n) * 1e-4
    t_numpy = median_time(numpy_kernel, runs)
    t_c = median_time(compiled_kernel, runs)
    t_draw = median_time(draws_only, runs)
    t_stats = 3 * median_time(lambda: Statistics.of(values), runs)
    t_mc = median_time(lambda: monte_carlo(mech, tol, x=x, samples=n), runs)
    with mock.patch("toggle.mc_kernel.load", return_value=None):  # today's numpy path
        t_mc_numpy = median_time(lambda: monte_carlo(mech, tol, x=x, samples=n), runs)
    print(f"\n{n:.0e} samples (both halves each), medians of {runs}:")
    print(f"  kernel, numpy (today):      {n / t_numpy / 1e6:8.2f} M samples/s")
    print(f"  kernel, compiled C:         {n / t_c / 1e6:8.2f} M samples/s "
          f"({t_numpy / t_c:.1f}x numpy; target >= 20)")
    print(f"  monte_carlo(), numpy:       {n / t_mc_numpy / 1e6:8.2f} M samples/s")
    print(f"  monte_carlo(), compiled:    {n / t_mc / 1e6:8.2f} M samples/s "
          f"({t_mc_numpy / t_mc:.2f}x)")
    print(f"  split of the compiled call: random draws (numpy) {t_draw / t_mc:5.1%}, "
          f"kernel {t_c / t_mc:5.1%}, statistics {t_stats / t_mc:5.1%}, "
          f"rest {1 - (t_draw + t_c + t_stats) / t_mc:5.1%}")


def main() -> None:
    print(f"one core (CPU 0), chang2021 at the toggle, IT10, normal; chunks of {CHUNK} samples")
    mech = load_preset("chang2021")
    with mock.patch("toggle.mc_kernel.load", return_value=None):
        # The process warmed as a search's is: after a first large call, glibc's allocator
        # serves numpy's temporaries from its heap, without page faults (2x faster).
        monte_carlo(mech, it_tolerances(mech, 10), samples=1_000_000)
    report(1_000_000, runs=5)
    report(10_000_000, runs=3)


if __name__ == "__main__":
    main()
