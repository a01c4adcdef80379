"""The reciprocating experiment (seed 000, section 5): trajectories and cycle segmentation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controllers.limits import DriveLimits, drive_limits
from controllers.profiles import s_curve, stroke_at_speed
from hil.host.experiment import (
    CycleCounter,
    profile_cycles,
    reciprocating_trajectory,
    segment_cycles,
    stroke_positions,
)
from hil.host.samples import Trajectory, TrajectoryError
from toggle.kinematics import stroke_limits

PERIOD = 1e-3


def derivatives(x: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v = np.diff(x) / period
    a = np.diff(v) / period
    return v, a, np.diff(a) / period


def test_reciprocating_runs_between_open_and_toggle(chang):
    x_open, x_tp = stroke_limits(chang.lower)
    traj = reciprocating_trajectory(chang, speed=0.025, cycles=3, period=PERIOD)
    x = traj.x_cmd
    assert x[0] == x_open and x[-1] == x_open
    assert np.count_nonzero(x == x_tp) == 3  # reaches the toggle exactly, once per cycle
    assert x.min() == x_open and x.max() == x_tp
    assert np.allclose(np.diff(traj.time), PERIOD)


@pytest.mark.parametrize("jerk", [50.0, math.inf])
def test_ramps_respect_speed_accel_and_jerk(chang, jerk):
    accel = 0.5
    limits = DriveLimits(velocity=0.04, acceleration=accel, jerk=50.0, torque=0.3)
    x = reciprocating_trajectory(chang, 0.025, 1, PERIOD, limits=limits, jerk=jerk).x_cmd
    v, a, j = derivatives(x, PERIOD)
    assert np.max(np.abs(v)) == pytest.approx(0.025, rel=1e-6)  # long stroke: cruises at v
    assert np.max(np.abs(a)) <= accel * (1 + 1e-3)
    if math.isfinite(jerk):
        assert np.max(np.abs(j)) <= jerk * (1 + 1e-3)
    else:  # trapezoidal: the acceleration jumps, so its finite difference is not bounded
        assert np.max(np.abs(j)) > 100 * accel


def test_default_strokes_keep_the_planners_drive_limits(chang):
    """The experiment's strokes obey the limits the planner and its baselines obey
    (they once defaulted to 0.5 m/s^2 and 50 m/s^3 against the preset's 0.4 and 8)."""
    limits = drive_limits(chang)
    x = reciprocating_trajectory(chang, 0.025, 1, PERIOD).x_cmd
    _, a, j = derivatives(x, PERIOD)
    assert np.max(np.abs(a)) <= limits.acceleration * (1 + 1e-3)
    assert np.max(np.abs(j)) <= limits.jerk * (1 + 1e-2)
    assert np.max(np.abs(a)) >= 0.99 * limits.acceleration  # the ramps use them


def test_one_s_curve_generator_for_the_rig_and_the_baselines(chang):
    """A stroke at a cruise speed is the baseline S-curve of the same duration."""
    limits = drive_limits(chang)
    x_open, x_tp = stroke_limits(chang.lower)
    move = stroke_at_speed(x_open, x_tp, 0.025, limits.acceleration, limits.jerk)
    baseline = s_curve(x_open, x_tp, move.duration, limits.velocity, limits.acceleration,
                       limits.jerk)
    t = np.linspace(0.0, move.duration, 997)
    np.testing.assert_allclose(move.sample(t), baseline.sample(t), atol=1e-12)
    back = stroke_at_speed(x_tp, x_open, 0.025, limits.acceleration, limits.jerk)
    np.testing.assert_allclose(back.sample(t)[0], x_open + x_tp - move.sample(t)[0],
                               atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(distance=st.floats(1e-4, 0.1), speed=st.floats(1e-3, 0.05),
       accel=st.floats(0.05, 5.0), jerk=st.one_of(st.just(math.inf), st.floats(5.0, 500.0)),
       backward=st.booleans())
def test_stroke_is_monotonic_exact_and_within_speed(distance, speed, accel, jerk, backward):
    limits = DriveLimits(velocity=1.0, acceleration=accel, jerk=jerk if math.isfinite(jerk)
                         else 1.0, torque=1.0)
    start, end = (0.01 + distance, 0.01) if backward else (0.01, 0.01 + distance)
    x = stroke_positions(start, end, speed, PERIOD, limits, jerk)
    assert x[0] == start and x[-1] == end
    step = np.diff(x) * (-1 if backward else 1)
    assert np.all(step >= -1e-15)
    assert np.max(step) / PERIOD <= speed * (1 + 1e-9)


def test_bad_stroke_arguments_raise(chang):
    with pytest.raises(TrajectoryError):
        stroke_positions(0.0, 0.01, -0.01, PERIOD, drive_limits(chang))
    with pytest.raises(TrajectoryError):
        stroke_positions(0.0, 0.0, 0.01, PERIOD, drive_limits(chang))
    with pytest.raises(TrajectoryError):
        reciprocating_trajectory(chang, 0.025, 0)


def test_segmentation_finds_every_cycle_and_drops_an_unfinished_one(chang):
    x_open, x_tp = stroke_limits(chang.lower)
    x = reciprocating_trajectory(chang, 0.05, 4, PERIOD).x_cmd
    cycles = segment_cycles(x, x_open, x_tp)
    assert len(cycles) == 4
    for c in cycles:
        assert x[c.start] == x_open and x[c.end] == x_open and x[c.toggle] == x_tp
        assert np.all(np.diff(x[c.forward]) >= 0) and np.all(np.diff(x[c.backward]) <= 0)
    assert [c.start for c in cycles[1:]] == [c.end for c in cycles[:-1]]
    cut = (cycles[2].toggle + cycles[2].end) // 2  # a run aborted in the third backward stroke
    assert len(segment_cycles(x[:cut], x_open, x_tp)) == 2


def test_cycle_counter_agrees_with_segmentation(chang):
    x_open, x_tp = stroke_limits(chang.lower)
    x = reciprocating_trajectory(chang, 0.05, 3, PERIOD).x_cmd
    counter = CycleCounter(x_open, x_tp)
    done = [i for i, xi in enumerate(x) if counter.update(float(xi))]
    assert counter.completed == 3
    for i, c in zip(done, segment_cycles(x, x_open, x_tp), strict=True):
        assert c.toggle < i <= c.end  # on entering the open band, at or before its lowest point


def write_profile(path, t, x):
    rows = ["time [s],position [m],velocity [m/s],acceleration [m/s^2],jerk [m/s^3]"]
    rows += [f"{ti:.6f},{xi:.9f},0,0,0" for ti, xi in zip(t, x)]
    path.write_text("\n".join(rows) + "\n")


def test_profile_csv_round_trip_and_mirror(tmp_path):
    t = 0.5 + np.arange(101) * 2e-3  # a planner may start at any time
    x = 0.02 * (t - t[0]) ** 2
    path = tmp_path / "plan.csv"
    write_profile(path, t, x)
    traj = Trajectory.from_csv(path)
    assert traj.period == pytest.approx(2e-3) and traj.time[0] == 0.0
    assert np.allclose(traj.x_cmd, x, atol=1e-9)
    resampled = Trajectory.from_csv(path, period=1e-3)
    assert len(resampled) == 201
    assert np.allclose(resampled.x_cmd[::2], x, atol=1e-9)
    both = profile_cycles(traj, 2)
    assert len(both) == 4 * 100 + 1
    assert np.allclose(both.x_cmd[100:201], x[::-1])  # the return stroke mirrors the plan


def test_profile_csv_errors(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x\n0,0\n1,1\n")
    with pytest.raises(TrajectoryError, match="position"):
        Trajectory.from_csv(bad)
    uneven = tmp_path / "uneven.csv"
    write_profile(uneven, [0.0, 0.001, 0.003, 0.004], [0.0, 1e-6, 2e-6, 3e-6])
    with pytest.raises(TrajectoryError, match="non-uniform"):
        Trajectory.from_csv(uneven)
    assert len(Trajectory.from_csv(uneven, period=1e-3)) == 5


def test_trajectory_rejects_bad_arrays():
    with pytest.raises(TrajectoryError):
        Trajectory(np.array([0.0, 0.001, 0.003]), np.zeros(3), 0.001)
    with pytest.raises(TrajectoryError):
        Trajectory.from_positions([0.0, np.nan], 0.001)
