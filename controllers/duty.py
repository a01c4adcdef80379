"""The motor's duty over a cycle: its torque and speed, RMS and peak torque, energy.

A machine builder sizes the motor by its RMS torque over the whole cycle, dwells
included (its winding heats with the square of the current, the current follows
the torque), by its peak torque and speed against the torque-speed curve, and
compares cycles by their energy. The model, stated:

* motor torque T_m = p (F / eta + m_drive a) (:func:`toggle.drive.motor_torque`, the
  one torque equation: the input force F through belt and screw, the rotor's and
  screw's inertia) and speed omega = v / p, on the cycle's samples; in a dwell the
  crosshead rests and T_m holds the input force the plant needs there;
* RMS torque sqrt(integral T_m^2 dt / cycle time) (trapezoidal rule);
* shaft power P = T_m omega; energy per cycle with regeneration: integral P dt (what
  the motor gives back while braking, P < 0, returns to the drive's DC bus); without
  regeneration: integral max(P, 0) dt (braking energy burnt in a resistor). The screw's
  efficiency is applied in both directions, as the torque equation applies it;
* copper losses: R / k_t^2 times integral T_m^2 dt (winding resistance R, torque
  constant k_t). The presets give neither, so the integral is reported (N^2 m^2 s) and
  the losses are left to the motor's data: the planner's ``"energy"`` objective
  minimises exactly this integral (:mod:`controllers.planner`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.limits import DriveLimits
from toggle.drive import motor_speed, motor_torque
from toggle.params import Drive


class DutyError(ValueError):
    """A motor too small for the cycle (the message says by how much)."""


def _integral(t: np.ndarray, y: np.ndarray) -> float:
    """Trapezoidal integral of samples y(t)."""
    return float(np.sum(np.diff(t) * (y[1:] + y[:-1]) / 2))


@dataclass(frozen=True)
class Duty:
    """The motor over one cycle (SI): samples of time (s), torque (N m), speed (rad/s)."""

    time: np.ndarray
    torque: np.ndarray
    speed: np.ndarray

    @property
    def cycle_time(self) -> float:
        return float(self.time[-1] - self.time[0])

    @property
    def torque_squared(self) -> float:
        """Integral of T_m^2 over the cycle, N^2 m^2 s (copper losses over R / k_t^2)."""
        return _integral(self.time, self.torque**2)

    @property
    def rms_torque(self) -> float:
        return math.sqrt(self.torque_squared / self.cycle_time)

    @property
    def peak_torque(self) -> float:
        return float(np.max(np.abs(self.torque)))

    @property
    def peak_speed(self) -> float:
        return float(np.max(np.abs(self.speed)))

    @property
    def energy_regenerating(self) -> float:
        """Shaft energy per cycle with regeneration, J."""
        return _integral(self.time, self.torque * self.speed)

    @property
    def energy_without_regeneration(self) -> float:
        """Shaft energy per cycle with the braking energy burnt, J."""
        return _integral(self.time, np.maximum(self.torque * self.speed, 0.0))

    def report(self) -> dict[str, float]:
        """The figures a machine builder compares, SI."""
        return {"cycle_time": self.cycle_time, "rms_torque": self.rms_torque,
                "peak_torque": self.peak_torque, "peak_speed": self.peak_speed,
                "energy_regenerating": self.energy_regenerating,
                "energy_without_regeneration": self.energy_without_regeneration,
                "torque_squared_integral": self.torque_squared}


def motor_duty(time: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray,
               input_force: np.ndarray, drive: Drive) -> Duty:
    """The motor's torque and speed on samples of the crosshead's motion and input force."""
    return Duty(np.asarray(time, float),
                np.asarray(motor_torque(np.asarray(input_force), drive,
                                        np.asarray(acceleration)), float),
                np.asarray(motor_speed(np.asarray(velocity), drive), float))


def check_motor(duty: Duty, drive: Drive, limits: DriveLimits,
                rated_torque: float | None = None) -> dict[str, float | None]:
    """The duty against the motor's ratings: RMS torque against the rated (continuous)
    torque (``rated_torque``, default the preset's [drive] ``rated_torque``), peak torque
    and speed against the torque-speed curve. Raises :class:`DutyError` naming by how
    much the RMS torque exceeds the rating; returns the ratios (None: no rating)."""
    rated = drive.rated_torque if rated_torque is None else rated_torque
    if rated is not None and duty.rms_torque > rated:
        raise DutyError(
            f"the motor is too small for this cycle: its RMS torque {duty.rms_torque:.4g} N m "
            f"exceeds the rated (continuous) torque {rated:.4g} N m by "
            f"{duty.rms_torque - rated:.4g} N m ({100 * (duty.rms_torque / rated - 1):.1f} %)")
    curve = np.abs(duty.torque) / limits.torque_at(duty.speed)
    return {"rms_over_rated": None if rated is None else duty.rms_torque / rated,
            "rated_torque": rated,
            "peak_over_curve": float(np.max(curve)),
            "peak_speed_over_rated": (None if drive.rated_speed is None
                                      else duty.peak_speed / drive.rated_speed)}
