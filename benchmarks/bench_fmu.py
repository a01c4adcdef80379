"""Cost of one co-simulation step of ToggleClamp.fmu in fmpy, against a trivial pythonfmu FMU.

Prints the microseconds per set-inputs + doStep + get-outputs of
ToggleClamp.fmu (all 12 outputs read every step, mold contact and an error
in link 8 switched on, ideal drive and a 20 Hz drive) and of the trivial test
slave (tests/fmu_fixtures/trivial_slave.py), each the median of several runs,
and their ratio (issue 5's target: at most 2). The runs of the FMUs are
interleaved so that load from other processes hits them alike.

Run: python benchmarks/bench_fmu.py [--steps N] [--runs R] [--fmu build/ToggleClamp.fmu]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import numpy as np
from bench_fmu_trivial import TRIVIAL_SLAVE, time_step
from fmpy import extract

from fmu_src.build import build_fmu
from toggle.kinematics import stroke_limits
from toggle.plant import PlantOutputs, configure

STEP = 1e-3  # s


def clamp_case() -> tuple[dict[str, list[float]], dict[str, float]]:
    """x_cmd of a closing and opening stroke (0.2 s each way) and the parameters used."""
    x_open, x_toggle = stroke_limits(configure("chang2021").mechanism.lower)
    s = np.linspace(0.0, 1.0, 201)
    closing = x_open + (x_toggle - x_open) * s**3 * (10 - 15 * s + 6 * s**2)
    x_cmd = np.concatenate([closing, closing[::-1]]).tolist()
    return {"x_cmd": x_cmd}, {"x_contact": x_toggle - 1e-3, "delta_r8": 0.3e-3,
                              "x_cmd": x_open, "drive_bandwidth": 0.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="steps per run")
    parser.add_argument("--runs", type=int, default=7, help="runs per FMU (median taken)")
    parser.add_argument("--fmu", type=Path, help="ToggleClamp.fmu to time (default: build one)")
    args = parser.parse_args()
    inputs, start = clamp_case()
    lag = {**start, "drive_bandwidth": 20.0}
    varying = np.random.default_rng(1).uniform(0.5e-3, 1.5e-3, 97).tolist()  # a new h each step
    outputs = list(PlantOutputs._fields)
    cases = {  # name: (start values, inputs, outputs, step size or sizes)
        "trivial": ({}, {"u": [0.1, 0.2, 0.3]}, ["y", "x"], STEP),
        # the cost of moving 12 outputs through pythonfmu and fmpy, without a model
        "trivial, 12 reads": ({}, {"u": [0.1, 0.2, 0.3]}, ["y", "x"] * 6, STEP),
        "clamp, ideal drive": (start, inputs, outputs, STEP),
        "clamp, 20 Hz drive": (lag, inputs, outputs, STEP),
        "clamp, 20 Hz, varying h": (lag, inputs, outputs, varying),
    }
    with tempfile.TemporaryDirectory(prefix="bench_fmu_") as tmp:
        work = Path(tmp)
        clamp_fmu = args.fmu or build_fmu(work / "clamp")
        dirs = {"trivial": Path(extract(str(build_fmu(work / "trivial", TRIVIAL_SLAVE)),
                                        str(work / "trivial_x"))),
                "clamp": Path(extract(str(clamp_fmu), str(work / "clamp_x")))}
        times: dict[str, list[float]] = {name: [] for name in cases}
        for _ in range(args.runs):
            for name, (start_values, ins, outs, h) in cases.items():
                folder = dirs[name.split(",")[0]]
                times[name].append(time_step(folder, ins, outs, h, args.steps, 1,
                                             start_values))
    base = statistics.median(times["trivial"])
    print(f"us per set-inputs + doStep + get-outputs in fmpy "
          f"(median of {args.runs} runs x {args.steps} steps):")
    for name, values in times.items():
        us = statistics.median(values)
        print(f"  {name:20s} {us:8.1f} us   ratio to trivial {us / base:5.2f}")


if __name__ == "__main__":
    main()
