"""Benchmark: the tolerance Monte Carlo end to end on one core, the generator it had (numpy's
default_rng, the draws handed to the compiled kernel, np.percentile) against the one it
has (toggle.philox's Philox4x32-10 drawn inside the kernel, toggle.tolerance.percentiles).

A "sample" is one draw of all 16 dimensions, i.e. both halves. Printed for 1e6 and 1e7
samples (chang2021 at the toggle, IT10, normal): samples per second of a whole
monte_carlo() call both ways (the issue's "whole call"), of the kernel alone with its
draws, of the numpy fallback (no C compiler), and where the new call's time goes; then the
statistics of both generators side by side with their difference in standard errors of
that difference (two independent runs: sqrt(2) times one run's error); then the
``toggle tolerance --samples 1e7`` process itself (Python's start and imports included)
against ``--samples 0``. Medians of several runs of the CPU time (user and system: on a
shared machine the wall clock counts the other processes' turns); the process is pinned to
CPU 0 and its thread pools to one thread (OMP, OpenBLAS), so one core.
Run: python benchmarks/bench_monte_carlo.py [--runs 3]
"""

from __future__ import annotations

import os

os.sched_setaffinity(0, {0})  # one core, before numpy starts any thread pool
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"

import argparse  # noqa: E402
import math  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from unittest import mock  # noqa: E402

import numpy as np  # noqa: E402
import timing  # noqa: E402
from scipy import stats  # noqa: E402

from toggle import load_preset, mc_kernel, philox  # noqa: E402
from toggle.kinematics import output_position, toggle_position  # noqa: E402
from toggle.params import DIMENSIONS, HALVES  # noqa: E402
from toggle.tolerance import MonteCarloResult, _scale, it_tolerances, monte_carlo  # noqa: E402

CHUNK = 65_536  # monte_carlo's default chunk
TOGGLE = Path(sys.executable).with_name("toggle")


def median_time(fn: Callable[[], object], runs: int) -> float:
    """CPU seconds of this process, the median after a warm-up call."""
    return timing.median_time(fn, runs, clock=time.process_time, warm_up=True)


def old_statistics(values: np.ndarray) -> dict[str, float]:
    """toggle.tolerance.Statistics as it was (np.percentile on a copy)."""
    qs = (0.135, 2.5, 50.0, 97.5, 99.865)
    pct = np.percentile(values, qs)
    return {"mean": float(values.mean()), "std": float(values.std(ddof=1)),
            **{f"p{q:g}": float(v) for q, v in zip(qs, pct)}}


def old_monte_carlo(mech, tol, x: float, samples: int, seed: int = 0) -> dict[str, dict]:
    """monte_carlo() as it was: numpy's default_rng draws every chunk's 16 dimensions, the
    kernel evaluates them, np.percentile summarises."""
    kernel, rng = mc_kernel.load(), np.random.default_rng(seed)
    nominal = {h: float(output_position(x, mech.half(h))) for h in HALVES}
    out = {h: np.empty(samples) for h in HALVES}
    for start in range(0, samples, CHUNK):
        n = min(CHUNK, samples - start)
        for h in HALVES:
            draws = rng.standard_normal((len(DIMENSIONS), n))
            out[h][start:start + n] = kernel.outputs(x, np.array(mech.half(h).as_tuple()),
                                                     _scale(tol[h], "normal"), draws)[0]
    return {"lower": old_statistics(out["lower"] - nominal["lower"]),
            "upper": old_statistics(out["upper"] - nominal["upper"]),
            "asymmetry": old_statistics(out["upper"] - out["lower"])}


def flat(result: MonteCarloResult) -> dict[str, dict]:
    return {part: {"mean": s.mean, "std": s.std, **s.percentiles}
            for part in ("lower", "upper", "asymmetry")
            for s in [getattr(result, part)]}


def side_by_side(new: dict[str, dict], old: dict[str, dict], n: int) -> None:
    """The statistics of both generators and their difference in standard errors."""
    p = 0.00135
    q_error = math.sqrt(p * (1 - p) / n) / stats.norm.pdf(stats.norm.isf(p))
    print(f"  statistics at {n:.0e} samples, um (difference / its standard error):")
    print(f"    {'output':<10} {'':>5} {'mean':>10} {'sigma':>10} {'p0.135':>10} {'p99.865':>10}")
    for part in ("lower", "upper", "asymmetry"):
        sigma = old[part]["std"]
        errors = {"mean": sigma / math.sqrt(n), "std": sigma / math.sqrt(2 * n),
                  "p0.135": q_error * sigma, "p99.865": q_error * sigma}
        for name, row in (("old", old[part]), ("new", new[part])):
            print(f"    {part if name == 'old' else '':<10} {name:>5} " + " ".join(
                f"{row[k] * 1e6:10.4f}" for k in errors))
        print(f"    {'':<10} {'z':>5} " + " ".join(
            f"{(new[part][k] - old[part][k]) / (math.sqrt(2) * e):10.2f}"
            for k, e in errors.items()))


def report(n: int, runs: int) -> None:
    mech = load_preset("chang2021")
    tol = it_tolerances(mech, 10)
    x = toggle_position(mech.lower)
    kernel = mc_kernel.load()
    key = philox.key(0)
    buffer = np.empty(CHUNK)
    nominal = np.array(mech.lower.as_tuple())
    scale = _scale(tol["lower"], "normal")

    def kernel_only() -> None:
        for start in range(0, 2 * n, CHUNK):  # two halves per sample
            kernel.sampled(x, nominal, scale, key, start, 0, "normal", buffer)

    t_new = median_time(lambda: monte_carlo(mech, tol, x=x, samples=n), runs)
    t_old = median_time(lambda: old_monte_carlo(mech, tol, x, n), runs)
    t_kernel = median_time(kernel_only, runs)
    print(f"\n{n:.0e} samples (both halves each), medians of {runs}, CPU time:")
    print(f"  monte_carlo(), old (numpy draws):  {n / t_old / 1e6:8.2f} M samples/s")
    print(f"  monte_carlo(), new (Philox in C):  {n / t_new / 1e6:8.2f} M samples/s "
          f"({t_old / t_new:.2f}x old; target >= 10)")
    print(f"  kernel with its draws alone:       {n / t_kernel / 1e6:8.2f} M samples/s "
          f"({t_kernel / t_new:5.1%} of the new call; the rest: statistics, arrays)")
    if n <= 1_000_000:
        with mock.patch("toggle.mc_kernel.load", return_value=None):
            t_numpy = median_time(lambda: monte_carlo(mech, tol, x=x, samples=n), runs)
        print(f"  monte_carlo(), numpy fallback:     {n / t_numpy / 1e6:8.2f} M samples/s")
    side_by_side(flat(monte_carlo(mech, tol, x=x, samples=n)), old_monte_carlo(mech, tol, x, n),
                 n)


def command(samples: int, runs: int) -> tuple[float, float]:
    """Median CPU and wall seconds of ``toggle tolerance --samples N --json`` (a process of
    its own, pinned with this one)."""
    cpu, wall = [], []
    for _ in range(runs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run([str(TOGGLE), "tolerance", "--samples", str(samples), "--json"],
                       check=True, stdout=subprocess.DEVNULL)
        wall.append(time.perf_counter() - t)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return float(np.median(cpu)), float(np.median(wall))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    if mc_kernel.load() is None:
        raise SystemExit("no C compiler: nothing to compare")
    print(f"one core (CPU 0, one thread), chang2021 at the toggle, IT10, normal; chunks of "
          f"{CHUNK} samples; load average {os.getloadavg()[0]:.1f} at the start")
    report(1_000_000, args.runs)
    report(10_000_000, args.runs)
    cpu0, wall0 = command(0, args.runs)
    cpu, wall = command(10_000_000, args.runs)
    print(f"\n`toggle tolerance --samples 1e7 --json`, medians of {args.runs}: CPU {cpu:.2f} s, "
          f"wall {wall:.2f} s; with --samples 0 (start, imports, the analysis): CPU "
          f"{cpu0:.2f} s, wall {wall0:.2f} s")
    print(f"  the whole process: {1e7 / cpu / 1e6:.2f} M samples/s of CPU; its Monte Carlo "
          f"(less --samples 0): {1e7 / (cpu - cpu0) / 1e6:.2f} M samples/s")
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
