"""The closing stroke's time and the motor's duty for the search: a cheap lower bound on
the time to rank by, and the planner's own plan for the duty.

The planner (:mod:`controllers.planner`) finds the true minimum-time stroke, but its
compiled problem is keyed by the linkage's geometry: every candidate of a search would
compile anew (about 10 s) before its 10-20 ms warm solve. The search ranks candidates by
the bound (:func:`close_time_bound`, 5-10 ms); the motor's RMS torque and energy, which a
bound's jerk-free profile gets wrong by up to 20 percentage points against the planner,
come from the planner on a coarser grid, interpreted (:func:`planned_duty`, about 1 s).

The bound is the time-optimal motion of the crosshead along its path in the phase plane
(position, speed): from rest at the open position to rest at the toggle, the speed at
most the drive's top speed, the platen at most the planner's contact speed at mold
contact, the acceleration within the drive's limit and the motor torque
(:func:`toggle.drive.motor_torque` of the plant's input force,
:func:`toggle.plant.plant_outputs`) within the torque-speed curve. The jerk limit and the
planner's creep floor are left out, so no stroke the planner finds is faster. The plant
is linear in the acceleration at a given position and speed, so two vectorised calls on a
(position, speed) grid give every acceleration bound; a forward and a backward sweep over
the positions give the speed profile.
"""

from __future__ import annotations

import numpy as np

from controllers.limits import DriveLimits
from controllers.plans import CONTACT_SPEED, Plan
from toggle.drive import motor_speed, motor_torque
from toggle.plant import PlantConfig, plant_outputs

#: Grid of the bound: positions before and after mold contact, speeds.
APPROACH_POINTS, CLAMP_POINTS, SPEED_POINTS = 160, 40, 24
#: Intervals of the planned strokes whose duty the search weighs (:func:`planned_duty`):
#: on eight SM-55 designs the stroke's RMS torque 0.4-1.0 % below the planner's default
#: 200, the cycle's 0.3-0.7 %, the designs' changes against the SM-55 within 0.6
#: percentage points (benchmarks/bench_design_duty.py); both strokes in 1.35-1.45 s on an
#: idle core, where one stroke at 200 takes 4.2 s.
DUTY_INTERVALS = 40


class StallError(ValueError):
    """The motor cannot move the crosshead at some position (the bound is infinite)."""


def _accelerations(cfg: PlantConfig, limits: DriveLimits, xs: np.ndarray, vs: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Largest and smallest crosshead acceleration on the grid xs x vs, m/s^2."""
    drive = cfg.mechanism.drive
    X, V = np.meshgrid(xs, vs, indexing="ij")
    torque = [np.asarray(motor_torque(plant_outputs(X, V, a, cfg).input_force, drive, a),
                         dtype=float) for a in (0.0, 1.0)]
    per_accel = torque[1] - torque[0]  # the torque is affine in a
    usable = np.asarray(limits.torque_at(motor_speed(V, drive)), dtype=float)
    up = np.minimum((usable - torque[0]) / per_accel, limits.acceleration)
    down = np.maximum((-usable - torque[0]) / per_accel, -limits.acceleration)
    return up, down


def _profile(cfg: PlantConfig, limits: DriveLimits, x_open: float, x_final: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """The bound's phase-plane profile: positions (m) and the fastest speeds (m/s) there."""
    x_contact = cfg.x_contact
    xs = np.concatenate([np.linspace(x_open, x_contact, APPROACH_POINTS),
                         np.linspace(x_contact, x_final, CLAMP_POINTS + 1)[1:]])
    vs = np.linspace(0.0, limits.velocity, SPEED_POINTS)
    up, down = _accelerations(cfg, limits, xs, vs)
    cap = np.full(xs.size, limits.velocity)
    g_contact = float(plant_outputs(x_contact, 1.0, 0.0, cfg.with_(x_contact=None))
                      .platen_velocity)
    cap[APPROACH_POINTS - 1] = min(limits.velocity, CONTACT_SPEED / max(g_contact, 1e-12))
    dx = np.diff(xs)
    v = np.zeros(xs.size)
    for i in range(xs.size - 1):  # accelerate as hard as the motor allows
        a = float(np.interp(v[i], vs, up[i]))
        if a <= 0 and v[i] <= 0:
            raise StallError(f"the motor cannot move the crosshead at x = {xs[i]:.6g} m")
        v[i + 1] = min(cap[i + 1], np.sqrt(max(v[i] ** 2 + 2 * a * dx[i], 0.0)))
    v[-1] = 0.0
    for i in range(xs.size - 2, -1, -1):  # and brake in time for the caps ahead
        a = float(np.interp(v[i + 1], vs, down[i + 1]))
        v[i] = min(v[i], np.sqrt(max(v[i + 1] ** 2 - 2 * a * dx[i], 0.0)))
    mean = 0.5 * (v[:-1] + v[1:])
    if np.any(mean <= 0):
        i = int(np.argmax(mean <= 0))
        raise StallError(f"the motor cannot move the crosshead at x = {xs[i]:.6g} m")
    return xs, v


def close_time_bound(cfg: PlantConfig, limits: DriveLimits, x_open: float, x_final: float
                     ) -> float:
    """Lower bound on the closing stroke's duration from rest at ``x_open`` to rest at
    ``x_final`` with the mold of ``cfg`` (its ``x_contact``), s."""
    xs, v = _profile(cfg, limits, x_open, x_final)
    return float(np.sum(np.diff(xs) / (0.5 * (v[:-1] + v[1:]))))


def fastest_stroke(cfg: PlantConfig, limits: DriveLimits, opening: bool = False,
                   intervals: int = DUTY_INTERVALS) -> Plan:
    """The minimum-time closing (or opening) stroke on ``intervals`` intervals, on a problem
    of its own, interpreted: started cold whatever the process planned before (a
    record replays), and out of :func:`controllers.stroke_problem.problem_for`'s cache of
    the problems that are planned again."""
    from controllers.planner import ClampPlanner
    from controllers.stroke_problem import StrokeProblem, neutral

    problem = StrokeProblem(neutral(cfg), intervals, opening=opening, machine_code=False)
    return ClampPlanner(cfg, limits, intervals=intervals, problem=problem).minimum_time()


def planned_duty(cfg: PlantConfig, limits: DriveLimits, hold: float, eject: float
                 ) -> dict[str, float]:
    """The motor's duty over the minimum-time closing stroke of ``cfg`` (from rest at its
    clamp's open position to rest at the toggle, under the drive's limits, jerk included)
    and over the molding cycle it starts (:class:`controllers.cycle.MoldingCycle`: that
    stroke, ``hold`` s locked, the minimum-time opening stroke, ``eject`` s open): RMS torque
    (N m), shaft energy without regeneration (J) and duration (s) of each. The planner at
    :data:`DUTY_INTERVALS` intervals with its functions interpreted: a candidate is planned
    once, so a compile (10-30 s) would cost more than the solve; each plan starts cold, so a
    design's duty does not depend on what the process planned before. PlanningError where
    the planner finds no stroke."""
    from controllers.cycle import MoldingCycle
    from controllers.duty import motor_duty

    closing = fastest_stroke(cfg, limits)
    s = closing.samples
    close = motor_duty(s.time, s.velocity, s.acceleration, s.input_force, cfg.mechanism.drive)
    cycle = MoldingCycle(closing, fastest_stroke(cfg, limits, opening=True), hold, eject).duty()
    return {"close_rms_torque": close.rms_torque,
            "close_energy": close.shaft_energy_without_regeneration,
            "close_plan_time": close.cycle_time,
            "cycle_rms_torque": cycle.rms_torque,
            "cycle_energy": cycle.shaft_energy_without_regeneration,
            "cycle_time": cycle.cycle_time}
