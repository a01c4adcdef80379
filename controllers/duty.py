"""The motor's duty over a cycle: torque and speed, RMS and peak torque, the electrical
energy, the braking energy and what absorbs it, the winding's temperature rise.

A machine builder sizes the motor by its RMS torque over the whole cycle, dwells
included, and by the winding's temperature over repeated cycles (it heats with the square
of the current, the current follows the torque); by its peak torque and speed against the
torque-speed curve; the drive's brake resistor or DC-bus capacitance by the power and
energy the motor regenerates; and compares cycles by their energy. The model, stated:

* motor torque T_m = p (F k + m_drive a) with k by the direction of power flow
  (:func:`toggle.drive.flow_torque`: 1/eta while the motor drives the load, F v > 0,
  the back-driving efficiency eta' while the load drives the motor and at rest), speed
  omega = v / p, on the cycle's samples; in a dwell the crosshead rests and T_m holds
  the input force the plant needs there;
* RMS torque sqrt(integral T_m^2 dt / cycle time) (trapezoidal rule, as every integral);
* shaft power T_m omega; copper losses P_cu = phases R (T_m / k_t)^2
  (:func:`toggle.drive.copper_loss`); electrical power P = T_m omega + P_cu, what the
  drive's DC bus gives the motor (the inverter's own losses are left out);
* energy per cycle with regeneration: integral P dt (the braking energy, P < 0, returns
  to the bus and is used again); without: integral max(P, 0) dt (it is burnt);
* braking: the peak regenerative power max(-P) and the energy of the largest braking
  event (one stretch of P < 0). A brake resistor takes the peak at the chopper's voltage
  if its resistance is at most V_brake^2 / max(-P), and must dissipate the braking
  energy per cycle over the cycle time continuously; the DC bus alone absorbs the largest
  event if its capacitance is at least 2 E / (V_brake^2 - V_bus^2);
* the winding's temperature rise: first order, C dtheta/dt = P_cu - theta / R_th with the
  time constant tau = R_th C of the preset and R_th = rated rise / P_cu at the rated
  torque; over repeated cycles it tends to the periodic solution (reported: its peak and
  mean, the first cycle's peak, the cycles to 95 % of it).

The planner's ``"energy"`` objective minimises integral P dt of a stroke
(:mod:`controllers.stroke_problem`, with the direction switch smoothed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controllers.limits import DriveLimits
from toggle.drive import copper_coefficient, flow_torque, motor_speed
from toggle.params import Drive

#: The periodic temperature counts as reached at this fraction of it.
_SETTLED = 0.95


class DutyError(ValueError):
    """A motor too small for the cycle (the message says by how much)."""


def _integral(t: np.ndarray, y: np.ndarray) -> float:
    """Trapezoidal integral of samples y(t)."""
    return float(np.sum(np.diff(t) * (y[1:] + y[:-1]) / 2))


def _largest_event(t: np.ndarray, power: np.ndarray) -> float:
    """The energy of the largest stretch of negative power (a braking event), J >= 0:
    integral of max(-P, 0) between the samples where P turns negative and back."""
    braking = np.maximum(-power, 0.0)
    pieces = np.diff(t) * (braking[1:] + braking[:-1]) / 2  # per interval
    inside = (braking[1:] > 0) | (braking[:-1] > 0)
    largest = current = 0.0
    for piece, on in zip(pieces, inside):
        current = current + piece if on else 0.0
        largest = max(largest, current)
    return float(largest)


def _temperature(t: np.ndarray, loss: np.ndarray, tau: float, resistance: float,
                 start: float) -> np.ndarray:
    """The first-order winding temperature rise (K) over the samples from ``start``, the
    loss held at each interval's mean (exact for the first-order model)."""
    decay = np.exp(-np.diff(t) / tau)
    drive = resistance * (loss[1:] + loss[:-1]) / 2 * (1 - decay)
    theta = np.empty(t.size)
    theta[0] = start
    for k in range(t.size - 1):
        theta[k + 1] = theta[k] * decay[k] + drive[k]
    return theta


@dataclass(frozen=True)
class Duty:
    """The motor over one cycle (SI): samples of time (s), torque (N m), speed (rad/s), and
    the drive they are of (its electrical and thermal data, where the preset gives them)."""

    time: np.ndarray
    torque: np.ndarray
    speed: np.ndarray
    drive: Drive = field(repr=False)

    @property
    def cycle_time(self) -> float:
        return float(self.time[-1] - self.time[0])

    @property
    def torque_squared(self) -> float:
        """Integral of T_m^2 over the cycle, N^2 m^2 s (copper losses over phases R / k_t^2)."""
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
    def shaft_power(self) -> np.ndarray:
        """T_m omega at the samples, W."""
        return self.torque * self.speed

    @property
    def copper_loss(self) -> np.ndarray | None:
        """The copper losses at the samples, W (None: no winding data)."""
        c = copper_coefficient(self.drive)
        return None if c is None else c * self.torque**2

    @property
    def electrical_power(self) -> np.ndarray | None:
        """The power the DC bus gives the motor at the samples, W (negative: regenerated);
        None without winding data."""
        loss = self.copper_loss
        return None if loss is None else self.shaft_power + loss

    @property
    def shaft_energy_regenerating(self) -> float:
        """Shaft energy per cycle with regeneration, J."""
        return _integral(self.time, self.shaft_power)

    @property
    def shaft_energy_without_regeneration(self) -> float:
        """Shaft energy per cycle with the braking energy burnt, J."""
        return _integral(self.time, np.maximum(self.shaft_power, 0.0))

    def electrical(self) -> dict[str, float | None] | None:
        """The electrical figures per cycle (SI), None without winding data: energy with
        and without regeneration, copper losses, braking power and energy, and what absorbs
        it (brake resistor, DC-bus capacitance; None where the bus voltages are unknown)."""
        power = self.electrical_power
        if power is None:
            return None
        d, t = self.drive, self.time
        braking = _integral(t, np.maximum(-power, 0.0))
        peak = float(np.max(np.maximum(-power, 0.0)))
        event = _largest_event(t, power)
        voltages = None not in (d.bus_voltage, d.brake_voltage)
        return {
            "energy_regenerating": _integral(t, power),
            "energy_without_regeneration": _integral(t, np.maximum(power, 0.0)),
            "copper_loss_energy": _integral(t, self.copper_loss),
            "copper_loss_mean": _integral(t, self.copper_loss) / self.cycle_time,
            "peak_power": float(np.max(power)),
            "peak_regenerative_power": peak,
            "braking_energy": braking,
            "largest_braking_event": event,
            "brake_resistor_max": (d.brake_voltage**2 / peak
                                   if d.brake_voltage is not None and peak > 0 else None),
            "brake_resistor_power": braking / self.cycle_time,
            "bus_capacitance": (2 * event / (d.brake_voltage**2 - d.bus_voltage**2)
                                if voltages else None),
        }

    def thermal(self) -> dict[str, float] | None:
        """The winding's temperature rise over repeated cycles (K, s, cycles), None without
        the thermal data (winding, rated torque and rise, time constant)."""
        d, loss = self.drive, self.copper_loss
        if loss is None or None in (d.rated_torque, d.rated_temperature_rise,
                                    d.thermal_time_constant):
            return None
        resistance = d.rated_temperature_rise / float(copper_coefficient(d) * d.rated_torque**2)
        tau, t = d.thermal_time_constant, self.time
        first = _temperature(t, loss, tau, resistance, 0.0)
        periodic = first[-1] / (1 - math.exp(-self.cycle_time / tau))
        steady = _temperature(t, loss, tau, resistance, periodic)
        return {
            "thermal_resistance": resistance,
            "time_constant": tau,
            "rise_first_cycle": float(np.max(first)),
            "rise_periodic_peak": float(np.max(steady)),
            "rise_periodic_mean": resistance * _integral(t, loss) / self.cycle_time,
            "rated_rise": d.rated_temperature_rise,
            "cycles_to_settle": math.ceil(-math.log(1 - _SETTLED) * tau / self.cycle_time),
        }

    def report(self) -> dict[str, object]:
        """The figures a machine builder compares, SI (the electrical ones None without the
        drive's winding data)."""
        electrical = self.electrical()
        figures = electrical or {}
        return {"cycle_time": self.cycle_time, "rms_torque": self.rms_torque,
                "peak_torque": self.peak_torque, "peak_speed": self.peak_speed,
                "energy_regenerating": figures.get("energy_regenerating"),
                "energy_without_regeneration": figures.get("energy_without_regeneration"),
                "shaft_energy_regenerating": self.shaft_energy_regenerating,
                "shaft_energy_without_regeneration": self.shaft_energy_without_regeneration,
                "torque_squared_integral": self.torque_squared,
                "electrical": electrical, "thermal": self.thermal()}


def motor_duty(time: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray,
               input_force: np.ndarray, drive: Drive) -> Duty:
    """The motor's torque and speed on samples of the crosshead's motion and input force."""
    velocity = np.asarray(velocity, float)
    return Duty(np.asarray(time, float),
                np.asarray(flow_torque(input_force, velocity, drive,
                                       np.asarray(acceleration, float)), float),
                np.asarray(motor_speed(velocity, drive), float), drive)


def check_motor(duty: Duty, drive: Drive, limits: DriveLimits,
                rated_torque: float | None = None) -> dict[str, float | None]:
    """The duty against the motor's ratings: RMS torque against the rated (continuous)
    torque (``rated_torque``, default the preset's [drive] ``rated_torque``), the winding's
    periodic peak temperature rise against its rated rise, peak torque and speed against
    the torque-speed curve. Raises :class:`DutyError` naming by how much the RMS torque
    (or the temperature rise) exceeds the rating; returns the ratios (None: no rating)."""
    rated = drive.rated_torque if rated_torque is None else rated_torque
    if rated is not None and duty.rms_torque > rated:
        raise DutyError(
            f"the motor is too small for this cycle: its RMS torque {duty.rms_torque:.4g} N m "
            f"exceeds the rated (continuous) torque {rated:.4g} N m by "
            f"{duty.rms_torque - rated:.4g} N m ({100 * (duty.rms_torque / rated - 1):.1f} %)")
    thermal = duty.thermal() if rated_torque is None else None  # R_th from the preset's rating
    heat = None if thermal is None else thermal["rise_periodic_peak"] / thermal["rated_rise"]
    if heat is not None and heat > 1:
        raise DutyError(
            f"the motor is too small for this cycle: over repeated cycles its winding rises "
            f"{thermal['rise_periodic_peak']:.4g} K above ambient at the cycle's peak, "
            f"{100 * (heat - 1):.1f} % above its rated rise {thermal['rated_rise']:.4g} K")
    curve = np.abs(duty.torque) / limits.torque_at(duty.speed)
    return {"rms_over_rated": None if rated is None else duty.rms_torque / rated,
            "rated_torque": rated,
            "temperature_rise_over_rated": heat,
            "peak_over_curve": float(np.max(curve)),
            "peak_speed_over_rated": (None if drive.rated_speed is None
                                      else duty.peak_speed / drive.rated_speed)}
