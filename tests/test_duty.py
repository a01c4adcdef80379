"""The motor's duty (controllers.duty): RMS and peak torque, energy with and without
regeneration, and the refusal of a motor too small for the cycle's RMS torque."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from controllers.duty import DutyError, check_motor, motor_duty
from controllers.limits import drive_limits
from toggle.drive import motor_torque, travel_per_radian
from toggle.params import load_preset

MECH = load_preset("chang2021")
DRIVE = MECH.drive


def test_a_constant_thrust_at_constant_speed_is_its_torque_and_power():
    """At constant speed v and thrust F the RMS and peak torque are Eq 32's, and the shaft
    energy is F v t / eta with or without regeneration (the motor never brakes)."""
    t = np.linspace(0.0, 2.0, 2001)
    v, force = 0.02, 10.0
    duty = motor_duty(t, np.full(t.size, v), 0 * t, np.full(t.size, force), DRIVE)
    torque = float(motor_torque(force, DRIVE))
    assert duty.rms_torque == pytest.approx(torque) and duty.peak_torque == pytest.approx(torque)
    assert duty.peak_speed == pytest.approx(v / travel_per_radian(DRIVE))
    assert duty.energy_regenerating == pytest.approx(force * v * 2.0 / DRIVE.efficiency)
    assert duty.energy_without_regeneration == pytest.approx(duty.energy_regenerating)
    assert duty.torque_squared == pytest.approx(torque**2 * 2.0)


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
    assert duty.energy_regenerating <= duty.energy_without_regeneration + 1e-12
    assert duty.energy_without_regeneration >= 0.0
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
