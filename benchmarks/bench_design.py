"""Throughput of toggle design's evaluation: candidates per second in this process and on
a local Dask cluster of 1 and 2 worker processes (the same candidates, a fresh store each
run; the cluster's start and each worker's first import are outside the timing).

    .venv/bin/python benchmarks/bench_design.py [--candidates 240] [--repeats 3]

Prints the median rate of each and the ratios against the one-worker cluster measured in
the same run, and the scheduler's cost per task (an empty task's round trip).
"""

from __future__ import annotations

import argparse
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


def rate(workers: int, vectors: np.ndarray, repeats: int) -> tuple[float, float]:
    """Median candidates per second, and the median empty-task round trip (s)."""
    targets = load_targets(TARGETS)
    rates, trips = [], []
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(Path(tmp) / "warm", targets.digest())
        with Runner(targets, store, workers=workers) as runner:
            runner.evaluate(vectors[:4 * max(workers, 1)])  # every worker imports, builds
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
    return statistics.median(rates), statistics.median(trips) if trips else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--candidates", type=int, default=240)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    vectors = candidates(args.candidates)
    inline, _ = rate(0, vectors, args.repeats)
    one, trip1 = rate(1, vectors, args.repeats)
    two, trip2 = rate(2, vectors, args.repeats)
    print(f"{args.candidates} SM-55 candidates, median of {args.repeats}")
    print(f"  in this process      {inline:8.1f} candidates/s")
    print(f"  Dask, 1 worker       {one:8.1f} candidates/s  ({one / inline:.2f} x in-process)")
    print(f"  Dask, 2 workers      {two:8.1f} candidates/s  ({two / one:.2f} x one worker)")
    print(f"  scheduler round trip per task (200 empty tasks): {1e3 * trip1:.2f} ms "
          f"(1 worker), {1e3 * trip2:.2f} ms (2 workers)")


if __name__ == "__main__":
    main()
