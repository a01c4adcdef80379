"""Cost of a co-simulation step of ToggleClampNative.fmu (generated C) in fmpy and libcosim.

Prints the microseconds per set-inputs + doStep + get-outputs in fmpy of two baselines,
a plain pythonfmu trivial FMU (benchmarks/trivial_plain_slave.py: pythonfmu alone, no
FMI guard, no toggle code) and a trivial C FMU (benchmarks/trivial_c_fmu.c), and of the
guarded trivial FMU (tests/fmu_fixtures/trivial_slave.py, built like ToggleClamp.fmu), the
pythonfmu ToggleClamp and the native ToggleClampNative (all 12 outputs read, the stroke,
mold contact at x_toggle - 1 mm and delta_r8 = 0.3 mm of bench_fmu.py; ideal and 20 Hz
drive), each the median of interleaved runs in this process, with ratios to both
baselines; then the steps per second of the native FMU in libcosim (libcosimpy, fixed
1 ms step, one and two instances, median of runs in a fresh process), and the cost of a
step called from C (a loop compiled here, no fmpy; the same mold and delta_r8) against
the trivial C FMU called the same way. libcosim steps its instances on worker
threads: on this 2-core VM its rate is bound by their wake-up latency, not by
the FMU (one and two instances run at the same rate, about 17 000 steps/s on
an idle machine), so it is also measured with the master on one CPU.

Run: python benchmarks/bench_native_fmu.py [--steps N] [--runs R] [--cosim-steps N]
[--docs docs/fmu.md]: with --docs, the table of FMU costs in that file (between its
``generated`` markers) is replaced by this run's, the one place the docs quote them.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

from bench_fmu import STEP, clamp_case
from bench_fmu_trivial import TRIVIAL_SLAVE, time_step
from fmpy import extract

from fmu_src.build import build_fmu
from fmu_src.native_build import build_native_fmu
from toggle.plant import PlantOutputs

PLAIN_SLAVE = Path(__file__).with_name("trivial_plain_slave.py")

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
        if (!lib || argc < 6) return 2;
        LOAD(fmi2Instantiate); LOAD(fmi2EnterInitializationMode); LOAD(fmi2SetReal);
        LOAD(fmi2ExitInitializationMode); LOAD(fmi2GetReal); LOAD(fmi2DoStep);
        LOAD(fmi2FreeInstance);
        fmi2CallbackFunctions cb = {NULL, calloc, free, NULL, NULL};
        /* argv: library guid x_cmd_vr first_output_vr n_outputs then (vr value) pairs */
        fmi2ValueReference x_cmd = atoi(argv[3]), out0 = atoi(argv[4]), outs[12];
        int n_out = atoi(argv[5]);
        double x0 = -3.4386e-3, y[12];
        long steps = 1000000;
        for (int i = 0; i < n_out; i++) outs[i] = out0 + i;
        fmi2Component c = fmi2Instantiate("loop", fmi2CoSimulation, argv[2], "", &cb, 0, 0);
        if (!c) return 5;
        fmi2EnterInitializationMode(c);
        fmi2SetReal(c, &x_cmd, 1, &x0);
        for (int i = 6; i + 1 < argc; i += 2) {
            fmi2ValueReference vr = atoi(argv[i]);
            double v = atof(argv[i + 1]);
            fmi2SetReal(c, &vr, 1, &v);
        }
        if (fmi2ExitInitializationMode(c) != fmi2OK) return 3;
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        for (long k = 0; k < steps; k++) {
            double s = (double)(k % 800) / 400.0;  /* into the mold and back out */
            double x = x0 + 0.0544 * (s > 1.0 ? 2.0 - s : s);
            fmi2SetReal(c, &x_cmd, 1, &x);
            if (fmi2DoStep(c, k * 1e-3, 1e-3, fmi2True) != fmi2OK) return 4;
            fmi2GetReal(c, outs, n_out, y);
        }
        clock_gettime(CLOCK_MONOTONIC, &t1);
        printf("%.4f\n", ((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / steps / 1e3);
        fmi2FreeInstance(c);
        return 0;
    }
    """
)


def c_loop_us(unzip_dir: Path, work: Path, x_cmd: str, outputs: list[str],
              start: dict[str, float]) -> float:
    """µs per set-input + doStep + get outputs called from C (no fmpy), one 1e6-step run."""
    from fmpy import read_model_description

    from fmu_src.c_code import fmi2_headers

    source, exe = work / "loop.c", work / "loop"
    if not exe.exists():
        source.write_text(C_LOOP)
        subprocess.run(["gcc", "-O2", "-I", str(fmi2_headers()), str(source), "-o", str(exe),
                        "-ldl"], check=True)
    md = read_model_description(str(unzip_dir))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    if [refs[n] - refs[outputs[0]] for n in outputs] != list(range(len(outputs))):
        raise ValueError("the outputs must have consecutive value references")
    lib = unzip_dir / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    pairs = [str(v) for name, value in start.items() for v in (refs[name], repr(value))]
    run = subprocess.run([str(exe), str(lib), md.guid, str(refs[x_cmd]), str(refs[outputs[0]]),
                          str(len(outputs)), *pairs], capture_output=True, text=True,
                         check=True)
    return float(run.stdout)


def trivial_c_fmu(work: Path) -> Path:
    """benchmarks/trivial_c_fmu.c compiled and zipped as an FMI 2.0 Co-Simulation FMU."""
    import zipfile

    from fmu_src.c_code import fmi2_headers

    lib = work / "TrivialC.so"
    subprocess.run(["gcc", "-std=c99", "-O2", "-shared", "-fPIC", "-I", str(fmi2_headers()),
                    str(Path(__file__).with_name("trivial_c_fmu.c")), "-o", str(lib)],
                   check=True)
    variables = [("gain", "parameter", "fixed", 'start="2.0"'),
                 ("u", "input", "continuous", 'start="0.0"'),
                 ("y", "output", "continuous", ""), ("x", "output", "continuous", "")]
    rows = "".join(f'<ScalarVariable name="{n}" valueReference="{i}" causality="{c}" '
                   f'variability="{v}"><Real {s}/></ScalarVariable>'
                   for i, (n, c, v, s) in enumerate(variables))
    description = (
        '<?xml version="1.0" encoding="UTF-8"?><fmiModelDescription fmiVersion="2.0" '
        'modelName="TrivialC" guid="trivial-c" numberOfEventIndicators="0">'
        '<CoSimulation modelIdentifier="TrivialC" canHandleVariableCommunicationStepSize='
        f'"true"/><ModelVariables>{rows}</ModelVariables><ModelStructure><Outputs>'
        '<Unknown index="3" dependencies=""/><Unknown index="4" dependencies=""/></Outputs>'
        '</ModelStructure></fmiModelDescription>')
    fmu = work / "TrivialC.fmu"
    with zipfile.ZipFile(fmu, "w") as zf:
        zf.writestr("modelDescription.xml", description)
        zf.write(lib, "binaries/linux64/TrivialC.so")
    return fmu


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


BEGIN = "<!-- generated: python benchmarks/bench_native_fmu.py --docs docs/fmu.md -->"
END = "<!-- end of generated table -->"


def cost_table(times: dict[str, list[float]], c_us: dict[str, float],
               rates: dict[bool, dict[int, float]], runs: int, steps: int) -> str:
    """The markdown table of this run: fmpy, from C, libcosim; ratios to its baselines."""
    plain, c_base = (statistics.median(times[k]) for k in ("plain pythonfmu trivial",
                                                           "C trivial"))
    load = os.getloadavg()[0]
    rows = [f"Measured {datetime.date.today()} on {os.cpu_count()} CPUs, load average "
            f"{load:.1f}; medians of {runs} interleaved runs of {steps} steps (fmpy), 3 x 1e6 "
            "steps (from C). Ratios are within this run; absolute figures vary 1.5-2x with "
            "the load.", "",
            "| FMU | µs per step in fmpy | ratio to plain pythonfmu trivial | ratio to C trivial |",
            "|---|---|---|---|"]
    for name, values in times.items():
        us = statistics.median(values)
        rows.append(f"| {name} | {us:.1f} | {us / plain:.2f} | {us / c_base:.2f} |")
    rows += ["", "| called from C, no fmpy | µs per step | ratio to C trivial |", "|---|---|---|"]
    rows += [f"| {name} | {us:.3f} | {us / c_us['C trivial']:.0f} |" for name, us in c_us.items()]
    rows += ["", "| libcosim, 1 ms step | 1 instance | 2 instances |", "|---|---|---|"]
    for pinned, by in rates.items():
        count = {int(n): rate for n, rate in by.items()}  # JSON keys are text
        rows.append(f"| master {'on one CPU' if pinned else 'free'} | {count[1]:,.0f} steps/s | "
                    f"{count[2]:,.0f} steps/s |")
    return "\n".join(rows)


def write_docs(path: Path, table: str) -> None:
    """Replace the table between BEGIN and END in ``path``."""
    text = path.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{path}: no {BEGIN} ... {END} block")
    head, rest = text.split(BEGIN, 1)
    path.write_text(f"{head}{BEGIN}\n{table}\n{END}{rest.split(END, 1)[1]}", encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="fmpy steps per run")
    parser.add_argument("--runs", type=int, default=7, help="runs per case (median taken)")
    parser.add_argument("--cosim-steps", type=int, default=200_000, help="libcosim steps per run")
    parser.add_argument("--docs", type=Path, help="write the table into this markdown file")
    args = parser.parse_args()
    inputs, start = clamp_case()
    outputs = list(PlantOutputs._fields)
    lag = {**start, "drive_bandwidth": 20.0}
    trivial_in = {"u": [0.1, 0.2, 0.3]}
    cases = {  # name: (FMU, start values, inputs, outputs)
        "plain pythonfmu trivial": ("plain", {}, trivial_in, ["y", "x"]),
        "C trivial": ("c", {}, trivial_in, ["y", "x"]),
        "guarded trivial": ("trivial", {}, trivial_in, ["y", "x"]),
        "pythonfmu clamp, ideal": ("python", start, inputs, outputs),
        "pythonfmu clamp, 20 Hz": ("python", lag, inputs, outputs),
        "native clamp, ideal": ("native", start, inputs, outputs),
        "native clamp, 20 Hz": ("native", lag, inputs, outputs),
    }
    with tempfile.TemporaryDirectory(prefix="bench_native_") as tmp:
        from pythonfmu import FmuBuilder

        work = Path(tmp)
        native = build_native_fmu(work / "native")
        fmus = {"plain": FmuBuilder.build_FMU(PLAIN_SLAVE, dest=work / "plain"),
                "c": trivial_c_fmu(work), "trivial": build_fmu(work / "trivial", TRIVIAL_SLAVE),
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
        c_cases = {"native clamp, ideal": ("native", "x_cmd", outputs, start),
                   "native clamp, 20 Hz": ("native", "x_cmd", outputs, lag),
                   "C trivial": ("c", "u", ["y", "x"], {})}
        c_us = {name: statistics.median(c_loop_us(dirs[kind], work, x, outs, values)
                                        for _ in range(3))
                for name, (kind, x, outs, values) in c_cases.items()}
    plain, c_base = (statistics.median(times[k]) for k in ("plain pythonfmu trivial",
                                                           "C trivial"))
    print(f"us per set-inputs + doStep + get-outputs in fmpy (median of {args.runs} "
          f"interleaved runs x {args.steps} steps; clamp: 12 outputs, mold at x_toggle - 1 mm, "
          "delta_r8 = 0.3 mm; trivial: 2 outputs):")
    for name, values in times.items():
        us = statistics.median(values)
        print(f"  {name:24s} {us:8.2f} us   ratio to plain pythonfmu trivial "
              f"{us / plain:5.2f}, to C trivial {us / c_base:5.2f}")
    print("called from C, no fmpy (median of 3 runs x 1e6 steps, the same parameters):")
    for name, us in c_us.items():
        print(f"  {name:24s} {us:8.3f} us   ratio to C trivial {us / c_us['C trivial']:6.1f}")
    for pinned, by_count in rates.items():
        for n, rate in by_count.items():
            print(f"libcosim{' on one CPU' if pinned else ''}, {n} native instance(s), 1 ms "
                  f"step: {rate:,.0f} steps/s (median of {args.runs} runs x {args.cosim_steps})")
    if args.docs:
        write_docs(args.docs, cost_table(times, c_us, rates, args.runs, args.steps))
        print(f"wrote the table into {args.docs}")


if __name__ == "__main__":
    main()
