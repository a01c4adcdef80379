"""Drive limits of the crosshead motion, from a preset's [drive] data.

The presets give the ball screw, the belt ratio and either the stepper's
resolution (chang2021) or the servo's rated torque and speed (SM-55); the
planner needs limits on crosshead velocity, acceleration, jerk and motor
torque. Where the preset is silent the defaults below are stated assumptions:

* velocity: the servo's rated speed, or the stepper's maximum step rate
  (``STEP_RATE``, a typical 200 kHz pulse input of a microstepping driver)
  over its steps per turn, times the screw travel per turn (R * lead);
* acceleration: the top speed reached in ``ACCEL_TIME``; jerk: that
  acceleration reached in ``JERK_TIME``;
* torque: the preset's torque-speed curve (``[drive] torque_speed``); without one,
  flat at ``PEAK_TORQUE_FACTOR`` times the servo's rated torque (servos give
  about three times rated torque for short peaks), or at ``STEPPER_TORQUE`` for a
  stepper, whose preset gives no torque. A torque given here sets the curve's
  standstill value and scales the whole curve.

The torque the motor must deliver is :func:`toggle.drive.motor_torque` (thrust and the
drive's reflected inertia), the limit :meth:`DriveLimits.torque_at` at the motor speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from toggle.drive import drive_data, motor_speed, motor_torque, torque_speed_limit
from toggle.params import Drive, Mechanism, ParameterError, torque_speed_points

STEP_RATE = 200e3  # steps/s, assumption: pulse-input limit of a microstepping driver
ACCEL_TIME = 0.1  # s, assumption: 0 to top speed
JERK_TIME = 0.05  # s, assumption: 0 to full acceleration
PEAK_TORQUE_FACTOR = 3.0  # assumption: servo peak over rated torque
STEPPER_TORQUE = 0.3  # N m, assumption: usable torque of a stepper preset without a curve


@dataclass(frozen=True)
class DriveLimits:
    """Limits on the crosshead motion and the motor's torque.

    Attributes:
        velocity: Crosshead speed limit, m/s.
        acceleration: Crosshead acceleration limit, m/s^2.
        jerk: Crosshead jerk limit, m/s^3.
        torque: Motor torque at standstill, N m.
        torque_speed: The torque-speed curve, (rad/s, N m) points scaled to ``torque`` at
            speed 0; empty: flat.
    """

    velocity: float
    acceleration: float
    jerk: float
    torque: float
    torque_speed: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        for name in ("velocity", "acceleration", "jerk", "torque"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ParameterError(
                    f"drive limit {name} must be a finite number > 0, got {value!r}")
        if self.torque_speed:
            object.__setattr__(self, "torque_speed", torque_speed_points(self.torque_speed))

    @property
    def curve(self) -> tuple[tuple[float, float], ...]:
        """The torque-speed curve's points (rad/s, N m), its standstill torque ``torque``."""
        if not self.torque_speed:
            return ((0.0, self.torque),)
        scale = self.torque / self.torque_speed[0][1]
        return tuple((w, scale * t) for w, t in self.torque_speed)

    def torque_at(self, speed: Any) -> Any:
        """The usable motor torque (N m) at motor speed ``speed`` (rad/s)."""
        speeds, torques = zip(*self.curve)
        return torque_speed_limit(speed, speeds, torques)

    def torque_ratio(self, drive: Drive, velocity: Any, acceleration: Any, force: Any
                     ) -> float:
        """The largest ratio of the motor torque (:func:`toggle.drive.motor_torque`) to the
        usable torque at the motor's speed over samples of crosshead velocity (m/s),
        acceleration (m/s^2) and input force (N): at most 1 within the curve."""
        torque = motor_torque(np.asarray(force), drive, np.asarray(acceleration))
        return float(np.max(np.abs(torque) / self.torque_at(motor_speed(
            np.asarray(velocity), drive))))

    def force(self, drive: Drive) -> float:
        """Largest crosshead thrust the standstill torque holds, N (Eq 32 inverted)."""
        return self.torque / float(motor_torque(1.0, drive))


def max_velocity(drive: Drive, step_rate: float = STEP_RATE) -> float:
    """Top crosshead speed, m/s: rated motor speed, else the stepper's step-rate limit."""
    if drive.rated_speed is not None:
        return drive.rated_speed / float(motor_speed(1.0, drive))
    return step_rate / drive.pulses_per_rev * drive.ratio * drive.lead


def drive_limits(
    mech: Mechanism,
    *,
    velocity: float | None = None,
    acceleration: float | None = None,
    jerk: float | None = None,
    torque: float | None = None,
) -> DriveLimits:
    """The preset's drive limits; any argument given overrides the derived value."""
    drive = drive_data(mech)
    v = max_velocity(drive) if velocity is None else velocity
    a = v / ACCEL_TIME if acceleration is None else acceleration
    j = a / JERK_TIME if jerk is None else jerk
    curve = drive.torque_speed or ()
    if torque is None:
        torque = (curve[0][1] if curve else PEAK_TORQUE_FACTOR * drive.rated_torque
                  if drive.rated_torque is not None else STEPPER_TORQUE)
    return DriveLimits(velocity=v, acceleration=a, jerk=j, torque=torque, torque_speed=curve)
