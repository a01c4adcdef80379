"""The docs' stroke into the mold and its reference: how close an FMU comes under a master.

docs/fmu.md's accuracy table (written by docs/fmu_accuracy.py) and tests/test_fmu_inputs.py
feed every build the same command u(t), the quintic closing stroke of chang2021 into a mold
1 mm before the toggle with link 8 0.3 mm long and a critically damped 20 Hz drive, and
compare the outputs after each step with :mod:`toggle.plant` stepped at 1e-5 s with the
command's exact derivatives. The steps in-process here are the FMUs' (``toggle.plant``'s
:func:`~toggle.plant.drive_step`, and :func:`~toggle.plant.follow`, the step before issue
39's input change).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

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
    """Per output: (the largest pointwise error, the error of the peak |value|), both over
    the reference's peak |value|; ``got`` after each step of ``h`` (a multiple of EVERY)."""
    stride = round(h / EVERY)
    out = {}
    for name in OUTPUTS:
        want = ref[name][stride - 1::stride]
        have = np.asarray(got[name], dtype=float)[:want.size]
        peak = float(np.abs(want).max())
        out[name] = (float(np.abs(have - want).max() / peak),
                     float(abs(np.abs(have).max() - peak) / peak))
    return out
