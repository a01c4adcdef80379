"""A cheap lower bound on the closing time under the motor's limits, for the search.

The planner (:mod:`controllers.planner`) finds the true minimum-time stroke, but its
compiled problem is keyed by the linkage's geometry: every candidate of a search would
compile anew (about 10 s) before its 10-20 ms warm solve. The search ranks candidates by
this bound instead and the planner checks the final designs (docs/design.md).

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
from controllers.plans import CONTACT_SPEED
from toggle.drive import motor_speed, motor_torque
from toggle.plant import PlantConfig, plant_outputs

#: Grid of the bound: positions before and after mold contact, speeds.
APPROACH_POINTS, CLAMP_POINTS, SPEED_POINTS = 160, 40, 24


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


def close_duty(cfg: PlantConfig, limits: DriveLimits, x_open: float, x_final: float
               ) -> dict[str, float]:
    """The bound's duration and the motor's RMS torque (N m) and energy without
    regeneration (J) along its profile: a fast estimate of the minimum-time plan's (the
    planner adds the jerk limit; docs/design.md compares the two)."""
    xs, v = _profile(cfg, limits, x_open, x_final)
    dx = np.diff(xs)
    dt = dx / (0.5 * (v[:-1] + v[1:]))
    a = np.diff(v) / dt  # constant on each interval
    x_mid, v_mid = 0.5 * (xs[:-1] + xs[1:]), 0.5 * (v[:-1] + v[1:])
    drive = cfg.mechanism.drive
    torque = np.asarray(motor_torque(plant_outputs(x_mid, v_mid, a, cfg).input_force, drive,
                                     a), dtype=float)
    power = np.maximum(torque * np.asarray(motor_speed(v_mid, drive), dtype=float), 0.0)
    duration = float(np.sum(dt))
    return {"close_time": duration,
            "close_rms_torque": float(np.sqrt(np.sum(torque ** 2 * dt) / duration)),
            "close_energy": float(np.sum(power * dt))}
