"""Servo drive of the crosshead: belt and ball screw (Lin & Hsiao 2003, Eqs 31-32).

One motor turn moves the crosshead by R * lead (R: velocity ratio of the driven
to the driver gear), so

* Eq 31: U_E = (N / N_s) R lead (encoder pulses N, N_s per motor turn);
* Eq 32: T_m = F0 R lead / (2 pi eta) (motor torque for crosshead thrust F0).

As in the paper, the encoder's zero is the final clamping position and the
pulses count the crosshead travel U_E of Eq 8 (:func:`toggle.elastics.crosshead_travel`).
Deceleration torque and inertia are neglected, as there.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import brentq

from toggle.elastics import (
    ClampingError,
    ClampingResult,
    clamp_state,
    clamp_stroke,
    crosshead_travel,
)
from toggle.params import Drive, Mechanism


def drive_data(mech: Mechanism) -> Drive:
    """The preset's [drive] section, or a clear error if it has none."""
    if mech.drive is None:
        raise ClampingError(f"preset {mech.name!r} has no [drive] section")
    return mech.drive


def travel_per_radian(drive: Drive) -> float:
    """Crosshead travel per radian of the motor, m/rad."""
    return drive.ratio * drive.lead / (2.0 * math.pi)


def motor_torque(thrust: Any, drive: Drive) -> Any:
    """Motor torque T_m (N m) for crosshead thrust F0 (N), Eq 32."""
    return thrust * travel_per_radian(drive) / drive.efficiency


def motor_speed(crosshead_speed: Any, drive: Drive) -> Any:
    """Motor speed (rad/s) for a crosshead speed (m/s), from Eq 31."""
    return crosshead_speed / travel_per_radian(drive)


def encoder_pulses(travel: Any, drive: Drive) -> Any:
    """Encoder pulses counted over a crosshead travel (m), Eq 31."""
    return travel / (drive.ratio * drive.lead) * drive.pulses_per_rev


def travel_from_pulses(pulses: Any, drive: Drive) -> Any:
    """Crosshead travel (m) from encoder pulses, Eq 31."""
    return pulses / drive.pulses_per_rev * drive.ratio * drive.lead


def contact_from_pulses(mech: Mechanism, pulses: float, *, half: str = "lower") -> float:
    """Mold-contact crosshead position from the pulses N_c counted from contact to
    the final position (Eqs 8 and 31, as the paper's experiments give alpha_C)."""
    dims = mech.half(half)
    x_open, x_final = clamp_stroke(mech, half)
    travel = float(travel_from_pulses(pulses, drive_data(mech)))
    longest = float(crosshead_travel(x_final, x_open, dims))
    if not (0 < travel < longest):
        raise ClampingError(
            f"{pulses} pulses are {travel * 1e3:.4g} mm of crosshead travel, outside the stroke "
            f"(0, {longest * 1e3:.4g}) mm"
        )
    return float(brentq(lambda v: float(crosshead_travel(x_final, v, dims)) - travel,
                        x_open, x_final, xtol=1e-15))


class TorqueHistory(NamedTuple):
    """Motor torque against time during real-mold clamping (arrays, SI)."""

    t: np.ndarray
    crosshead_travel: np.ndarray
    x: np.ndarray
    thrust: np.ndarray
    torque: np.ndarray


def torque_history(
    mech: Mechanism, result: ClampingResult, t: Any, speed: Any, *, half: str = "lower"
) -> TorqueHistory:
    """Motor torque for a motor-speed profile ``speed`` (rad/s at times ``t``, s,
    t[0] = mold contact), as in the paper's Figs 8-11.

    The crosshead travel is the integral of the speed (Eq 31), capped at the final
    position; until then friction is kinetic (``result.mu``), afterwards the thrust
    holds with static friction (``result.hold``, mu_s = static_factor * mu).
    """
    drive = drive_data(mech)
    dims = mech.half(half)
    t = np.asarray(t, dtype=float)
    speed = np.broadcast_to(np.asarray(speed, dtype=float), t.shape)
    if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0):
        raise ValueError("t must be an increasing 1-D array of at least two times")
    if np.any(speed < 0):
        raise ValueError("the motor-speed profile must be non-negative during clamping")
    angle = np.concatenate(([0.0], np.cumsum(np.diff(t) * (speed[1:] + speed[:-1]) / 2)))
    travel = np.minimum(angle * travel_per_radian(drive), result.crosshead_travel)
    # invert U_E(x) (monotone) on a fine grid: U_E = x - x_C - S_bar, nearly linear in x
    grid = np.linspace(result.x_contact, result.x_final, 4001)
    x = np.interp(travel, np.asarray(crosshead_travel(grid, result.x_contact, dims)), grid)
    moving = travel < result.crosshead_travel
    thrust = np.where(
        moving,
        np.asarray(clamp_state(x, result.x_contact, mech, result.mu, half=half).thrust),
        result.hold.thrust,
    )
    return TorqueHistory(t, travel, x, thrust, np.asarray(motor_torque(thrust, drive)))
