"""The docs' stroke into the mold and its reference: how close an FMU comes under a master.

docs/fmu.md's accuracy table (written by docs/fmu_accuracy.py) and tests/test_fmu_inputs.py
feed every build the same command u(t), the quintic closing stroke of chang2021 into a mold
1 mm before the toggle with link 8 0.3 mm long and a critically damped 20 Hz drive, and
compare the outputs after each step with :mod:`toggle.plant` stepped at 1e-5 s with the
command's exact derivatives. The masters: ``fmpy.simulate_fmu`` as it comes, a loop that
sends input derivatives, Model Exchange with the input set at every evaluation; and the
steps in-process (``toggle.plant``'s :func:`~toggle.plant.drive_step`, and
:func:`~toggle.plant.follow`, the step before issue 39's input change).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from fmpy import read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Model
from fmpy.sundials import CVodeSolver

from fmu_src.host import start_slave
from toggle.params import load_preset
from toggle.plant import DriveState, HystereticPlant, configure, drive_step, follow

X_OPEN, X_TOGGLE = -3.4386e-3, 51.566e-3  # chang2021, m
CLOSE, STOP = 0.4, 0.5  # s: the quintic closes in 0.4 s; 0.1 s at rest in the mold
#: the FMU's start values of the stroke (docs/fmu.md, docs/fmu-native.md)
START = {"x_contact": X_TOGGLE - 1e-3, "delta_r8": 0.3e-3, "drive_bandwidth": 20.0,
         "drive_damping": 1.0, "x_cmd": X_OPEN}
#: the outputs compared, in the table's order
OUTPUTS = ("clamp_force", "tiebar_force", "input_force", "motor_torque", "acceleration")
REFERENCE_STEP, EVERY = 1e-5, 5e-4  # s: the reference's step, and its samples

Stepper = Callable[[DriveState, float, float, float, float, float], DriveState]


def stroke(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The docs' quintic closing stroke: x_cmd (m) and its first two derivatives at t (s)."""
    t = np.asarray(t, dtype=float)
    s, span = np.clip(t / CLOSE, 0.0, 1.0), X_TOGGLE - X_OPEN
    moving = (t > 0) & (t < CLOSE)
    return (X_OPEN + span * s**3 * (10 - 15 * s + 6 * s**2),
            np.where(moving, span * 30 * s**2 * (1 - s) ** 2 / CLOSE, 0.0),
            np.where(moving, span * 60 * s * (1 - s) * (1 - 2 * s) / CLOSE**2, 0.0))


def _derivatives(state, u, h, bw, zeta, du, ddu):
    return drive_step(state, u, h, bw, zeta, du, ddu)


def _extrapolated(state, u, h, bw, zeta, du, ddu):
    return drive_step(state, u, h, bw, zeta)


def _held(state, u, h, bw, zeta, du, ddu):
    return drive_step(state, u, h, bw, zeta, 0.0)


def _before(state, u, h, bw, zeta, du, ddu):
    return follow(state, u, h, bw, zeta)


#: The steps in-process: with the command's derivatives; without (extrapolated, the FMUs
#: now); held (the FMUs of issue 39 without derivatives); x_cmd read as the step's end (the
#: FMUs before issue 39's input change).
STEPPERS: dict[str, Stepper] = {"derivatives": _derivatives, "extrapolated": _extrapolated,
                                "held": _held, "before": _before}


def simulate(h: float, stepper: str = "derivatives") -> dict[str, np.ndarray]:
    """The outputs after each step of ``h`` (s) from 0 to STOP, x_cmd(t) given at each
    step's start t, stepped in-process by ``STEPPERS[stepper]``."""
    cfg = configure(load_preset("chang2021"), x_contact=START["x_contact"],
                    errors={"r8": START["delta_r8"]})
    plant, drive, step = HystereticPlant(cfg), DriveState.at_rest(X_OPEN), STEPPERS[stepper]
    plant.state = (None, 0.0)
    u, du, ddu = stroke(np.arange(round(STOP / h)) * h)
    rows = []
    for k in range(u.size):
        drive = step(drive, float(u[k]), h, START["drive_bandwidth"], START["drive_damping"],
                     float(du[k]), float(ddu[k]))
        out = plant(drive)
        rows.append([getattr(out, name) for name in OUTPUTS])
    return dict(zip(OUTPUTS, np.array(rows).T, strict=True))


def reference() -> dict[str, np.ndarray]:
    """The outputs every EVERY (s), from EVERY to STOP: toggle.plant at 1e-5 s steps with
    the command's exact derivatives."""
    fine = simulate(REFERENCE_STEP)
    every = round(EVERY / REFERENCE_STEP)
    return {name: column[every - 1::every] for name, column in fine.items()}


def errors(got: dict[str, np.ndarray], ref: dict[str, np.ndarray], h: float
           ) -> dict[str, tuple[float, float]]:
    """Per output of ``got`` (after each step of ``h``, a multiple of EVERY): the largest
    pointwise error and the error of the peak |value|, both over the reference's peak."""
    stride = round(h / EVERY)
    out = {}
    for name in (n for n in OUTPUTS if n in got):
        want = ref[name][stride - 1::stride]
        have = np.asarray(got[name], dtype=float)[:want.size]
        peak = float(np.abs(want).max())
        out[name] = (float(np.abs(have - want).max() / peak),
                     float(abs(np.abs(have).max() - peak) / peak))
    return out


def _signal(h: float) -> np.ndarray:
    t = np.arange(0.0, STOP + h / 2, h)
    return np.array(list(zip(t, stroke(t)[0])), dtype=[("time", float), ("x_cmd", float)])


def stock(fmu: Path, h: float) -> dict[str, np.ndarray]:
    """``fmpy.simulate_fmu`` as it comes: Co-Simulation at h (no input derivatives), or Model
    Exchange under CVode at its defaults with the input sampled every h."""
    result = simulate_fmu(str(fmu), stop_time=STOP, step_size=h, output_interval=h,
                          input=_signal(h), start_values=START, output=list(OUTPUTS))
    return {name: result[name][1:] for name in OUTPUTS}


def with_derivatives(unzipped: Path, h: float, order: int) -> dict[str, np.ndarray]:
    """A master loop: x_cmd(t) and its derivatives up to ``order`` set before doStep(t, h)."""
    slave, refs = start_slave(unzipped, "accuracy", START)
    rows = []
    for k in range(round(STOP / h)):
        values = [float(v) for v in stroke(np.array(k * h))]
        slave.setReal([refs["x_cmd"]], [values[0]])
        for n in range(1, order + 1):
            slave.setRealInputDerivatives([refs["x_cmd"]], [n], [values[n]])
        slave.doStep(k * h, h)
        rows.append(slave.getReal([refs[name] for name in OUTPUTS]))
    slave.terminate()
    slave.freeInstance()
    return dict(zip(OUTPUTS, np.array(rows).T, strict=True))


def model_exchange_every_evaluation(unzipped: Path, h: float) -> dict[str, np.ndarray]:
    """fmpy's CVode at its defaults (relative tolerance 1e-4, max step STOP / 50), x_cmd(t)
    set at every right-hand-side evaluation; outputs every h."""
    md = read_model_description(str(unzipped))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    model = FMU2Model(guid=md.guid, unzipDirectory=str(unzipped),
                      modelIdentifier=md.modelExchange.modelIdentifier, instanceName="me")
    model.instantiate()
    model.setupExperiment(startTime=0.0)
    model.enterInitializationMode()
    for name, value in START.items():
        model.setReal([refs[name]], [value])
    model.exitInitializationMode()
    model.newDiscreteStates()
    model.enterContinuousTimeMode()

    def set_time(t: float) -> None:
        model.setTime(t)
        model.setReal([refs["x_cmd"]], [float(stroke(np.array(t))[0])])

    solver = CVodeSolver(nx=3, nz=0, get_x=model.getContinuousStates,
                         set_x=model.setContinuousStates, get_dx=model.getDerivatives,
                         get_z=model.getEventIndicators,
                         get_nominals=model.getNominalsOfContinuousStates, set_time=set_time,
                         input=None, startTime=0.0, maxStep=STOP / 50, relativeTolerance=1e-4)
    rows, t = [], 0.0
    for k in range(1, round(STOP / h) + 1):
        _, _, t = solver.step(t, k * h)
        set_time(t)
        model.completedIntegratorStep()
        rows.append(model.getReal([refs[name] for name in OUTPUTS]))
    model.terminate()
    model.freeInstance()
    return dict(zip(OUTPUTS, np.array(rows).T, strict=True))
