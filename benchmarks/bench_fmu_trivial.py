"""Cost of one co-simulation step of a pythonfmu FMU in fmpy (trivial baseline).

Prints the median over several runs of the microseconds per
set-inputs + doStep + get-outputs of the trivial test slave
(tests/fmu_fixtures/trivial_slave.py). ``time_step`` is the reusable part:
the ToggleClamp benchmark calls it on build/ToggleClamp.fmu and compares.

Run: python benchmarks/bench_fmu_trivial.py [--steps N] [--runs R]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from fmpy import extract

from fmu_src.build import build_fmu
from fmu_src.host import start_slave

REPO = Path(__file__).resolve().parents[1]
TRIVIAL_SLAVE = REPO / "tests" / "fmu_fixtures" / "trivial_slave.py"


def time_step(
    unzip_dir: Path,
    inputs: Mapping[str, Sequence[float]],
    outputs: Sequence[str],
    step_size: float | Sequence[float],
    steps: int,
    runs: int,
    start_values: Mapping[str, float | str] | None = None,
) -> float:
    """Median over ``runs`` fresh instances of µs per set-inputs + doStep + get-outputs.

    ``inputs`` maps each input name to a sequence of values, cycled step by step;
    a sequence of step sizes is cycled too.
    """
    sizes = [step_size] if isinstance(step_size, float) else list(step_size)
    per_run = []
    for run in range(runs):
        slave, refs = start_slave(unzip_dir, f"bench{run}", start_values)
        in_refs = [refs[name] for name in inputs]
        out_refs = [refs[name] for name in outputs]
        series = list(zip(*inputs.values(), strict=True))
        t = 0.0
        start = time.perf_counter()
        for k in range(steps):
            slave.setReal(in_refs, series[k % len(series)])
            h = sizes[k % len(sizes)]
            slave.doStep(t, h)
            slave.getReal(out_refs)
            t += h
        per_run.append((time.perf_counter() - start) / steps * 1e6)
        slave.terminate()
        slave.freeInstance()
    return statistics.median(per_run)


def trivial_baseline(work_dir: Path, steps: int, runs: int) -> float:
    """µs per step of the trivial FMU, built and extracted under ``work_dir``."""
    fmu = build_fmu(work_dir, TRIVIAL_SLAVE)
    unzip_dir = Path(extract(str(fmu), str(work_dir / "trivial")))
    return time_step(unzip_dir, {"u": [0.1, 0.2, 0.3]}, ["y", "x"], 1e-3, steps, runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="steps per run")
    parser.add_argument("--runs", type=int, default=5, help="runs (median taken)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_fmu_") as tmp:
        us = trivial_baseline(Path(tmp), args.steps, args.runs)
    print(
        f"trivial pythonfmu FMU: {us:.1f} us per set-inputs + doStep + get-outputs "
        f"(median of {args.runs} runs x {args.steps} steps)"
    )


if __name__ == "__main__":
    main()
