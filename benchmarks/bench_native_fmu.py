"""Cost of a co-simulation step of ToggleClampNative.fmu (generated C) in fmpy and libcosim.

Prints the microseconds per set-inputs + doStep + get-outputs in fmpy of the
trivial pythonfmu FMU (tests/fmu_fixtures/trivial_slave.py), the pythonfmu
ToggleClamp and the native ToggleClampNative (all 12 outputs read, the stroke,
mold contact and link-8 error of bench_fmu.py; ideal and 20 Hz drive), each
the median of interleaved runs in this process, with ratios to the trivial
FMU (issue 16's target: native at or below it); then the steps per second
of the native FMU in libcosim (libcosimpy, fixed 1 ms step, one and two
instances, median of runs in a fresh process).

Run: python benchmarks/bench_native_fmu.py [--steps N] [--runs R] [--cosim-steps N]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

from bench_fmu import STEP, clamp_case
from bench_fmu_trivial import TRIVIAL_SLAVE, time_step
from fmpy import extract

from toggle.fmu_build import build_fmu
from toggle.fmu_host import release_native_runtime
from toggle.native_fmu import build_native_fmu
from toggle.plant import PlantOutputs

LIBCOSIM_RATE = textwrap.dedent(
    """
    import json, statistics, sys, time
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimSlave import CosimLocalSlave
    fmu, steps, runs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    start = json.loads(sys.argv[4])
    log_output_level(CosimLogLevel.WARNING)
    rates = {}
    for n in (1, 2):
        per_run = []
        for _ in range(runs):
            execution = CosimExecution.from_step_size(1_000_000)
            for i in range(n):
                s = execution.add_local_slave(CosimLocalSlave(fmu_path=fmu, instance_name=f"c{i}"))
                refs = {v.name.decode(): v.reference for v in execution.slave_variables(s)}
                for name, value in start.items():
                    execution.real_initial_value(s, refs[name], value)
            t0 = time.perf_counter()
            assert execution.simulate_until(steps * 1_000_000)
            per_run.append(steps / (time.perf_counter() - t0))
        rates[n] = statistics.median(per_run)
    print(json.dumps(rates))
    """
)


def libcosim_rates(fmu: Path, steps: int, runs: int, start: dict[str, float]) -> dict[str, float]:
    """Co-simulation steps per second (all instances stepped once per step) by instance count."""
    run = subprocess.run([sys.executable, "-c", LIBCOSIM_RATE, str(fmu), str(steps), str(runs),
                          json.dumps(start)], capture_output=True, text=True, check=True)
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="fmpy steps per run")
    parser.add_argument("--runs", type=int, default=7, help="runs per case (median taken)")
    parser.add_argument("--cosim-steps", type=int, default=200_000, help="libcosim steps per run")
    args = parser.parse_args()
    inputs, start = clamp_case()
    outputs = list(PlantOutputs._fields)
    lag = {**start, "drive_bandwidth": 20.0}
    cases = {  # name: (FMU, start values, inputs, outputs)
        "trivial pythonfmu": ("trivial", {}, {"u": [0.1, 0.2, 0.3]}, ["y", "x"]),
        "pythonfmu clamp, ideal": ("python", start, inputs, outputs),
        "pythonfmu clamp, 20 Hz": ("python", lag, inputs, outputs),
        "native clamp, ideal": ("native", start, inputs, outputs),
        "native clamp, 20 Hz": ("native", lag, inputs, outputs),
    }
    with tempfile.TemporaryDirectory(prefix="bench_native_") as tmp:
        work = Path(tmp)
        native = build_native_fmu(work / "native")
        fmus = {"trivial": build_fmu(work / "trivial", TRIVIAL_SLAVE),
                "python": build_fmu(work / "python"), "native": native}
        dirs = {k: Path(extract(str(f), str(work / f"{k}_x"))) for k, f in fmus.items()}
        times: dict[str, list[float]] = {name: [] for name in cases}
        try:
            for _ in range(args.runs):
                for name, (kind, start_values, ins, outs) in cases.items():
                    times[name].append(time_step(dirs[kind], ins, outs, STEP, args.steps, 1,
                                                 start_values))
        finally:
            for kind in ("trivial", "python"):
                release_native_runtime(dirs[kind])
        rates = libcosim_rates(native, args.cosim_steps, args.runs, {**start, "x_cmd": 0.0})
    base = statistics.median(times["trivial pythonfmu"])
    print(f"us per set-inputs + doStep + get-outputs in fmpy "
          f"(median of {args.runs} runs x {args.steps} steps):")
    for name, values in times.items():
        us = statistics.median(values)
        print(f"  {name:24s} {us:8.2f} us   ratio to trivial {us / base:5.2f}")
    for n, rate in rates.items():
        print(f"libcosim, {n} native instance(s), 1 ms step: {rate:,.0f} steps/s "
              f"(median of {args.runs} runs x {args.cosim_steps} steps)")


if __name__ == "__main__":
    main()
