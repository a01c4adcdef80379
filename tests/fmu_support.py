"""Helpers shared by the FMU tests: run an FMU in other processes and masters.

Both runners start a fresh Python (one that has not imported this project)
with a script that takes a JSON spec, and return the JSON the script prints
last (the process must also exit with 0). ``run_fresh`` simulates with fmpy and
reports where the FMU's bundled package was imported from (it must be the FMU's
own ``resources/``) and whether a top-level ``toggle`` was imported; ``run_libcosim`` runs
any number of FMU instances in one libcosimpy (DNV libcosim) execution.
"""

from __future__ import annotations

import atexit
import functools
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType

import numpy as np

from fmu_src.build import DEFAULT_SLAVE
from fmu_src.slave import Var

FRESH_PROCESS = textwrap.dedent(
    """
    import json, sys
    from pathlib import Path
    import numpy as np
    from fmpy import extract, simulate_fmu
    spec = json.loads(sys.argv[1])
    unzip = Path(spec["unzip"])
    extract(spec["fmu"], str(unzip))
    name, times, values = spec["input"]
    signal = np.array(list(zip(times, values)), dtype=[("time", float), (name, float)])
    res = simulate_fmu(str(unzip), stop_time=spec["stop_time"], step_size=spec["step_size"],
                       input=signal, start_values=spec["start_values"], output=spec["output"])
    bundled = [m.__file__ for n, m in sys.modules.items() if n.startswith(("toggle_", "fmu_src_"))
               and "." not in n and str(getattr(m, "__file__", "")).endswith("__init__.py")]
    print(json.dumps({"last": {n: float(res[n][-1]) for n in spec["output"]},
                      "toggle": bundled[0] if bundled else None,
                      "host_toggle": bool({"toggle", "fmu_src"} & set(sys.modules))}))
    """
)

LIBCOSIM = textwrap.dedent(
    """
    import json, sys
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave
    spec = json.loads(sys.argv[1])
    log_output_level(CosimLogLevel.WARNING)
    execution = CosimExecution.from_step_size(spec["step_ns"])
    index, refs = {}, {}
    for name, fmu in spec["slaves"].items():
        index[name] = execution.add_local_slave(CosimLocalSlave(fmu_path=fmu, instance_name=name))
        refs[name] = {v.name.decode(): v.reference for v in execution.slave_variables(index[name])}
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    for name, var, value in spec["initial"]:
        execution.real_initial_value(index[name], refs[name][var], value)
    for src, out, dst, inp in spec["connections"]:
        execution.connect_real_variables(index[src], refs[src][out], index[dst], refs[dst][inp])
    ok = execution.simulate_until(spec["stop_ns"])
    last = {name: dict(zip(names, observer.last_real_values(index[name],
                                                             [refs[name][n] for n in names])))
            for name, names in spec["observe"].items()}
    print(json.dumps({"ok": ok, "last": last}), flush=True)
    """
)


#: Ecos (NTNU's C++ co-simulation engine, ecospy): instances of FMUs in one execution, the
#: master setting x_cmd before every step; its native library needs oneTBB's libtbb.so.12,
#: which the tbb wheel installs under sys.prefix/lib (:func:`run_ecos`).
ECOS = textwrap.dedent(
    """
    import json, os, sys
    from ecospy import EcosSimulation, EcosSimulationStructure
    spec = json.loads(sys.argv[1])
    structure = EcosSimulationStructure()
    for name, fmu in spec["slaves"].items():
        structure.add_model(name, fmu)
    structure.add_parameter_set("start", {f"{name}::{var}": value
                                          for name, var, value in spec["initial"]})
    out = {name: [] for name in spec["slaves"]}
    with EcosSimulation(structure=structure, step_size=spec["step"]) as sim:
        for name in spec["slaves"]:
            sim.set_real(f"{name}::x_cmd", spec["x_cmd"][0])
        sim.init(parameter_set="start")
        for x_cmd in spec["x_cmd"][1:]:
            for name in spec["slaves"]:
                sim.set_real(f"{name}::x_cmd", x_cmd)
            sim.step()
            for name in spec["slaves"]:
                out[name].append([sim.get_real(f"{name}::{v}") for v in spec["observe"]])
        sim.terminate()
    print(json.dumps(out), flush=True)
    # the instances are freed: the process ends here, without the interpreter's teardown,
    # where oneTBB (Ecos's) crashed 1 run in 5 (SIGSEGV after the results were printed; the
    # core: a TBB worker thread in governor::release_resources -> dynamic_unlink_all
    # unmapping the library that the main thread's exit was executing)
    sys.stderr.flush()
    os._exit(0)
    """
)


def run_ecos(cwd: Path, slaves: Mapping[str, Path], x_cmd: Sequence[float],
             observe: Sequence[str], initial: Sequence[tuple[str, str, float]] = (),
             step_size: float = 1e-3) -> dict[str, list[list[float]]]:
    """Run instances (name → FMU path) in one Ecos simulation: x_cmd[0] before initialisation,
    then x_cmd[k] set before step k. Returns {instance: [[observed values] after each step]}."""
    spec = {"slaves": {k: str(v) for k, v in slaves.items()}, "x_cmd": list(x_cmd),
            "observe": list(observe), "initial": [list(row) for row in initial],
            "step": step_size}
    env = {**os.environ, "LD_LIBRARY_PATH": os.pathsep.join(
        filter(None, [str(Path(sys.prefix) / "lib"), os.environ.get("LD_LIBRARY_PATH")]))}
    return _run_script(ECOS, spec, cwd, env)


FIXTURES = Path(__file__).parent / "fmu_fixtures"


@functools.cache
def built_fmu(kind: str = "clamp") -> Path:
    """An FMU built once per test session and shared by the test modules: ``"clamp"`` (the
    pythonfmu build of chang2021), ``"native"`` (its native build), ``"trivial"`` and
    ``"staircase"`` (the slaves in fmu_fixtures/). Read-only: extract it to use it."""
    from fmu_src.build import build_fmu
    from fmu_src.native_build import build_native_fmu

    folder = Path(tempfile.mkdtemp(prefix=f"toggle_{kind}_fmu_"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    builders = {"clamp": lambda: build_fmu(folder), "native": lambda: build_native_fmu(folder),
                "trivial": lambda: build_fmu(folder, FIXTURES / "trivial_slave.py"),
                "staircase": lambda: build_fmu(folder, FIXTURES / "staircase_slave.py")}
    return builders[kind]()


def compile_c_host(folder: Path) -> Path:
    """tests/fmu_c_host.c (a C master: dlopen, no Python, no environment) compiled."""
    from fmu_src.c_code import fmi2_headers

    host = folder / "host"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-I", str(fmi2_headers()),
                    str(Path(__file__).parent / "fmu_c_host.c"), "-o", str(host), "-ldl"],
                   check=True, capture_output=True)
    return host


#: A master without Python: an environment with PATH and the venv the pythonfmu FMU runs
#: in (docs/fmu.md), nothing else (no LD_PRELOAD, no PYTHONPATH).
BARE_ENV = {"PATH": "/usr/bin:/bin", "VIRTUAL_ENV": sys.prefix}


def run_c_host(c_host: Path, unzipped: Path, m_platen: float, loads: int,
               env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """The C host on an extracted FMU (resources given as a file: URI), in ``env`` (default
    :data:`BARE_ENV`): ``loads`` times instantiate, set m_platen, 500 steps of a ramp, free."""
    from fmpy import read_model_description

    md = read_model_description(str(unzipped))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    library = unzipped / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    return subprocess.run(
        [str(c_host), str(library), md.guid, (unzipped / "resources").as_uri(),
         *(str(refs[n]) for n in ("x_cmd", "input_force", "m_platen")), repr(m_platen),
         str(loads)],
        capture_output=True, text=True, timeout=120, env=BARE_ENV if env is None else env)


def run_steps(slave, refs: Mapping[str, int], commands_and_steps, read, t: float = 0.0
              ) -> list:
    """Set x_cmd and doStep for each (x_cmd, h); ``read(slave, refs)`` after each step."""
    out = []
    for x_cmd, h in commands_and_steps:
        slave.setReal([refs["x_cmd"]], [x_cmd])
        slave.doStep(t, h)
        t += h
        out.append(read(slave, refs))
    return out


def slip_along(x, slip_distance: float) -> np.ndarray:
    """The pin friction's slip state at each point of a sampled path that starts relaxed
    (z = 0), as the FMUs and the rig emulator carry it (toggle.plant.HystereticPlant)."""
    from toggle.asymmetry import advance_slip_state

    x = np.atleast_1d(np.asarray(x, dtype=float))
    z = np.zeros_like(x)
    for i in range(1, x.size):
        z[i] = advance_slip_state(z[i - 1], x[i] - x[i - 1], slip_distance)
    return z


def close_slave(slave, *states) -> None:
    """Free saved FMU states, terminate and free an fmpy slave."""
    for state in states:
        slave.freeFMUstate(state)
    slave.terminate()
    slave.freeInstance()


def validator_problems(fmu: Path) -> list[str]:
    """Problems fmpy's validator and ``fmutool -check`` find in ``fmu`` (none: [])."""
    from fmpy.validation import validate_fmu

    problems = list(validate_fmu(str(fmu)))
    log = fmutool_log(fmu)
    if "ERROR" in log or "No semantic error" not in log:
        problems.append(f"fmutool -check: {log}")
    return problems


def fmutool_log(fmu: Path) -> str:
    """Output of ``fmutool -check`` (fmu-manipulation-toolbox) on ``fmu``; skip if absent."""
    import pytest

    fmutool = Path(sys.executable).parent / "fmutool"
    if not fmutool.exists():
        pytest.skip("fmu-manipulation-toolbox is not installed")
    run = subprocess.run(
        [str(fmutool), "-input", str(fmu), "-check"], capture_output=True, text=True, timeout=60
    )
    log = run.stdout + run.stderr
    assert run.returncode == 0, log
    return log


def load_module(path: Path, name: str) -> ModuleType:
    """Import a slave file in-process under ``name``.

    Use a name that differs from the module name inside the FMU: pythonfmu
    imports the slave by that name and would reuse a module already in
    ``sys.modules``.
    """
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run_script(script: str, spec: dict, cwd: Path, env: Mapping[str, str] | None = None
                ) -> dict:
    run = subprocess.run(
        # faulthandler: a crash of the master (Ecos once died of SIGSEGV) prints its stacks
        [sys.executable, "-X", "faulthandler", "-c", script, json.dumps(spec)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=cwd,
        env=env,
    )
    assert run.returncode == 0, (run.returncode, run.stderr)
    return json.loads(run.stdout.strip().splitlines()[-1])


def run_fresh(
    fmu: Path,
    cwd: Path,
    signal: tuple[str, Sequence[float], Sequence[float]],
    output: Sequence[str],
    stop_time: float,
    step_size: float,
    start_values: Mapping[str, float | str] | None = None,
) -> dict:
    """Simulate ``fmu`` with fmpy in a fresh Python; ``signal`` is (input name, times, values).

    Returns ``{"last": {output: value at stop_time}, "toggle": <toggle/__init__.py used>,
    "unzip": <extraction folder>}``.
    """
    unzip = cwd / "unzipped"
    spec = {"fmu": str(fmu), "unzip": str(unzip), "input": [signal[0], list(signal[1]),
                                                           list(signal[2])],
            "output": list(output), "stop_time": stop_time, "step_size": step_size,
            "start_values": dict(start_values or {})}
    return _run_script(FRESH_PROCESS, spec, cwd) | {"unzip": str(unzip)}


def run_libcosim(
    cwd: Path,
    slaves: Mapping[str, Path],
    observe: Mapping[str, Sequence[str]],
    initial: Sequence[tuple[str, str, float]] = (),
    connections: Sequence[tuple[str, str, str, str]] = (),
    step_size: float = 1e-3,
    stop_time: float = 0.1,
) -> dict:
    """Run instances (name → FMU path) in one libcosim execution with a fixed step.

    ``initial`` rows are (instance, variable, value); ``connections`` rows are
    (source instance, output, target instance, input). Returns
    ``{"ok": bool, "last": {instance: {variable: value at stop_time}}}``.
    """
    spec = {"slaves": {k: str(v) for k, v in slaves.items()},
            "observe": {k: list(v) for k, v in observe.items()},
            "initial": [list(row) for row in initial],
            "connections": [list(row) for row in connections],
            "step_ns": round(step_size * 1e9), "stop_ns": round(stop_time * 1e9)}
    return _run_script(LIBCOSIM, spec, cwd)


def variable_table(variables: Sequence[Var]) -> str:
    """Markdown table of a slave's variables (docs/fmu.md embeds ToggleClamp's)."""
    rows = ["| Name | Causality | Unit | Start | Min | Max | Description |",
            "|---|---|---|---|---|---|---|"]
    for var in variables:
        if var.is_string:
            start, unit = f'`"{var.start}"`', ""
        else:
            start, unit = ("" if var.start is None else f"{var.start:g}"), var.unit
        low, high = ("" if b is None else f"{b:g}" for b in (var.min, var.max))
        rows.append(f"| `{var.name}` | {var.causality} | {unit} | {start} | {low} | {high} | "
                    f"{var.description} |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":  # print ToggleClamp's table for docs/fmu.md
    print(variable_table(load_module(DEFAULT_SLAVE, "toggle_clamp_fmu_doc").ToggleClamp.VARIABLES),
          end="")
