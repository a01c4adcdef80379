"""Benchmark: how long ``toggle --version`` and ``toggle --help`` take, against a bare
Python start measured in the same run (the floor every command pays).

Prints medians of several runs and the ratio against the baseline; the aim is
``toggle --version`` under 0.3 s. Run: python benchmarks/bench_startup.py
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from timing import median_time

TOGGLE = str(Path(sys.executable).with_name("toggle"))


def median_run(argv: list[str], runs: int = 9) -> float:
    """Median wall time of running ``argv`` to its end, s."""
    return median_time(lambda: subprocess.run(argv, stdout=subprocess.DEVNULL,
                                              stderr=subprocess.DEVNULL, check=True), runs)


def main() -> None:
    base = median_run([sys.executable, "-c", "pass"])
    version = median_run([TOGGLE, "--version"])
    helped = median_run([TOGGLE, "--help"], runs=3)
    print(f"load average {os.getloadavg()[0]:.1f}")
    print(f"python -c pass:   {base * 1e3:7.0f} ms (baseline)")
    print(f"toggle --version: {version * 1e3:7.0f} ms ({version / base:.1f}x baseline; aim 300 ms)")
    print(f"toggle --help:    {helped * 1e3:7.0f} ms ({helped / base:.1f}x baseline; "
          "loads every command)")


if __name__ == "__main__":
    main()
