"""Ball-screw/belt drive (Lin & Hsiao 2003, Eqs 31-32)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from toggle.drive import (
    contact_from_pulses,
    encoder_pulses,
    motor_speed,
    motor_torque,
    torque_history,
    travel_from_pulses,
)
from toggle.elastics import ClampingError, analyse_clamping
from toggle.params import ParameterError, load_preset

SM55 = load_preset("lin2003_sm55")
RPM = 2 * math.pi / 60  # rad/s per rpm


@pytest.fixture(scope="module")
def run():
    return analyse_clamping(SM55, 0.05)


def test_preset_drive_is_the_papers():
    d = SM55.drive
    assert d.ratio == pytest.approx(30 / 42)
    assert d.lead == pytest.approx(0.020)
    assert d.pulses_per_rev == 16384
    assert d.rated_torque == pytest.approx(2440 * 9.80665e-3)  # 2440 kgf mm
    assert d.rated_speed == pytest.approx(2000 * RPM)


def test_torque_is_thrust_times_travel_per_radian_over_efficiency():
    """Eq 32 is power balance: T_m * omega * eta = F0 * v."""
    d = SM55.drive
    v = 0.05  # m/s
    assert motor_torque(1e4, d) * motor_speed(v, d) * d.efficiency == pytest.approx(1e4 * v)


def test_pulses_round_trip_and_experiment_travel():
    """Eq 31: the first experiment's N_c = 27 790 pulses is 27790/16384 * 30/42 * 20 mm."""
    d = SM55.drive
    travel = travel_from_pulses(27_790, d)
    assert travel * 1e3 == pytest.approx(27_790 / 16_384 * 30 / 42 * 20)
    assert encoder_pulses(travel, d) == pytest.approx(27_790)


def test_contact_from_pulses_inverts_the_travel(run):
    pulses = encoder_pulses(run.crosshead_travel, SM55.drive)
    assert contact_from_pulses(SM55, pulses) == pytest.approx(run.x_contact, abs=1e-12)
    # the experiments' shorter travel means later contact (a thicker mold), less force
    x_c = contact_from_pulses(SM55, 27_790)
    assert x_c > run.x_contact
    assert analyse_clamping(SM55, 0.05, x_contact=x_c).final.tiebar_force < run.final.tiebar_force


def test_torque_history_at_200_rpm(run):
    """Constant 200 rpm from contact: torque rises, peaks at T(F0_max), then holds with mu_s."""
    d = SM55.drive
    speed = 200 * RPM
    t_arrive = run.crosshead_travel / (speed * d.ratio * d.lead / (2 * math.pi))
    t = np.linspace(0.0, 1.2 * t_arrive, 2001)
    h = torque_history(SM55, run, t, speed)
    assert h.torque[0] == pytest.approx(0.0, abs=1e-9)
    assert h.torque.max() == pytest.approx(motor_torque(run.thrust_max, d), rel=1e-4)
    assert h.crosshead_travel[-1] == pytest.approx(run.crosshead_travel)
    assert h.torque[-1] == pytest.approx(motor_torque(run.hold.thrust, d))
    assert run.hold.thrust > run.final.thrust  # mu_s = 1.25 mu_d holds harder
    moving = t < t_arrive
    assert np.all(np.diff(h.crosshead_travel[moving]) > 0)


def test_bad_profiles_are_clear_errors(run):
    with pytest.raises(ValueError, match="increasing"):
        torque_history(SM55, run, [0.0, 0.0], 1.0)
    with pytest.raises(ValueError, match="non-negative"):
        torque_history(SM55, run, [0.0, 1.0], -1.0)
    with pytest.raises(ClampingError, match="outside the stroke"):
        contact_from_pulses(SM55, 10**9)


def test_invalid_drive_data_is_rejected():
    with pytest.raises(ParameterError, match="efficiency"):
        dataclasses.replace(SM55.drive, efficiency=1.5)
    with pytest.raises(ParameterError, match="lead"):
        dataclasses.replace(SM55.drive, lead=-0.02)
