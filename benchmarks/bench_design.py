"""Throughput of toggle design's evaluation: candidates per second in this process, on
a local Dask cluster of 1 and 2 worker processes and on the default back-end (what
``toggle design`` picks without --workers, from the free cores: design.runner.default_workers)
(the same candidates, a fresh store each run; the cluster's start and each worker's first
import are outside the timing). Run it with a CPU hog (``python3 -c 'while 1: pass' &``) to
see the default against the faster of the process and the cluster.

    .venv/bin/python benchmarks/bench_design.py [--candidates 240] [--repeats 3]

Prints the median rate of each and the ratios against the one-worker cluster measured in
the same run, and the scheduler's cost per task (an empty task's round trip).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from design.runner import Runner
from design.search import full_vectors
from design.store import Store
from design.targets import load_targets

TARGETS = Path(__file__).resolve().parents[1] / "design" / "examples" / "sm55.toml"


def candidates(n: int) -> np.ndarray:
    from scipy.stats import qmc
    targets = load_targets(TARGETS)
    lo = np.array([targets.bounds[v][0] for v in targets.free])
    hi = np.array([targets.bounds[v][1] for v in targets.free])
    return full_vectors(targets, lo + qmc.LatinHypercube(d=lo.size, seed=1).random(n)
                        * (hi - lo))


def rate(workers: int | None, vectors: np.ndarray, repeats: int
         ) -> tuple[float, float, int]:
    """Median candidates per second, the median empty-task round trip (s), and the local
    workers used (None: the default back-end's choice)."""
    targets = load_targets(TARGETS)
    rates, trips = [], []
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(Path(tmp) / "warm", targets.digest())
        with Runner(targets, store, workers=workers, total=len(vectors)) as runner:
            runner.evaluate(vectors[:4 * max(runner.workers or 0, 1)])  # imports, builds
            for r in range(repeats):
                fresh = Store(Path(tmp) / str(r), targets.digest())
                runner.store = fresh
                t0 = time.perf_counter()
                runner.evaluate(vectors)
                rates.append(len(vectors) / (time.perf_counter() - t0))
                if runner.client is not None:
                    t0 = time.perf_counter()
                    runner.client.gather(runner.client.map(abs, range(200), pure=False))
                    trips.append((time.perf_counter() - t0) / 200)
    return (statistics.median(rates), statistics.median(trips) if trips else 0.0,
            runner.workers)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--candidates", type=int, default=240)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    vectors = candidates(args.candidates)
    inline, _, _ = rate(0, vectors, args.repeats)
    one, trip1, _ = rate(1, vectors, args.repeats)
    two, trip2, _ = rate(2, vectors, args.repeats)
    default, _, chosen = rate(None, vectors, args.repeats)
    print(f"{args.candidates} SM-55 candidates, median of {args.repeats}")
    print(f"  in this process      {inline:8.1f} candidates/s")
    print(f"  Dask, 1 worker       {one:8.1f} candidates/s  ({one / inline:.2f} x in-process)")
    print(f"  Dask, 2 workers      {two:8.1f} candidates/s  ({two / one:.2f} x one worker)")
    print(f"  default ({chosen or 'in-process'}{' workers' if chosen else ''})"
          f"{default:10.1f} candidates/s  ({default / max(inline, two):.2f} x the faster of "
          f"the process and 2 workers; load average {os.getloadavg()[0]:.1f})")
    print(f"  scheduler round trip per task (200 empty tasks): {1e3 * trip1:.2f} ms "
          f"(1 worker), {1e3 * trip2:.2f} ms (2 workers)")


if __name__ == "__main__":
    main()
