"""Benchmark: how many times faster than real time the simulated rig runs seed 000's experiment.

100 forward-backward cycles at 25 mm/s between x_open and x_toggle (1 ms samples) on the
FMU back-end, recorded to a run directory as ``hil run`` does. Prints the median over
several runs of the wall time, samples per second and the real-time factor.
Run: python benchmarks/bench_hil.py [--cycles 100] [--runs 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from hil.host.backends import FmuPlant, RigSetup, ensure_fmu
from hil.host.experiment import reciprocating_trajectory
from hil.host.recording import RunMeta, RunRecorder
from toggle.params import load_preset


def one_run(cycles: int, speed: float, out: Path) -> tuple[float, int, float]:
    mech = load_preset("chang2021")
    setup = RigSetup(delta_r8=0.5e-3)
    traj = reciprocating_trajectory(mech, speed, cycles, setup.period)
    meta = RunMeta.for_experiment(mech, backend="fmu", cycles=cycles, delta_r8=setup.delta_r8,
                                  period=setup.period, speed=speed)
    plant = FmuPlant()
    plant.configure(setup)
    start = time.perf_counter()
    with RunRecorder(meta, out, plot=False) as rec, plant:
        for sample in plant.run(traj):
            rec.append(sample)
    return time.perf_counter() - start, rec.count, traj.duration


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=100)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--speed", type=float, default=25e-3)
    args = parser.parse_args()
    ensure_fmu()
    walls, count, simulated = [], 0, 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            wall, count, simulated = one_run(args.cycles, args.speed, Path(tmp) / f"run{i}")
            walls.append(wall)
    wall = statistics.median(walls)
    print(f"{args.cycles} cycles at {args.speed * 1e3:g} mm/s: {simulated:.1f} s simulated, "
          f"{count} samples")
    print(f"wall time (median of {args.runs}): {wall:.2f} s  "
          f"({count / wall / 1e3:.1f} k samples/s, {simulated / wall:.1f}x faster than real time)")


if __name__ == "__main__":
    main()
