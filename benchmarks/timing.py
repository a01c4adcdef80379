"""The benchmarks' one timing helper: the median of repeated runs."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def median_time(fn: Callable[[], object], runs: int = 7, *,
                clock: Callable[[], float] = time.perf_counter, warm_up: bool = False) -> float:
    """Median seconds of ``runs`` calls of ``fn`` on ``clock`` (wall time by default;
    ``time.process_time`` for this process's CPU time), after one untimed call if
    ``warm_up``."""
    if warm_up:
        fn()
    times = []
    for _ in range(runs):
        t = clock()
        fn()
        times.append(clock() - t)
    return statistics.median(times)
