"""Benchmark: ``toggle tolerance --samples 1e7`` end to end on one core, against the tree
before issue 45's whole-call work, with the statistics of the old and new generator.

A "sample" is one draw of all 16 dimensions, i.e. both halves; chang2021 at the toggle,
IT10, normal. Printed:

* the whole call, ``toggle tolerance --samples 1e7`` as a user runs it (a process of its
  own: Python's start, the imports, the analysis, the Monte Carlo, the printing), of this
  tree and of the baseline tree (``--baseline``, default the commit before the one-pass
  statistics, exported with ``git archive``), and ``--samples 0`` (start, imports and the
  analysis alone); the median of ``--runs`` runs after a warm-up run (the kernel compiled,
  the bytecode written), wall and CPU (user + system) time;
* in this process: a whole ``monte_carlo()`` call and the kernel with its draws alone;
* the first call on an empty compile cache (the kernel's compile), apart: median of 3;
* the statistics of the generator before issue 45 (numpy's ``default_rng`` drawing the
  16 normals, the same kernel, ``np.percentile``) beside this tree's (Philox4x32-10 drawn
  in the kernel, summarised in one pass), each difference in standard errors of that
  difference (two independent runs: sqrt(2) times one run's error);
* the baseline tree's statistics against this tree's, from both processes' ``--json``:
  the same generator, so the same numbers (the percentiles to the bit).

Everything runs on CPU 0 (this process is pinned as ``taskset -c 0`` pins, its children
inherit it) with one OpenMP/BLAS thread. On a shared machine the wall time counts the other
processes' turns on that core: the CPU time is the idle machine's wall time, and the
ratios within one run are the result. Run: python benchmarks/bench_monte_carlo.py [--runs 5]
"""

from __future__ import annotations

import os

os.sched_setaffinity(0, {0})  # one core, before numpy starts any thread pool
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import timing  # noqa: E402
from scipy import stats  # noqa: E402

from toggle import load_preset, mc_kernel, philox  # noqa: E402
from toggle.kinematics import output_position, toggle_position  # noqa: E402
from toggle.params import DIMENSIONS, HALVES  # noqa: E402
from toggle.tolerance import _scale, it_tolerances, monte_carlo  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
#: The tree before the one-pass statistics and the lazy imports (issue 45's whole call).
BASELINE = "2bdb1c3"
SAMPLES = 10_000_000
CHUNK = 65_536
PARTS = ("lower", "upper", "asymmetry")


def command_env() -> dict[str, str]:
    """The environment of a user's ``toggle``: bytecode written (as an installed package
    has it), nothing else changed."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def run_command(tree: Path | None, samples: int, runs: int, env: dict[str, str],
                json_out: bool = False) -> tuple[float, float, str]:
    """Median wall and CPU seconds of ``toggle tolerance --samples N`` (``python -m
    toggle_cli`` from ``tree``; None: this tree's installed ``toggle``) after a warm-up
    run, and the last run's stdout."""
    if tree is None:
        argv, cwd = [str(Path(sys.executable).with_name("toggle"))], None
    else:
        argv, cwd = [sys.executable, "-m", "toggle_cli"], tree
    argv += ["tolerance", "--samples", str(samples), *(["--json"] if json_out else [])]
    walls, cpus, out = [], [], ""
    for i in range(runs + 1):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        done = subprocess.run(argv, cwd=cwd, env=env, check=True, capture_output=True,
                              text=True)
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if i:  # the first is the warm-up
            walls.append(wall)
            cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
        out = done.stdout
    return statistics.median(walls), statistics.median(cpus), out


def baseline_tree(rev: str, into: Path) -> Path | None:
    """The baseline commit's files (git archive), or None without git history."""
    try:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return into


def old_generator(mech, tol, x: float, samples: int, seed: int = 0) -> dict[str, dict]:
    """monte_carlo() before issue 45: numpy's default_rng draws every chunk's 16 dimensions,
    the kernel evaluates them, np.percentile summarises."""
    kernel, rng = mc_kernel.load(), np.random.default_rng(seed)
    nominal = {h: float(output_position(x, mech.half(h))) for h in HALVES}
    out = {h: np.empty(samples) for h in HALVES}
    for start in range(0, samples, CHUNK):
        n = min(CHUNK, samples - start)
        for h in HALVES:
            draws = rng.standard_normal((len(DIMENSIONS), n))
            out[h][start:start + n] = kernel.outputs(x, np.array(mech.half(h).as_tuple()),
                                                     _scale(tol[h], "normal"), draws)[0]
    values = (out["lower"] - nominal["lower"], out["upper"] - nominal["upper"],
              out["upper"] - out["lower"])
    return {part: {"mean": float(v.mean()), "std": float(v.std(ddof=1)),
                   **dict(zip(("p0.135", "p99.865"), np.percentile(v, (0.135, 99.865))))}
            for part, v in zip(PARTS, values)}


def flat(mc: dict) -> dict[str, dict]:
    """A --json Monte Carlo (or asdict of a result): mean, std and the 3-sigma bounds."""
    return {part: {"mean": mc[part]["mean"], "std": mc[part]["std"],
                   "p0.135": mc[part]["percentiles"]["p0.135"],
                   "p99.865": mc[part]["percentiles"]["p99.865"]} for part in PARTS}


def side_by_side(new: dict[str, dict], old: dict[str, dict], n: int) -> None:
    """Both generators' statistics, their standard errors and difference in standard
    errors of that difference."""
    p = 0.00135
    q_error = math.sqrt(p * (1 - p) / n) / stats.norm.pdf(stats.norm.isf(p))
    print(f"\nstatistics at {n:.0e} samples, seed 0, um: the generator before issue 45 (numpy "
          "default_rng) and this tree's (Philox4x32-10 in the kernel)")
    print(f"  {'output':<10} {'':>9} {'mean':>10} {'sigma':>10} {'p0.135':>10} {'p99.865':>10}")
    for part in PARTS:
        sigma = old[part]["std"]
        errors = {"mean": sigma / math.sqrt(n), "std": sigma / math.sqrt(2 * n),
                  "p0.135": q_error * sigma, "p99.865": q_error * sigma}
        for name, row in (("old", old[part]), ("new", new[part])):
            print(f"  {part if name == 'old' else '':<10} {name:>9} " + " ".join(
                f"{row[k] * 1e6:10.4f}" for k in errors))
        print(f"  {'':<10} {'+- 1 s.e.':>9} " + " ".join(f"{e * 1e6:10.4f}"
                                                        for e in errors.values()))
        print(f"  {'':<10} {'z':>9} " + " ".join(
            f"{(new[part][k] - old[part][k]) / (math.sqrt(2) * e):10.2f}"
            for k, e in errors.items()))


def in_process(runs: int) -> tuple[float, float]:
    """CPU seconds of one monte_carlo() call and of the kernel with its draws alone."""
    mech = load_preset("chang2021")
    tol, x = it_tolerances(mech, 10), toggle_position(mech.lower)
    kernel, key, buffer = mc_kernel.load(), philox.key(0), np.empty(CHUNK)
    nominal, scale = np.array(mech.lower.as_tuple()), _scale(tol["lower"], "normal")

    def kernel_only() -> None:
        for start in range(0, 2 * SAMPLES, CHUNK):  # two halves per sample
            kernel.sampled(x, nominal, scale, key, start, 0, "normal", buffer)

    clock = time.process_time
    return (timing.median_time(lambda: monte_carlo(mech, tol, x=x, samples=SAMPLES), runs,
                               clock=clock, warm_up=True),
            timing.median_time(kernel_only, runs, clock=clock, warm_up=True))


def rate(seconds: float) -> str:
    return f"{SAMPLES / seconds / 1e6:6.2f} M samples/s"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--baseline", default=BASELINE, help="git revision of the old tree")
    args = parser.parse_args()
    if mc_kernel.load() is None:
        raise SystemExit("no C compiler: nothing to compare")
    env = command_env()
    print(f"one core (CPU 0, one thread), chang2021 at the toggle, IT10, normal, {SAMPLES:.0e} "
          f"samples; load average {os.getloadavg()[0]:.1f} at the start")
    with tempfile.TemporaryDirectory() as tmp:
        firsts = []
        for i in range(3):
            cold = dict(env, TOGGLE_CACHE_DIR=str(Path(tmp) / f"cache-{i}"))
            t = time.perf_counter()
            subprocess.run([str(Path(sys.executable).with_name("toggle")), "tolerance",
                            "--samples", str(SAMPLES)], env=cold, check=True,
                           capture_output=True)
            firsts.append(time.perf_counter() - t)
        first = statistics.median(firsts)
        wall, cpu, new_json = run_command(None, SAMPLES, args.runs, env, json_out=True)
        wall0, cpu0, _ = run_command(None, 0, args.runs, env)
        old = baseline_tree(args.baseline, Path(tmp))
        if old is not None:
            old_wall, old_cpu, old_json = run_command(old, SAMPLES, args.runs, env,
                                                      json_out=True)
    t_call, t_kernel = in_process(args.runs)
    print(f"\nmedians of {args.runs} runs after a warm-up (wall on CPU 0 / CPU user + sys):")
    print(f"  toggle tolerance --samples 1e7, this tree:  {wall:5.2f} s / {cpu:5.2f} s: "
          f"{rate(wall)} wall, {rate(cpu)} CPU (target >= 10 M/s)")
    if old is not None:
        print(f"  the same, baseline {args.baseline}:          {old_wall:5.2f} s / "
              f"{old_cpu:5.2f} s: {rate(old_wall)} wall, {rate(old_cpu)} CPU")
        print(f"  this tree against the baseline:             {old_wall / wall:5.2f}x wall, "
              f"{old_cpu / cpu:5.2f}x CPU")
    print(f"  --samples 0 (start, imports, analysis):     {wall0:5.2f} s / {cpu0:5.2f} s")
    print(f"  in process, monte_carlo() alone:            CPU {t_call:5.2f} s: {rate(t_call)}")
    print(f"  in process, the kernel with its draws:      CPU {t_kernel:5.2f} s: "
          f"{rate(t_kernel)} ({t_kernel / cpu:.0%} of the whole call's CPU)")
    print(f"  first call on an empty compile cache (the kernel compiled), median of 3: wall "
          f"{first:5.2f} s")
    new = flat(json.loads(new_json)["monte_carlo"])
    if old is not None:
        base = flat(json.loads(old_json)["monte_carlo"])
        worst = max(abs(new[p][k] - base[p][k]) / base[p]["std"] for p in PARTS for k in new[p])
        same = all(new[p][k] == base[p][k] for p in PARTS for k in ("p0.135", "p99.865"))
        print(f"\nthis tree against the baseline, same seed: 3-sigma bounds "
              f"{'equal to the bit' if same else 'DIFFERENT'}; largest difference of mean, "
              f"sigma, bounds {worst:.1e} sigma")
    mech = load_preset("chang2021")
    side_by_side(new, old_generator(mech, it_tolerances(mech, 10), toggle_position(mech.lower),
                                    SAMPLES), SAMPLES)
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
