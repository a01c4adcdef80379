"""The native FMU under every interface (FMI 2.0 and 3.0, Co-Simulation and Model
Exchange, one C core), setpoints with input derivatives, and any unpack path.

- fmpy validates and simulates all four; the four give the same trajectory for the docs'
  quintic closing stroke into a mold (Model Exchange under fmpy's CVode, with the command
  set at each right-hand-side evaluation, to 1e-6 of each output's peak);
- with x_cmd's velocity and acceleration at the step's start (fmi2SetRealInputDerivatives)
  the ideal drive ends each step on the master's polynomial, whatever the steps;
- a step the drive cannot follow names drive_bandwidth, in the pythonfmu build's words;
- extracted under a folder named with a space, %, # and é, the FMU runs in fmpy, the C host
  and (with FMUCHECK) the FMI Compliance Checker.
"""

from __future__ import annotations

import math
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Model, FMU2Slave
from fmpy.fmi3 import FMU3Model
from fmpy.sundials import CVodeSolver
from fmpy.validation import validate_fmu
from native_support import native_build

from fmu_src.c_code import fmi_headers
from fmu_src.host import start_slave
from fmu_src.native_build import slave_variables
from toggle.kinematics import stroke_limits
from toggle.plant import PlantOutputs, configure

OUTPUTS = list(PlantOutputs._fields)
VARIABLES = {v.name: v for v in slave_variables()[0]}
X_OPEN, X_TOGGLE = stroke_limits(configure("chang2021").mechanism.lower)
STOP = 0.5  # s: the docs' stroke closes in 0.4 s into a mold 1 mm before the toggle
#: the docs' parameters; a critically damped 20 Hz drive (Model Exchange needs a lag, and
#: with damping 1 the drive does not reverse, where a step's net slip update and the
#: integrated slip law would differ)
START = {"x_cmd": X_OPEN, "x_contact": X_TOGGLE - 1e-3, "delta_r8": 0.3e-3,
         "drive_bandwidth": 20.0, "drive_damping": 1.0}
H_CS = 1e-4  # s: Co-Simulation step of the comparison (the parabola's error ~ jerk h^3)


def _command(t):
    """The docs' quintic stroke x_cmd(t) and its first two derivatives."""
    s = np.clip(np.asarray(t, dtype=float) / 0.4, 0.0, 1.0)
    span, inside = X_TOGGLE - X_OPEN, (np.asarray(t) > 0) & (np.asarray(t) < 0.4)
    x = X_OPEN + span * s**3 * (10 - 15 * s + 6 * s**2)
    v = np.where(inside, span * 30 * s**2 * (1 - s) ** 2 / 0.4, 0.0)
    a = np.where(inside, span * 60 * s * (1 - s) * (1 - 2 * s) / 0.16, 0.0)
    return x, v, a


def _signal(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.array(list(zip(times, values)), dtype=[("time", float), ("x_cmd", float)])


@pytest.fixture(scope="module")
def both() -> dict[int, Path]:
    """FMI 2.0 and 3.0 builds that declare Co-Simulation and Model Exchange."""
    return {version: native_build(version, "both") for version in (2, 3)}


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("fmi_type", ["CoSimulation", "ModelExchange"])
def test_fmpy_validates_and_simulates_every_interface(both: dict, version: int, fmi_type: str):
    assert validate_fmu(str(both[version])) == []
    md = read_model_description(str(both[version]))
    assert md.fmiVersion == f"{version}.0" and md.coSimulation and md.modelExchange
    assert [d.variable.derivative.name for d in md.derivatives] == ["x", "velocity", "slip_state"]
    t = np.arange(0.0, STOP + 5e-4, 1e-3)
    res = simulate_fmu(str(both[version]), fmi_type=fmi_type, stop_time=STOP,
                       output_interval=1e-3, input=_signal(t, _command(t)[0]),
                       start_values=START, output=OUTPUTS)
    assert all(np.isfinite(res[n]).all() for n in OUTPUTS)
    assert res["clamp_force"][-1] > 100.0  # N: the mold is clamped
    assert res["x"][-1] == pytest.approx(X_TOGGLE, abs=1e-3)


def _co_simulation(fmu: Path, tmp: Path) -> dict:
    """H_CS steps; x_cmd(t) and its two derivatives set before doStep(t, h) (docs/fmu.md)."""
    slave, refs = start_slave(Path(extract(str(fmu), str(tmp))), "cs", START)
    vr, rows = refs["x_cmd"], []
    for k in range(round(STOP / H_CS)):
        x, v, a = (float(c) for c in _command(k * H_CS))
        slave.setReal([vr], [x])
        slave.setRealInputDerivatives([vr, vr], [1, 2], [v, a])
        slave.doStep(k * H_CS, H_CS)
        if (k + 1) % round(1e-3 / H_CS) == 0:
            rows.append(slave.getReal([refs[n] for n in OUTPUTS]))
    slave.terminate()
    slave.freeInstance()
    return {n: np.array(column) for n, column in zip(OUTPUTS, zip(*rows), strict=True)}


def _model_exchange(fmu: Path, version: int, tmp: Path) -> dict:
    """fmpy's CVode on the FMU's states, x_cmd(t) set at every right-hand-side evaluation."""
    folder = extract(str(fmu), str(tmp))
    md = read_model_description(folder)
    refs = {v.name: v.valueReference for v in md.modelVariables}
    common = {"unzipDirectory": folder, "modelIdentifier": md.modelExchange.modelIdentifier,
              "instanceName": "me"}
    if version == 2:
        model = FMU2Model(guid=md.guid, **common)
        model.instantiate()
        model.setupExperiment(startTime=0.0)
        model.enterInitializationMode()
        set_real, get_real = model.setReal, model.getReal
    else:
        model = FMU3Model(guid=md.guid, **common)
        model.instantiate()
        model.enterInitializationMode(startTime=0.0)
        set_real, get_real = model.setFloat64, model.getFloat64
    for name, value in START.items():
        set_real([refs[name]], [value])
    model.exitInitializationMode()
    if version == 2:
        model.newDiscreteStates()
    else:
        model.updateDiscreteStates()
    model.enterContinuousTimeMode()

    def set_time(t: float) -> None:
        model.setTime(t)
        set_real([refs["x_cmd"]], [float(_command(t)[0])])

    solver = CVodeSolver(nx=3, nz=0, get_x=model.getContinuousStates,
                         set_x=model.setContinuousStates,
                         get_dx=model.getDerivatives if version == 2
                         else model.getContinuousStateDerivatives,
                         get_z=model.getEventIndicators,
                         get_nominals=model.getNominalsOfContinuousStates, set_time=set_time,
                         input=None, startTime=0.0, maxStep=1e-3, relativeTolerance=1e-11)
    rows, t = [get_real([refs[n] for n in OUTPUTS])], 0.0
    for k in range(1, round(STOP / 1e-3) + 1):
        _, _, t = solver.step(t, k * 1e-3)
        set_time(t)
        model.completedIntegratorStep()
        rows.append(get_real([refs[n] for n in OUTPUTS]))
    model.terminate()
    model.freeInstance()
    return {n: np.array(column) for n, column in zip(OUTPUTS, zip(*rows), strict=True)}


def test_the_four_interfaces_give_the_same_trajectory(both: dict, tmp_path: Path):
    """FMI 2.0 Co-Simulation with x_cmd's derivatives and Model Exchange with x_cmd set at
    every right-hand-side evaluation agree to 1e-6 of each output's peak (FMI 3.0
    Co-Simulation, which extrapolates x_cmd over a step, is FMI 2.0's without derivatives:
    tests/test_fmu_inputs.py)."""
    runs = {"FMI 2.0 CS": _co_simulation(both[2], tmp_path / "cs")}
    runs |= {f"FMI {v}.0 ME": {n: column[1:] for n, column in  # from t = 1 ms, as CS
                                _model_exchange(both[v], v, tmp_path / f"me{v}").items()}
             for v in (2, 3)}
    for run in runs.values():  # 1/|q| is ill-conditioned at the toggle: compare q
        run["mechanical_advantage"] = 1.0 / run["mechanical_advantage"]
    reference = runs["FMI 2.0 CS"]
    for name, run in runs.items():
        for out in OUTPUTS:
            peak = float(np.max(np.abs(reference[out])))
            np.testing.assert_allclose(run[out], reference[out], rtol=0, atol=1e-6 * peak,
                                       err_msg=f"{name}: {out}")
    assert reference["clamp_force"].max() > 100.0


def test_model_exchange_needs_a_drive_lag(both: dict):
    log: list[tuple[int, str]] = []
    folder = extract(str(both[2]))
    md = read_model_description(folder)
    model = FMU2Model(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.modelExchange.modelIdentifier, instanceName="me")
    from fmu_src.host import log_callbacks

    model.instantiate(callbacks=log_callbacks(lambda s, text: log.append((s, text))))
    model.setupExperiment(startTime=0.0)
    model.enterInitializationMode()
    refs = {v.name: v.valueReference for v in md.modelVariables}
    model.setReal([refs["drive_bandwidth"]], [0.0])
    with pytest.raises(FMICallException):
        model.exitInitializationMode()
    model.freeInstance()
    assert "drive_bandwidth = 0 Hz: Model Exchange needs drive_bandwidth > 0 Hz" in log[-1][1]


# ---- setpoints as masters send them ---------------------------------------------------------


def _steps_with_derivatives(folder: Path, steps: list[float]) -> tuple[list, list]:
    """FMI 2.0 CS with the ideal drive over the docs' stroke; before each step x_cmd and
    its derivatives at the step's start. Returns the times and outputs after each step."""
    slave, refs = start_slave(folder, "derivatives", {**START, "drive_bandwidth": 0.0})
    times, rows, t = [], [], 0.0
    for h in steps:
        x, v, a = (float(c) for c in _command(t))
        slave.setReal([refs["x_cmd"]], [x])
        slave.setRealInputDerivatives([refs["x_cmd"]] * 2, [1, 2], [v, a])
        slave.doStep(t, h)
        t += h
        times.append(t)
        rows.append(slave.getReal([refs[n] for n in OUTPUTS]))
    slave.terminate()
    slave.freeInstance()
    return times, rows


def test_with_input_derivatives_the_ideal_drive_follows_the_masters_polynomial(tmp_path: Path):
    """The ideal drive ends each step where the master's Taylor polynomial at the step's
    start puts it (x, velocity, acceleration, to rounding), whatever the steps: alternating
    0.5/1.5 ms steps then differ from 1 ms steps by the polynomial's own error only (jerk
    h in the acceleration, so about 3 % of the peak input force; 4e-7 of the stroke in x)."""
    md = read_model_description(str(native_build()))
    assert md.coSimulation.canInterpolateInputs
    folder = Path(extract(str(native_build()), str(tmp_path)))
    steps = [0.5e-3, 1.5e-3] * round(STOP / 2e-3)
    variable_t, variable = _steps_with_derivatives(folder, steps)
    starts = np.array(variable_t) - steps
    x, v, a = _command(starts)
    h = np.array(steps)
    taylor = np.column_stack([x + v * h + a * h * h / 2, v + a * h, a])
    np.testing.assert_allclose(np.array(variable)[:, :3], taylor, rtol=1e-12, atol=1e-15)
    fixed_t, fixed = _steps_with_derivatives(folder, [1e-3] * round(STOP / 1e-3))
    fixed_at = dict(zip(np.round(fixed_t, 9), fixed))
    pairs = [(fixed_at[t], row) for t, row in zip(np.round(variable_t, 9), variable)
             if t in fixed_at]
    assert len(pairs) == round(STOP / 2e-3)
    want, got = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
    peak = np.max(np.abs(want), axis=0)
    bound = np.full(len(OUTPUTS), 0.05)
    bound[OUTPUTS.index("x")] = 1e-6
    assert (np.abs(got - want) <= bound * peak).all(), np.max(np.abs(got - want) / peak, axis=0)


STEP_JUMP = 0.05  # m of setpoint jump within one 1 ms step


@pytest.mark.parametrize("bandwidth", [0.0, VARIABLES["drive_bandwidth"].max, 20.0])
def test_a_setpoint_jump_is_followed_or_refused_naming_drive_bandwidth(bandwidth: float,
                                                                      tmp_path: Path):
    log: list[tuple[int, str]] = []
    folder = Path(extract(str(native_build()), str(tmp_path)))
    slave, refs = start_slave(folder, "jump", {"drive_bandwidth": bandwidth},
                              log=lambda s, text: log.append((s, text)))
    slave.setReal([refs["x_cmd"]], [X_OPEN + STEP_JUMP])
    if bandwidth == 20.0:  # 790 m/s^2 at most: a lagging drive follows the jump
        slave.doStep(0.0, 1e-3)
        assert not log
        return
    with pytest.raises(FMICallException):
        slave.doStep(0.0, 1e-3)
    v, a = (2 * STEP_JUMP / 1e-3, 2 * STEP_JUMP / 1e-6) if bandwidth == 0 else (None, None)
    text = log[-1][1]
    if bandwidth == 0:
        assert text == (f"step at t=0 s rejected: the command x_cmd = {X_OPEN + STEP_JUMP:.6g} m "
                        f"after 0.001 s asks for {v:.3g} m/s and {a:.3g} m/s^2; an input link "
                        "moves within 10 m/s and 10000 m/s^2 (drive_bandwidth = 0: an ideal "
                        "drive follows a setpoint jump within one step; a drive_bandwidth > 0 "
                        "Hz follows it through the drive's lag)")
    else:
        assert text.endswith(f"(drive_bandwidth = {bandwidth:.6g} Hz; a lower drive_bandwidth "
                             "follows larger setpoint jumps)")
    slave.terminate()
    slave.freeInstance()


# ---- any unpack path ------------------------------------------------------------------------

ODD = "odd folder % #1 é"


def test_an_fmu_unpacked_under_an_odd_path_runs_in_fmpy_and_a_c_host(tmp_path: Path):
    fmu = native_build()
    folder = Path(extract(str(fmu), str(tmp_path / ODD / "ToggleClampNative")))
    t = np.arange(0.0, 0.1 + 5e-4, 1e-3)
    res = simulate_fmu(str(folder), stop_time=0.1, output_interval=1e-3,
                       input=_signal(t, X_OPEN + 0.1 * t), output=["x"],
                       start_values={"drive_bandwidth": 0.0})  # ideal drive: x is the command
    assert res["x"][-1] == pytest.approx(X_OPEN + 0.1 * 0.099, rel=1e-12)  # set at 99 ms
    host = tmp_path / "host"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-I", str(fmi_headers()),
                    str(Path(__file__).with_name("fmu_c_host.c")), "-o", str(host), "-ldl"],
                   check=True, capture_output=True)
    md = read_model_description(str(folder))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    library = folder / "binaries" / "linux64" / "ToggleClampNative.so"
    run = subprocess.run([str(host), str(library), md.guid, (folder / "resources").as_uri(),
                          *(str(refs[n]) for n in ("x_cmd", "input_force", "m_platen")), "4.0",
                          "1"], capture_output=True, text=True, env={"PATH": "/usr/bin:/bin"},
                         timeout=30)
    assert run.returncode == 0, run.stderr
    status, force = run.stdout.split()
    assert status == "0" and math.isfinite(float(force))


def test_an_fmu_under_an_odd_path_passes_the_compliance_checker(tmp_path: Path):
    checker = os.environ.get("FMUCHECK")
    if not checker:
        pytest.skip("set FMUCHECK to an fmuCheck.linux64 (see docs/fmu-native.md)")
    folder = tmp_path / ODD
    (folder / "unpacked").mkdir(parents=True)  # the checker's -t: where it extracts
    fmu = folder / "ToggleClampNative.fmu"
    fmu.write_bytes(native_build().read_bytes())
    log = tmp_path / "check.log"
    run = subprocess.run([checker, "-l", "3", "-e", str(log), "-o", str(tmp_path / "out.csv"),
                          "-t", str(folder / "unpacked"), str(fmu)], capture_output=True,
                         text=True, timeout=120)
    text = log.read_text()
    assert run.returncode == 0, text
    assert "0 warning(s) and error(s)" in text and "0 Warning(s)" in text
    assert "0 Error(s)" in text


def test_fmu2slave_of_the_both_build_is_the_cs_builds(both: dict, tmp_path: Path):
    """One core: the CS+ME FMU stepped as Co-Simulation gives the CS FMU's outputs."""
    outs = []
    for fmu in (native_build(), both[2]):
        folder = extract(str(fmu), str(tmp_path / fmu.stem))
        md = read_model_description(folder)
        slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName="cs")
        refs = {v.name: v.valueReference for v in md.modelVariables}
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        for name, value in START.items():
            slave.setReal([refs[name]], [value])
        slave.exitInitializationMode()
        rows = []
        for k in range(1, 301):
            slave.setReal([refs["x_cmd"]], [float(_command(k * 1e-3)[0])])
            slave.doStep((k - 1) * 1e-3, 1e-3)
            rows.append(slave.getReal([refs[n] for n in OUTPUTS]))
        slave.terminate()
        slave.freeInstance()
        outs.append(rows)
    assert outs[0] == outs[1]
