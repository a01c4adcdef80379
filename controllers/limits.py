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
* torque: ``PEAK_TORQUE_FACTOR`` times the servo's rated torque (servos give
  about three times rated torque for short peaks), or ``STEPPER_TORQUE`` for a
  stepper, whose preset gives no torque.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from toggle.drive import drive_data, motor_speed, motor_torque
from toggle.params import Drive, Mechanism, ParameterError

STEP_RATE = 200e3  # steps/s, assumption: pulse-input limit of a microstepping driver
ACCEL_TIME = 0.1  # s, assumption: 0 to top speed
JERK_TIME = 0.05  # s, assumption: 0 to full acceleration
PEAK_TORQUE_FACTOR = 3.0  # assumption: servo peak over rated torque
STEPPER_TORQUE = 0.3  # N m, assumption: usable pull-out torque of the desktop rig's stepper


@dataclass(frozen=True)
class DriveLimits:
    """Limits on the crosshead motion: m/s, m/s^2, m/s^3 and motor torque, N m."""

    velocity: float
    acceleration: float
    jerk: float
    torque: float

    def __post_init__(self) -> None:
        for name in ("velocity", "acceleration", "jerk", "torque"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ParameterError(
                    f"drive limit {name} must be a finite number > 0, got {value!r}")

    def force(self, drive: Drive) -> float:
        """Largest crosshead thrust the torque limit allows, N (Eq 32 inverted)."""
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
    if torque is None:
        torque = (PEAK_TORQUE_FACTOR * drive.rated_torque if drive.rated_torque is not None
                  else STEPPER_TORQUE)
    return DriveLimits(velocity=v, acceleration=a, jerk=j, torque=torque)
