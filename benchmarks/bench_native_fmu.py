"""Cost of a co-simulation step of ToggleClampNative.fmu (generated C) in fmpy and libcosim.

Prints the microseconds per set-inputs + doStep + get-outputs in fmpy of the
trivial pythonfmu FMU (tests/fmu_fixtures/trivial_slave.py), the pythonfmu
ToggleClamp and the native ToggleClampNative (all 12 outputs read, the stroke,
mold contact and link-8 error of bench_fmu.py; ideal and 20 Hz drive), each
the median of interleaved runs in this process, with ratios to the trivial
FMU (issue 16's target: native at or below it); then the steps per second
of the native FMU in libcosim (libcosimpy, fixed 1 ms step, one and two
instances, median of runs in a fresh process), and the cost of a step called
from C (a loop compiled here, no fmpy). libcosim steps its instances on worker
threads: on this 2-core VM its rate is bound by their wake-up latency, not by
the FMU (one and two instances run at the same rate, about 17 000 steps/s on
an idle machine), so it is also measured with the master on one CPU.

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


C_LOOP = textwrap.dedent(
    r"""
    #include <dlfcn.h>
    #include <stdio.h>
    #include <stdlib.h>
    #include <time.h>
    #include "fmi2Functions.h"
    #define LOAD(f) f##TYPE *f = (f##TYPE *)dlsym(lib, #f)
    int main(int argc, char **argv) {
        void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
        if (!lib || argc != 8) return 2;
        LOAD(fmi2Instantiate); LOAD(fmi2EnterInitializationMode); LOAD(fmi2SetReal);
        LOAD(fmi2ExitInitializationMode); LOAD(fmi2GetReal); LOAD(fmi2DoStep);
        LOAD(fmi2FreeInstance);
        fmi2CallbackFunctions cb = {NULL, calloc, free, NULL, NULL};
        fmi2ValueReference x_cmd = atoi(argv[3]), out0 = atoi(argv[4]), outs[12];
        fmi2ValueReference bw_vr = atoi(argv[6]), xc_vr = atoi(argv[7]);
        double x0 = -3.4386e-3, bw = atof(argv[5]), xc = 0.0505, y[12];
        long steps = 1000000;
        for (int i = 0; i < 12; i++) outs[i] = out0 + i;
        fmi2Component c = fmi2Instantiate("loop", fmi2CoSimulation, argv[2], "", &cb, 0, 0);
        fmi2EnterInitializationMode(c);
        fmi2SetReal(c, &x_cmd, 1, &x0);
        fmi2SetReal(c, &bw_vr, 1, &bw);
        fmi2SetReal(c, &xc_vr, 1, &xc);
        if (fmi2ExitInitializationMode(c) != fmi2OK) return 3;
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        for (long k = 0; k < steps; k++) {
            double s = (double)(k % 800) / 400.0;  /* into the mold and back out */
            double x = x0 + 0.0544 * (s > 1.0 ? 2.0 - s : s);
            fmi2SetReal(c, &x_cmd, 1, &x);
            if (fmi2DoStep(c, k * 1e-3, 1e-3, fmi2True) != fmi2OK) return 4;
            fmi2GetReal(c, outs, 12, y);
        }
        clock_gettime(CLOCK_MONOTONIC, &t1);
        printf("%.4f\n", ((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / steps / 1e3);
        fmi2FreeInstance(c);
        return 0;
    }
    """
)


def c_loop_us(unzip_dir: Path, work: Path, bandwidth: float) -> float:
    """µs per set-input + doStep + get 12 outputs called from C (no fmpy), one 1e6-step run."""
    from fmpy import read_model_description

    from toggle.native_fmu import MODEL, fmi2_headers

    source, exe = work / "loop.c", work / "loop"
    source.write_text(C_LOOP)
    subprocess.run(["gcc", "-O2", "-I", str(fmi2_headers()), str(source), "-o", str(exe),
                    "-ldl"], check=True)
    md = read_model_description(str(unzip_dir))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    lib = unzip_dir / "binaries" / "linux64" / f"{MODEL}.so"
    run = subprocess.run([str(exe), str(lib), md.guid, str(refs["x_cmd"]),
                          str(refs[PlantOutputs._fields[0]]), repr(bandwidth),
                          str(refs["drive_bandwidth"]), str(refs["x_contact"])],
                         capture_output=True, text=True,
                         check=True)
    return float(run.stdout)


def libcosim_rates(fmu: Path, steps: int, runs: int, start: dict[str, float],
                   pinned: bool) -> dict[str, float]:
    """Co-simulation steps per second (all instances stepped once per step) by instance count.

    ``pinned`` runs the master on one CPU (taskset -c 0): its worker threads then hand
    over on that core instead of waking an idle one.
    """
    pin = ["taskset", "-c", "0"] if pinned else []
    run = subprocess.run([*pin, sys.executable, "-c", LIBCOSIM_RATE, str(fmu), str(steps),
                          str(runs), json.dumps(start)], capture_output=True, text=True,
                         check=True)
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
        for _ in range(args.runs):
            for name, (kind, start_values, ins, outs) in cases.items():
                times[name].append(time_step(dirs[kind], ins, outs, STEP, args.steps, 1,
                                             start_values))
        rates = {pinned: libcosim_rates(native, args.cosim_steps, args.runs,
                                        {**start, "x_cmd": 0.0}, pinned)
                 for pinned in (False, True)}
        c_us = {bw: statistics.median(c_loop_us(dirs["native"], work, bw) for _ in range(3))
                for bw in (0.0, 20.0)}
    base = statistics.median(times["trivial pythonfmu"])
    print(f"us per set-inputs + doStep + get-outputs in fmpy "
          f"(median of {args.runs} runs x {args.steps} steps):")
    for name, values in times.items():
        us = statistics.median(values)
        print(f"  {name:24s} {us:8.2f} us   ratio to trivial {us / base:5.2f}")
    for bw, us in c_us.items():
        print(f"  native clamp from C, {'ideal' if bw == 0 else '20 Hz'}: {us:.3f} us "
              "(no fmpy; median of 3 runs x 1e6 steps)")
    for pinned, by_count in rates.items():
        for n, rate in by_count.items():
            print(f"libcosim{' on one CPU' if pinned else ''}, {n} native instance(s), 1 ms "
                  f"step: {rate:,.0f} steps/s (median of {args.runs} runs x {args.cosim_steps})")


if __name__ == "__main__":
    main()
