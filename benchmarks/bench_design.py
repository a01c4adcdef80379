"""Throughput of toggle design's evaluation beside CPU hogs: candidates per second in this
process, on a local Dask cluster of 1 and 2 worker processes and on the default back-end
(what ``toggle design`` picks without --workers: design.runner.default_workers).

It starts its own hogs (``python -c "while True: pass"``, ``--hogs``, default 1; 0 for
none) and lets the load settle, then opens the four back-ends at once (the clusters'
start and each worker's first imports outside the timing) and times them in turn, round
after round, on the same candidates with a fresh record each time, so a change of the
machine's load falls on all of them alike. It kills its hogs (by their process ids) at the
end.

    .venv/bin/python benchmarks/bench_design.py [--candidates 96] [--repeats 3] [--hogs 1]
        [--duty]

With ``--duty`` each round also plans the duty of the candidates' Pareto front on the same
back-end, as ``toggle design`` does after its search (design.search.run_search: about
1.6 s of CPU a design), and the rate is the candidates over both.

Prints the median rate of each, its CPU time per candidate (this process and the
back-end's workers: what it costs whoever shares the cores), the ratios against the faster
of the process and the 2-worker cluster measured in the same run, the load average and
what the default rule saw.
The machine may be shared: the absolute rates are noisy, the ratios within one run are the
result.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

import numpy as np

from design import runner as runner_module
from design.runner import Runner, busy_cores, default_workers
from design.search import full_vectors, pareto_front
from design.store import Store
from design.targets import load_targets

TARGETS = Path(__file__).resolve().parents[1] / "design" / "examples" / "sm55.toml"
#: The back-ends timed: name and --workers (None: the default back-end's choice).
BACKENDS = (("in this process", 0), ("Dask, 1 worker", 1), ("Dask, 2 workers", 2),
            ("default", None))
#: With --dask-defaults also: two workers with Dask's own worker settings (the statistical
#: profiler, MALLOC_TRIM_THRESHOLD_), which design.runner.WORKER_CONFIG turns off.
DASK_DEFAULTS = ("2 workers, Dask's defaults", 2)


def candidates(n: int) -> np.ndarray:
    from scipy.stats import qmc
    targets = load_targets(TARGETS)
    lo = np.array([targets.bounds[v][0] for v in targets.free])
    hi = np.array([targets.bounds[v][1] for v in targets.free])
    return full_vectors(targets, lo + qmc.LatinHypercube(d=lo.size, seed=1).random(n)
                        * (hi - lo))


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def cpu_seconds(runner: Runner) -> float:
    """CPU seconds so far of this process (the client, the local clusters' schedulers) and
    of the runner's workers: what a back-end costs, whoever else shares the cores."""
    workers = runner.client.run(_cpu_seconds).values() if runner.client is not None else ()
    return _cpu_seconds() + sum(workers)


def rates(vectors: np.ndarray, repeats: int, search: int, folder: Path, duty: bool,
          backends: tuple[tuple[str, int | None], ...] = BACKENDS
          ) -> tuple[dict[str, list[float]], dict[str, list[float]], dict[str, float], int,
                     int]:
    """Candidates per second of each back-end, round by round (with ``duty``: the front's
    duty planned too), and its CPU milliseconds per candidate (:func:`cpu_seconds`); the
    seconds each took to start (the cluster, the workers' imports and first evaluations,
    less the time of those evaluations at the back-end's rate); the default's workers; the
    front's size."""
    targets = load_targets(TARGETS)
    out: dict[str, list[float]] = {name: [] for name, _ in backends}
    cpu: dict[str, list[float]] = {name: [] for name, _ in backends}
    starts, warm, front = {}, {}, 0
    with contextlib.ExitStack() as stack:
        runners = {}
        for name, workers in backends:
            store = Store(folder / f"warm-{name}", targets.digest())
            t0 = time.perf_counter()
            settings = {} if name == DASK_DEFAULTS[0] else runner_module.WORKER_CONFIG
            with mock.patch.object(runner_module, "WORKER_CONFIG", settings):
                runner = stack.enter_context(Runner(targets, store, workers=workers,
                                                    total=search))
            warm[name] = 4 * max(runner.workers or 0, 1)
            runner.evaluate(vectors[:warm[name]])  # imports, builds
            starts[name] = time.perf_counter() - t0
            runners[name] = runner
        for r in range(repeats):
            for name, runner in runners.items():
                runner.store = Store(folder / f"{r}-{name}", targets.digest())
                c0, t0 = cpu_seconds(runner), time.perf_counter()
                evaluations = runner.evaluate(vectors)
                if duty:
                    planned = pareto_front(evaluations, targets.objectives)
                    runner.with_duty(planned)
                    front = len(planned)
                out[name].append(len(vectors) / (time.perf_counter() - t0))
                cpu[name].append(1e3 * (cpu_seconds(runner) - c0) / len(vectors))
        for name in starts:
            starts[name] = max(0.0, starts[name] - warm[name] / statistics.median(out[name]))
        return out, cpu, starts, runners["default"].workers, front


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--candidates", type=int, default=96)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--hogs", type=int, default=1, help="CPU hogs to start (default 1)")
    parser.add_argument("--settle", type=float, default=60.0,
                        help="seconds to let the load average see the hogs (default 60)")
    parser.add_argument("--search", type=int, default=2400,
                        help="the search size the default back-end is chosen for (default "
                             "2400, the documented SM-55 search)")
    parser.add_argument("--duty", action="store_true",
                        help="plan the front's duty each round too, as toggle design does")
    parser.add_argument("--dask-defaults", action="store_true",
                        help="time two workers with Dask's own worker settings too")
    args = parser.parse_args()
    backends = BACKENDS + ((DASK_DEFAULTS,) if args.dask_defaults else ())
    vectors = candidates(args.candidates)
    before = os.getloadavg()[0]
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
            for _ in range(args.hogs)]
    try:
        time.sleep(args.settle if hogs else 0.0)
        seen = (os.getloadavg()[0], busy_cores(), default_workers(args.search))
        with tempfile.TemporaryDirectory() as tmp:
            got, cpu, starts, chosen, front = rates(vectors, args.repeats, args.search, Path(tmp),
                                               args.duty, backends)
        after = os.getloadavg()[0]
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
    med = {name: statistics.median(v) for name, v in got.items()}
    faster = max(med["in this process"], med["Dask, 2 workers"])
    print(f"{args.candidates} SM-55 candidates, median of {args.repeats} interleaved rounds, "
          f"{args.hogs} CPU hog(s) of ours on {os.cpu_count()} cores; load average "
          f"{before:.1f} before the hogs, {seen[0]:.1f} when the back-ends opened, {after:.1f} "
          f"at the end" + (f"; the front's duty planned each round ({front} designs)"
                           if args.duty else ""))
    print(f"  the default rule saw {seen[1]:.1f} cores busy and chose "
          f"{chosen or 'the process'}{' workers' if chosen else ''} for a {args.search}-"
          f"candidate search")
    for name, _ in backends:
        rounds = ", ".join(f"{v:.1f}" for v in got[name])
        print(f"  {name:<26} {med[name]:7.1f} candidates/s  ({med[name] / faster:.2f} x the "
              f"faster of the process and 2 workers; rounds {rounds})")
    print("  CPU per candidate (this process, its schedulers and the back-end's workers), ms: "
          + ", ".join(f"{name} {statistics.median(cpu[name]):.1f}" for name, _ in backends))
    pair = [b / a for a, b in zip(got["in this process"], got["Dask, 2 workers"])]
    print(f"  2 workers over the process, round by round: "
          f"{', '.join(f'{r:.2f}' for r in pair)} (median {statistics.median(pair):.2f})")
    whole = {name: starts[name] + args.search / med[name] for name in med}
    best = min(whole["in this process"], whole["Dask, 2 workers"])
    print(f"  a {args.search}-candidate search, start included (s): " + ", ".join(
        f"{name} {whole[name]:.0f} (start {starts[name]:.1f}; {best / whole[name]:.2f} x "
        f"the faster)" for name in med))


if __name__ == "__main__":
    main()
