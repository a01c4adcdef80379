"""Ball-screw/belt drive (Lin & Hsiao 2003, Eqs 31-32)."""

from __future__ import annotations

import dataclasses
import math
from importlib import resources

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toggle.drive import (
    back_efficiency,
    contact_from_pulses,
    copper_loss,
    encoder_pulses,
    flow_factor,
    flow_torque,
    motor_speed,
    motor_torque,
    reflected_mass,
    torque_history,
    torque_speed_limit,
    travel_from_pulses,
)
from toggle.elastics import ClampingError, analyse_clamping
from toggle.kinematics import stroke_limits
from toggle.params import ParameterError, load_mechanism, load_preset
from toggle.plant import (
    DriveState,
    PlantError,
    configure,
    drive_step,
    extrapolation,
    follow,
    lag_transition,
    plant_outputs,
)
from toggle_cli import main

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


# ---- the drive's inertia and torque-speed curve ------------------------------------------

CHANG = load_preset("chang2021")


def test_reflected_mass_by_hand():
    """m_drive = (J_m + R^2 J_s) (2 pi / (R lead))^2: the rotor turns 1/R times the screw."""
    d = CHANG.drive  # direct drive, 5 mm lead
    assert reflected_mass(d) == pytest.approx((2.8e-5 + 5.0e-6) * (2 * math.pi / 5e-3) ** 2)
    assert reflected_mass(d) == pytest.approx(52.11, abs=0.01)
    s = SM55.drive  # belt 30/42, 20 mm lead
    by_hand = 6e-3 * (2 * math.pi / (30 / 42 * 0.020)) ** 2 + 6e-3 * (2 * math.pi / 0.020) ** 2
    assert reflected_mass(s) == pytest.approx(by_hand)
    a = 2.0  # m/s^2: the rotor and screw torque is m_drive a times travel per radian
    assert motor_torque(0.0, s, a) == pytest.approx(
        (6e-3 + (30 / 42) ** 2 * 6e-3) * a / (30 / 42 * 0.020 / (2 * math.pi)))


@settings(max_examples=25, deadline=None)
@given(rotor=st.floats(0.0, 1e-3), screw=st.floats(0.0, 1e-3), platen=st.floats(0.5, 20.0),
       stroke=st.floats(0.2, 0.9), duration=st.floats(0.2, 2.0))
def test_motor_power_is_the_rate_of_kinetic_energy_with_the_rotor(rotor, screw, platen, stroke,
                                                                 duration):
    """Friction off (pins, guides, efficiency 1), no mold: the motor's power T omega equals
    the rate of change of the kinetic energy of crosshead, links, platen, rotor and screw,
    so its work from rest is that kinetic energy."""
    cfg = configure("chang2021", mu=0.0,
                    masses={"platen": platen, "guide_damping": 0.0, "guide_friction": 0.0},
                    drive={"rotor_inertia": rotor, "screw_inertia": screw, "efficiency": 1.0})
    d, dyn = cfg.mechanism.drive, cfg.dynamics
    x0, x1 = cfg.input_range
    x_open, x_toggle = stroke_limits(CHANG.lower)
    span = stroke * (x_toggle - x_open)
    t = np.linspace(0.0, duration, 20001)
    s = t / duration  # from rest, accelerating to speed (a quintic's first half)
    x = x_open + span * s**3 * (10 - 15 * s + 6 * s**2)
    v = span / duration * 30 * s**2 * (1 - s) ** 2
    a = span / duration**2 * 60 * s * (1 - s) * (1 - 2 * s)
    assert x0 <= x.min() and x.max() <= x1
    out = plant_outputs(x, v, a, cfg)
    power = np.asarray(out.motor_torque) * motor_speed(v, d)
    work = np.concatenate(([0.0], np.cumsum(np.diff(t) * (power[1:] + power[:-1]) / 2)))
    m_in, m_out = dyn.crosshead + 0.5 * dyn.links, dyn.platen + 0.5 * dyn.links
    kinetic = 0.5 * ((m_in + reflected_mass(d)) * v**2 + m_out * np.asarray(out.platen_velocity)**2)
    scale = float(np.max(kinetic)) + 1e-12
    np.testing.assert_allclose(work, kinetic, atol=2e-6 * scale)


def test_torque_speed_limit_interpolates_and_holds_beyond_the_last_point():
    speeds, torques = (0.0, 10.0, 30.0), (1.0, 0.8, 0.2)
    w = np.array([0.0, 5.0, 10.0, 20.0, 30.0, 100.0, -5.0])
    np.testing.assert_allclose(torque_speed_limit(w, speeds, torques),
                               [1.0, 0.9, 0.8, 0.5, 0.2, 0.2, 0.9])
    np.testing.assert_allclose(torque_speed_limit(w, speeds, torques),
                               np.interp(np.abs(w), speeds, torques))
    assert torque_speed_limit(3.0, (0.0,), (0.3,)) == 0.3


BAD_CURVES = [
    ("[[0.0, 0.5], [10.0, 0.6]]", "must not rise"),
    ("[[0.0, 0.5], [10.0, 0.4], [5.0, 0.3]]", "speeds must increase"),
    ("[[1.0, 0.5], [10.0, 0.4]]", "start at speed 0"),
    ("[[0.0, 0.5], [10.0, -0.1]]", "must be > 0"),
    ("[[0.0, nan], [10.0, 0.1]]", "pair of finite numbers"),
    ("[[0.0, 0.5, 1.0]]", "pair of finite numbers"),
    ("[]", "1 to 8"),
    ("0.5", "list of"),
    ('[["fast", 0.5]]', "pair of finite numbers"),
    ("[" + ", ".join(f"[{k}.0, 0.5]" for k in range(9)) + "]", "1 to 8"),
]


def _preset_with(tmp_path, line: str):
    """chang2021 as a user's file with the line of one [drive] key replaced by ``line``."""
    text = (resources.files("toggle") / "presets" / "chang2021.toml").read_text()
    start = text.index("\n" + line.split(" = ")[0] + " = ") + 1
    path = tmp_path / "mine.toml"
    path.write_text(text[:start] + line + text[text.index("\n", start):])
    return path


@pytest.mark.parametrize("curve, named", BAD_CURVES)
def test_a_bad_torque_speed_curve_is_refused_naming_file_and_key(tmp_path, curve, named):
    path = _preset_with(tmp_path, f"torque_speed = {curve}")
    with pytest.raises(ParameterError, match=named) as info:
        load_mechanism(path)
    assert str(path) in str(info.value) and "[drive]" in str(info.value)
    assert "torque_speed" in str(info.value)


@pytest.mark.parametrize("line, named", [("rotor_inertia = -1e-5", "rotor_inertia"),
                                         ('screw_inertia = "big"', "screw_inertia"),
                                         ("rotor_inertia = inf", "rotor_inertia")])
def test_a_bad_inertia_is_refused(tmp_path, line, named):
    path = _preset_with(tmp_path, line)
    with pytest.raises(ParameterError, match=named):
        load_mechanism(path)


def test_toggle_plan_refuses_a_bad_curve_with_one_line(tmp_path, capsys):
    path = _preset_with(tmp_path, "torque_speed = [[0.0, 0.5], [10.0, 0.9]]")
    assert main(["plan", "--preset", str(path), "--min-time"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert captured.out == "" and len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(path) in err and "torque_speed" in err and "must not rise" in err


# ---- the drive lag over the whole declared range (toggle.plant.lag_transition, follow) ----

BANDWIDTH_MAX, DAMPING_MAX = 1e3, 10.0  # Hz, 1: the FMUs' declared maxima (both minima 0)
STEPS = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0)  # s
LAG_TOL = 1e-9  # of the dimensionless exp(A h) (x in m, v in m/s w); ~5e-12 observed


def _lag_error(bandwidth: float, damping: float, h: float) -> float:
    """Largest difference of lag_transition from scipy's expm, on diag(1, 1/w) exp(A h)
    diag(1, w) (dimensionless: every entry of order 1)."""
    from scipy.linalg import expm

    w = 2 * math.pi * bandwidth
    want = expm(np.array([[0.0, 1.0], [-w * w, -2 * damping * w]]) * h)
    got = np.reshape(lag_transition(w, damping, h), (2, 2))
    scale = np.array([[1.0, w], [1.0 / w, 1.0]])
    assert np.all(np.isfinite(got))
    return float(np.max(np.abs(got - want) * scale))


@pytest.mark.parametrize("bandwidth", [1e-3, BANDWIDTH_MAX])  # Hz: the lag's lowest, highest
@pytest.mark.parametrize("damping", [0.0, 1.0, DAMPING_MAX])
def test_lag_transition_is_expm_at_the_corners_of_the_range(bandwidth, damping):
    """Overdamped at 1000 Hz with damping 10 and a 1 s step (w h sqrt(zeta^2 - 1) ~ 6e4)
    overflowed cosh before; now every step from 1 us to 1 s agrees with expm."""
    assert max(_lag_error(bandwidth, damping, h) for h in STEPS) < LAG_TOL


@settings(max_examples=300, deadline=None)
@given(bandwidth=st.floats(1e-3, BANDWIDTH_MAX), damping=st.floats(0.0, DAMPING_MAX),
       h=st.floats(1e-6, 1.0))
def test_lag_transition_is_expm_over_the_range(bandwidth, damping, h):
    assert _lag_error(bandwidth, damping, h) < LAG_TOL


@settings(max_examples=100, deadline=None)
@given(damping=st.floats(1 - 1e-3, 1 + 1e-3), bandwidth=st.floats(1e-3, BANDWIDTH_MAX),
       h=st.floats(1e-6, 1.0))
def test_lag_transition_is_expm_near_critical_damping(bandwidth, damping, h):
    """Where the series replaces cosh/cos and sinh(q)/q (|q^2| < 1e-2) and beside it."""
    assert _lag_error(bandwidth, damping, h) < LAG_TOL


@pytest.mark.parametrize("bandwidth", [0.0, BANDWIDTH_MAX])
@pytest.mark.parametrize("damping", [0.0, DAMPING_MAX])
def test_a_drive_at_rest_stays_at_rest_at_every_step_size(bandwidth, damping):
    """The four corners of the declared range: no rejection, the input link stays where it
    is; then a command of constant acceleration (1 m/s^2) is followed without rejection,
    with finite outputs."""
    x0 = -3.4386e-3
    for h in STEPS:
        state = DriveState.at_rest(x0)
        for _ in range(3):
            state = follow(state, x0, h, bandwidth, damping)
            assert (state.x, state.v, state.a) == (x0, 0.0, 0.0)
        for k in range(1, 4):
            state = follow(state, x0 + 0.5 * (h * k) ** 2, h, bandwidth, damping)
            assert all(map(math.isfinite, state)) and abs(state.a) <= 2.0


@pytest.mark.parametrize(("bandwidth", "hint"), [
    (0.0, " (drive_bandwidth = 0: an ideal drive follows a setpoint jump within one step; a "
          "drive_bandwidth > 0 Hz follows it through the drive's lag)"),
    (1000.0, " (drive_bandwidth = 1000 Hz; a lower drive_bandwidth follows larger setpoint "
             "jumps)")])
def test_a_refused_jump_names_drive_bandwidth(bandwidth, hint):
    with pytest.raises(PlantError) as refused:
        follow(DriveState.at_rest(0.0), 0.05, 1e-3, bandwidth, 0.7)
    v, a = (100.0, 1e5) if bandwidth == 0 else (None, None)
    text = str(refused.value)
    assert text.startswith("the command x_cmd = 0.05 m after 0.001 s asks for ")
    assert text.endswith("m/s^2; an input link moves within 10 m/s and 10000 m/s^2" + hint)
    if v is not None:
        assert f"asks for {v:.3g} m/s and {a:.3g} m/s^2;" in text


@settings(max_examples=40, deadline=None)
@given(h=st.floats(1e-6, 1.0), levels=st.lists(st.floats(-1.0, 1.0), min_size=2, max_size=12),
       hold=st.integers(1, 30))
def test_the_default_drive_follows_any_staircase_at_any_fixed_step(h, levels, hold):
    """The FMU's default drive_bandwidth (the preset's drive, docs/fmu.md) follows setpoints
    that jump anywhere within the x_cmd range, each held ``hold`` steps of ``h``: never
    refused, and far within the input link's bounds (at most ~40 m/s^2 observed), both as the
    FMU steps (x_cmd at the step's start, extrapolated from the last commands within its
    range) and with the command taken at the step's end (:func:`toggle.plant.follow`)."""
    from fmu_support import load_module

    from fmu_src.build import DEFAULT_SLAVE

    table = {v.name: v for v in load_module(DEFAULT_SLAVE, "clamp_fmu_drive").ToggleClamp.VARIABLES}
    bandwidth, damping, x_cmd = (table[n] for n in ("drive_bandwidth", "drive_damping", "x_cmd"))
    middle, half = (x_cmd.max + x_cmd.min) / 2, (x_cmd.max - x_cmd.min) / 2
    states = [DriveState.at_rest(x_cmd.min)] * 2
    for level in levels:
        for _ in range(hold):
            u = middle + half * level
            states = [drive_step(states[0], u, h, bandwidth.start, damping.start,
                                 bounds=(x_cmd.min, x_cmd.max)),
                      follow(states[1], u, h, bandwidth.start, damping.start)]
            for state in states:
                assert abs(state.a) <= 100.0 and abs(state.v) <= 2.0


def test_the_back_driving_efficiency_is_the_catalogue_relation_unless_given():
    """eta' = 2 - 1/eta (NSK/THK) where the preset gives none; the presets state theirs;
    a screw that would not back-drive (eta <= 0.5) is refused, naming the key to give."""
    plain = dataclasses.replace(SM55.drive, back_efficiency=None)
    assert back_efficiency(plain) == pytest.approx(2 - 1 / 0.8) == pytest.approx(0.75)
    assert back_efficiency(SM55.drive) == SM55.drive.back_efficiency
    with pytest.raises(ParameterError, match="back_efficiency"):
        back_efficiency(dataclasses.replace(plain, efficiency=0.5))
    with pytest.raises(ParameterError, match="back_efficiency must be in"):
        dataclasses.replace(SM55.drive, back_efficiency=0.9)


@settings(max_examples=60, deadline=None)
@given(st.floats(-1e4, 1e4), st.floats(-0.5, 0.5), st.floats(-5.0, 5.0))
def test_the_torque_by_power_flow_is_eq_32_driving_and_eta_prime_back_driven(force, v, a):
    """Driving (F v > 0) the torque is Eq 32's with the rotor; back-driven or at rest the
    thrust reaches the motor times eta' (less torque than 1/eta gives, the same sign)."""
    drive = SM55.drive
    torque = float(flow_torque(force, v, drive, a))
    inertia = float(motor_torque(0.0, drive, a))
    if force * v > 0:
        assert torque == pytest.approx(float(motor_torque(force, drive, a)), rel=1e-12,
                                       abs=1e-12)
    else:
        expected = force * drive.back_efficiency * drive.ratio * drive.lead / (2 * math.pi)
        assert torque - inertia == pytest.approx(expected, rel=1e-12, abs=1e-12)
        assert abs(torque - inertia) <= abs(float(motor_torque(force, drive))) + 1e-12


def test_the_smoothed_flow_factor_tends_to_the_switch():
    """The planner's tanh blend is the exact switch away from zero power, the mean at it."""
    powers = np.array([-1.0, -1e-3, 0.0, 1e-3, 1.0])
    exact = flow_factor(powers, 0.8, 0.75)
    np.testing.assert_allclose(exact, [0.75, 0.75, 0.75, 1.25, 1.25])
    smooth = flow_factor(powers, 0.8, 0.75, 1e-5)
    np.testing.assert_allclose(smooth[[0, 1, 3, 4]], exact[[0, 1, 3, 4]], rtol=1e-12)
    assert smooth[2] == pytest.approx((1.25 + 0.75) / 2)


def test_copper_losses_are_phases_r_i_squared():
    drive = SM55.drive
    current = 10.0 / drive.torque_constant
    assert float(copper_loss(10.0, drive)) == pytest.approx(
        drive.phases * drive.winding_resistance * current**2)
    with pytest.raises(ParameterError, match="winding_resistance"):
        copper_loss(1.0, dataclasses.replace(drive, winding_resistance=None))


@pytest.mark.parametrize(("line", "named"), [
    ("phases = 0", "phases"), ("brake_voltage = 10.0", "brake_voltage"),
    ("torque_constant = -1.0", "torque_constant"), ("back_efficiency = 0.95", "back_eff")])
def test_bad_motor_data_is_refused_naming_the_key(tmp_path, line, named):
    """A preset's bad electrical data is refused at load, naming file, section and key."""
    path = _preset_with(tmp_path, line)
    with pytest.raises(ParameterError, match=named) as info:
        load_mechanism(path)
    assert str(path) in str(info.value) and "[drive]" in str(info.value)


def _after(commands: list[tuple[float, float]]) -> DriveState:
    """The drive state after stepping (x_cmd, h) pairs with a 20 Hz lag, no derivatives."""
    state = DriveState.at_rest(commands[0][0])
    for u, h in commands:
        state = drive_step(state, u, h, 20.0, 1.0)
    return state


def test_extrapolation_is_the_parabola_through_the_last_three_commands():
    """A command of constant acceleration, given at unequal steps, is extrapolated exactly
    (its velocity and acceleration at the step's start), whatever the step that follows."""
    times = [0.0, 1e-3, 2.5e-3, 3.3e-3]
    command = [1e-3 + 0.05 * t + 0.5 * 3.0 * t * t for t in times]
    steps = [b - a for a, b in zip(times, times[1:])] + [0.7e-3]
    state = _after(list(zip(command[:-1], steps[:-1])))
    d1, d2 = extrapolation(state, command[-1], steps[-1])
    assert d1 == pytest.approx(0.05 + 3.0 * times[-1], rel=1e-9)
    assert d2 == pytest.approx(3.0, rel=1e-7)


def test_extrapolation_reads_no_reversal_nor_jump_beyond_twice_itself():
    """A stop is held; a jump from rest is continued by at most twice itself (and never
    beyond a longer step); a slope's sign is kept; the bounds (x_cmd's range) hold."""
    rest = _after([(0.0, 1e-3)] * 3)
    assert extrapolation(_after([(0.0, 1e-3), (0.01, 1e-3), (0.01, 1e-3)]), 0.01, 1e-3) == \
        (0.0, 0.0)
    for h in (1e-3, 0.5):
        d1, d2 = extrapolation(rest, 0.01, h)
        move = d1 * h + d2 * h * h / 2
        assert 0.0 < move <= 2 * 0.01 * min(h, 1e-3) / 1e-3 + 1e-15
    d1, d2 = extrapolation(rest, 0.01, 1e-3, bounds=(-0.1, 0.012))
    assert d1 * 1e-3 + d2 * 1e-6 / 2 == pytest.approx(0.002)
    slowing = _after([(0.0, 1e-3), (0.01, 1e-3), (0.011, 1e-3)])
    d1, d2 = extrapolation(slowing, 0.0111, 1e-3)  # the parabola turns back: held at 0
    assert d1 * 1e-3 + d2 * 1e-6 / 2 >= 0.0
