"""The motor's duty (controllers.duty): RMS and peak torque, shaft and electrical energy
with and without regeneration (the screw's efficiency by the direction of power flow),
braking power and its resistor, the winding's temperature over repeated cycles, and the
refusal of a motor too small for the cycle; the SM-55 molding cycle's energy against an
integration of its samples with the drive data alone."""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from controllers.duty import DutyError, check_motor, motor_duty
from controllers.limits import drive_limits
from controllers.profiles import read_profile_csv
from toggle.drive import motor_torque, travel_per_radian
from toggle.params import load_preset
from toggle_cli import main

MECH = load_preset("chang2021")
DRIVE = MECH.drive


def test_a_constant_thrust_at_constant_speed_is_its_torque_and_power():
    """At constant speed v and thrust F the RMS and peak torque are Eq 32's, and the shaft
    energy is F v t / eta with or without regeneration (the motor never brakes); the
    electrical energy adds the copper losses phases R (T / k_t)^2 t."""
    t = np.linspace(0.0, 2.0, 2001)
    v, force = 0.02, 10.0
    duty = motor_duty(t, np.full(t.size, v), 0 * t, np.full(t.size, force), DRIVE)
    torque = float(motor_torque(force, DRIVE))
    assert duty.rms_torque == pytest.approx(torque) and duty.peak_torque == pytest.approx(torque)
    assert duty.peak_speed == pytest.approx(v / travel_per_radian(DRIVE))
    assert duty.shaft_energy_regenerating == pytest.approx(force * v * 2.0 / DRIVE.efficiency)
    assert duty.shaft_energy_without_regeneration == pytest.approx(
        duty.shaft_energy_regenerating)
    assert duty.torque_squared == pytest.approx(torque**2 * 2.0)
    copper = DRIVE.phases * DRIVE.winding_resistance * (torque / DRIVE.torque_constant)**2
    electrical = duty.electrical()
    assert electrical["energy_regenerating"] == pytest.approx(
        duty.shaft_energy_regenerating + copper * 2.0)
    assert electrical["peak_regenerative_power"] == 0.0
    assert electrical["brake_resistor_max"] is None


def test_a_dwell_lowers_the_rms_torque_by_the_root_of_the_duty_factor():
    """The same stroke followed by a dwell at no torque as long again: RMS / sqrt(2)."""
    t = np.linspace(0.0, 1.0, 1001)
    move = motor_duty(t, np.full(t.size, 0.01), 0 * t, np.full(t.size, 5.0), DRIVE)
    t2 = np.linspace(0.0, 2.0, 2001)
    force = np.where(t2 <= 1.0, 5.0, 0.0)
    force[1001] = 0.0  # the step falls between samples 1000 and 1001
    cycle = motor_duty(t2, np.where(t2 <= 1.0, 0.01, 0.0), 0 * t2, force, DRIVE)
    assert cycle.rms_torque == pytest.approx(move.rms_torque / math.sqrt(2), rel=2e-3)


@settings(max_examples=50, deadline=None)
@given(arrays(float, 50, elements=st.floats(-1.0, 1.0)),
       arrays(float, 50, elements=st.floats(-50.0, 50.0)),
       arrays(float, 50, elements=st.floats(-2.0, 2.0)))
def test_regeneration_never_costs_energy_and_rms_stays_below_peak(v, force, a):
    duty = motor_duty(np.linspace(0.0, 1.0, 50), v, a, force, DRIVE)
    assert duty.shaft_energy_regenerating <= duty.shaft_energy_without_regeneration + 1e-12
    assert duty.shaft_energy_without_regeneration >= 0.0
    e = duty.electrical()
    assert e["energy_regenerating"] <= e["energy_without_regeneration"] + 1e-12
    assert e["energy_regenerating"] >= duty.shaft_energy_regenerating - 1e-12  # copper
    assert e["largest_braking_event"] <= e["braking_energy"] + 1e-12
    assert duty.rms_torque <= duty.peak_torque * (1 + 1e-12)


def test_a_motor_too_small_for_the_rms_torque_is_refused_by_how_much():
    t = np.linspace(0.0, 1.0, 101)
    duty = motor_duty(t, 0 * t, 0 * t, np.full(t.size, 100.0), DRIVE)
    limits = drive_limits(MECH)
    rms = duty.rms_torque
    with pytest.raises(DutyError, match=f"exceeds the rated .* by {rms - rms / 2:.4g} N m "
                                        r"\(100.0 %\)"):
        check_motor(duty, DRIVE, limits, rated_torque=rms / 2)
    fits = check_motor(duty, DRIVE, limits, rated_torque=2 * rms)
    assert fits["rms_over_rated"] == pytest.approx(0.5)
    assert check_motor(duty, DRIVE, limits)["rated_torque"] == DRIVE.rated_torque


def test_the_winding_heats_to_the_rated_rise_at_the_rated_torque():
    """Held at the rated torque for many time constants the winding rises by its rated
    rise (R_th is defined so); over one cycle repeated, the periodic peak lies above the
    first cycle's and its mean, the mean is R_th times the mean loss; a cycle within the
    RMS rating whose long peak heats the winding past its rated rise is refused."""
    rated, tau = DRIVE.rated_torque, DRIVE.thermal_time_constant
    # at rest the motor holds the thrust through eta' (T = p F eta')
    force = rated / (float(motor_torque(1.0, DRIVE)) * DRIVE.efficiency * DRIVE.back_efficiency)
    t = np.linspace(0.0, 20 * tau, 20001)
    held = motor_duty(t, 0 * t, 0 * t, np.full(t.size, force), DRIVE)
    assert held.peak_torque == pytest.approx(rated)
    thermal = held.thermal()
    assert thermal["rise_first_cycle"] == pytest.approx(DRIVE.rated_temperature_rise, rel=1e-6)
    assert thermal["rise_periodic_mean"] == pytest.approx(DRIVE.rated_temperature_rise)
    t = np.linspace(0.0, 2 * tau, 2001)
    pulse = np.where(t < tau, 1.3 * force, 0.0)  # RMS 1.3 / sqrt(2) of the rated torque
    duty = motor_duty(t, 0 * t, 0 * t, pulse, DRIVE)
    cycle = duty.thermal()
    assert cycle["rise_first_cycle"] < cycle["rise_periodic_peak"]
    assert cycle["rise_periodic_mean"] < cycle["rise_periodic_peak"]
    # the periodic peak of a first-order winding heated at 1.69 x the rated loss for tau
    # and cooled for tau: 1.69 (1 - 1/e) / (1 - 1/e^2) of the rated rise
    assert cycle["rise_periodic_peak"] == pytest.approx(
        DRIVE.rated_temperature_rise * 1.69 * (1 - math.exp(-1)) / (1 - math.exp(-2)),
        rel=2e-3)
    assert cycle["cycles_to_settle"] == math.ceil(math.log(20) / 2)
    assert duty.rms_torque < rated
    with pytest.raises(DutyError, match="winding rises .* above its rated rise"):
        check_motor(duty, DRIVE, drive_limits(MECH))


#: The SM-55 molding cycle of docs/planning-drive.md: an 8 s hold, a 1.5 s ejection.
SM55_CYCLE = ["plan", "--preset", "lin2003_sm55", "--cycle", "--hold", "8", "--eject", "1.5"]


@pytest.fixture(scope="module")
def sm55_cycle(tmp_path_factory):
    """``toggle plan --preset lin2003_sm55 --cycle``: the cycle's samples (CSV) and report."""
    out = tmp_path_factory.mktemp("sm55") / "cycle.csv"
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        assert main([*SM55_CYCLE, "--cycle-out", str(out), "--json"]) == 0
    return read_profile_csv(out), json.loads(printed.getvalue())["molding_cycle"]


def _trapezoid(t: np.ndarray, y: np.ndarray) -> float:
    return float(np.sum(np.diff(t) * (y[1:] + y[:-1]) / 2))


def test_the_sm55_cycles_energy_is_the_plans_samples_through_the_drive_data(sm55_cycle):
    """The molding cycle's electrical energy (and its braking figures) against an
    integration of the cycle's samples (the CSV the command writes) with the preset's
    [drive] numbers alone, not controllers.duty nor toggle.drive: torque p (F k + m a), k
    1/eta where F v > 0 else eta', power T omega + phases R (T / k_t)^2. Within 1 %; and
    the two efficiencies both count (1/eta throughout is more than 1 % off)."""
    s, molding = sm55_cycle
    d = load_preset("lin2003_sm55").drive
    p = d.ratio * d.lead / (2 * math.pi)
    m = (d.rotor_inertia + d.ratio**2 * d.screw_inertia) / p**2
    F, v, a, t = s.input_force, s.velocity, s.acceleration, s.time
    forward = F * v > 0
    assert forward.any() and (F * v < 0).any()  # the cycle both drives and back-drives

    def power(k: np.ndarray) -> np.ndarray:
        T = p * (F * k + m * a)
        return T * v / p + d.phases * d.winding_resistance * (T / d.torque_constant) ** 2

    P = power(np.where(forward, 1 / d.efficiency, d.back_efficiency))
    e = molding["electrical"]
    assert e["energy_regenerating"] == pytest.approx(_trapezoid(t, P), rel=0.01)
    assert e["energy_without_regeneration"] == pytest.approx(
        _trapezoid(t, np.maximum(P, 0)), rel=0.01)
    assert e["peak_regenerative_power"] == pytest.approx(float(np.max(-P)), rel=0.01)
    assert e["brake_resistor_max"] == pytest.approx(d.brake_voltage**2 / np.max(-P), rel=0.01)
    assert e["braking_energy"] == pytest.approx(_trapezoid(t, np.maximum(-P, 0)), rel=0.01)
    one_way = _trapezoid(t, power(np.full(t.size, 1 / d.efficiency)))
    assert abs(one_way / e["energy_regenerating"] - 1) > 0.01


def test_the_sm55_cycle_prints_its_brake_resistor(capsys, sm55_cycle):
    """The text report names the brake resistor and the DC-bus capacitance the cycle
    needs, and the winding's temperature over repeated cycles."""
    e = sm55_cycle[1]["electrical"]
    assert main(SM55_CYCLE) == 0
    out = capsys.readouterr().out
    assert f"a brake resistor of at most {e['brake_resistor_max']:.4g} ohm" in out
    assert f"{e['bus_capacitance'] * 1e6:.4g} uF of DC bus" in out
    assert "winding temperature rise over repeated cycles" in out
