"""Servo drive of the crosshead: belt and ball screw (Lin & Hsiao 2003, Eqs 31-32).

One motor turn moves the crosshead by R * lead (R: velocity ratio of the driven
to the driver gear), so

* Eq 31: U_E = (N / N_s) R lead (encoder pulses N, N_s per motor turn);
* Eq 32: T_m = F0 R lead / (2 pi eta) (motor torque for crosshead thrust F0).

As in the paper, the encoder's zero is the final clamping position and the
pulses count the crosshead travel U_E of Eq 8 (:func:`toggle.elastics.crosshead_travel`).

Beyond the paper, the drive's own inertia: the rotor J_m turns at the motor speed
omega = v / p (p = R lead / 2 pi, :func:`travel_per_radian`), the screw J_s at R omega,
so their kinetic energy is that of a mass m_drive = (J_m + R^2 J_s) / p^2 moving with the
crosshead (:func:`reflected_mass`), and the motor torque for crosshead thrust F (the load
cell's input force) and acceleration a is

    T_m = p (F / eta + m_drive a)           (:func:`drive_torque`, Eq 32 at a = 0)

the efficiency applying to the thrust (the screw's and belt's losses), not to the
rotating parts' own inertia. The motor delivers at most its torque-speed curve
(:func:`torque_speed_limit`), a table of the preset (``[drive] torque_speed``); against
it the torque is taken with 1/eta in both directions (the larger torque, on the safe side).

Where the load back-drives the motor (thrust power F v < 0: the clamp's elastic energy
or the masses' kinetic energy flowing back through the screw) the screw's losses reduce
the torque reaching the motor instead of adding to it, so the motor torque is

    T_m = p (F k + m_drive a),  k = 1/eta where F v > 0, else eta'   (:func:`flow_torque`)

with eta' the back-driving efficiency, by default eta' = 2 - 1/eta (:func:`back_efficiency`:
the relation between a ball screw's forward and reverse efficiency that THK's and NSK's
ball-screw catalogues give, from the same friction angle; 0.9 -> 0.889, 0.8 -> 0.75). At
rest (v = 0) the motor holds the load with eta' (the screw's friction helps to hold it).
The motor's copper losses are phases R (T_m / k_t)^2 (:func:`copper_loss`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from toggle.elastics import (
    ClampingError,
    ClampingResult,
    clamp_state,
    clamp_stroke,
    crosshead_travel,
)
from toggle.params import Drive, Mechanism, ParameterError
from toggle.roots import brentq


def drive_data(mech: Mechanism) -> Drive:
    """The preset's [drive] section, or a clear error if it has none."""
    if mech.drive is None:
        raise ClampingError(f"preset {mech.name!r} has no [drive] section")
    return mech.drive


def travel_per_radian(drive: Drive) -> float:
    """Crosshead travel per radian of the motor, m/rad."""
    return drive.ratio * drive.lead / (2.0 * math.pi)


def reflected_mass(drive: Drive) -> Any:
    """The rotor's and the screw's inertia as a mass moving with the crosshead,
    m_drive = (J_m + R^2 J_s) / p^2, kg (p = :func:`travel_per_radian`)."""
    return ((drive.rotor_inertia + drive.ratio**2 * drive.screw_inertia)
            / travel_per_radian(drive)**2)


def drive_torque(thrust: Any, acceleration: Any, travel: Any, efficiency: Any,
                 mass: Any) -> Any:
    """Motor torque T_m = p (F / eta + m_drive a), N m, for crosshead thrust F (N) and
    acceleration a (m/s^2), with travel per radian p (m/rad), efficiency eta and reflected
    drive mass m_drive (kg): the one torque equation, on floats, arrays or CasADi symbols
    (the planner's drive values are symbols of its compiled problem)."""
    return travel * (thrust / efficiency + mass * acceleration)


def back_efficiency(drive: Drive) -> float:
    """The back-driving efficiency eta' of belt and screw: the preset's ``back_efficiency``
    or 2 - 1/eta (THK and NSK ball-screw catalogues); refused where that is not positive
    (eta <= 0.5: the screw would not back-drive, a model this one is not)."""
    if drive.back_efficiency is not None:
        return drive.back_efficiency
    reverse = 2.0 - 1.0 / drive.efficiency
    if reverse <= 0:
        raise ParameterError(f"a drive efficiency of {drive.efficiency:g} gives no back-driving "
                         "efficiency (2 - 1/eta <= 0): give [drive] back_efficiency")
    return reverse


def flow_factor(power: Any, efficiency: Any, reverse: Any, smoothing: Any = None) -> Any:
    """The factor k on the thrust in the motor torque by the direction of power flow:
    1/eta where the thrust power F v is positive (the motor drives the load), eta' (the
    ``reverse`` efficiency) where it is not. With ``smoothing`` (W, or the caller's power
    unit) a tanh blend of the two over that power, for a smooth optimisation problem
    (floats, arrays or CasADi symbols); without it the exact switch (arrays)."""
    if smoothing is None:
        return np.where(np.asarray(power) > 0, 1.0 / efficiency, reverse)
    mean, half = (1.0 / efficiency + reverse) / 2, (1.0 / efficiency - reverse) / 2
    return mean + half * np.tanh(power / smoothing)


def flow_torque(thrust: Any, velocity: Any, drive: Drive, acceleration: Any = 0.0) -> Any:
    """Motor torque T_m = p (F k + m_drive a), N m, with k by the direction of power flow
    (:func:`flow_factor`: 1/eta driving, the back-driving efficiency eta' while the load
    drives the motor and at rest) for crosshead thrust F (N), velocity v (m/s) and
    acceleration a (m/s^2)."""
    thrust = np.asarray(thrust, dtype=float)
    k = flow_factor(thrust * np.asarray(velocity, dtype=float), drive.efficiency,
                    back_efficiency(drive))
    return drive_torque(thrust, acceleration, travel_per_radian(drive), 1.0 / k,
                        reflected_mass(drive))


def copper_coefficient(drive: Drive) -> float | None:
    """c in the copper losses c T_m^2 (W per (N m)^2): phases R / k_t^2; None where the
    preset gives no winding resistance or torque constant."""
    if drive.winding_resistance is None or drive.torque_constant is None:
        return None
    return drive.phases * drive.winding_resistance / drive.torque_constant**2


def copper_loss(torque: Any, drive: Drive) -> Any:
    """The motor's copper losses phases R (T_m / k_t)^2, W, at motor torque T_m (N m)."""
    c = copper_coefficient(drive)
    if c is None:
        raise ParameterError("the drive has no winding_resistance and torque_constant")
    return c * np.asarray(torque) ** 2


def motor_torque(thrust: Any, drive: Drive, acceleration: Any = 0.0) -> Any:
    """Motor torque T_m (N m) for crosshead thrust F0 (N), Eq 32, and the torque that
    accelerates the rotor and the screw at crosshead acceleration ``acceleration`` (m/s^2)."""
    return drive_torque(thrust, acceleration, travel_per_radian(drive), drive.efficiency,
                        reflected_mass(drive))


def torque_speed_limit(speed: Any, speeds: Sequence[Any], torques: Sequence[Any]) -> Any:
    """The torque-speed curve through the points (``speeds`` rad/s, increasing from 0;
    ``torques`` N m) at motor speed ``speed`` (either sign): linear between the points,
    constant beyond the last. Written as a sum of ramps max(|w| - w_k, 0), so that it
    evaluates on floats, arrays and CasADi symbols alike (the points may be symbols)."""
    w = np.fabs(speed)
    limit = torques[0] + 0.0 * w
    slope = 0.0
    for k in range(1, len(speeds)):
        new = (torques[k] - torques[k - 1]) / (speeds[k] - speeds[k - 1])
        limit = limit + (new - slope) * np.maximum(w - speeds[k - 1], 0.0)
        slope = new
    return limit - slope * np.maximum(w - speeds[-1], 0.0)


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
