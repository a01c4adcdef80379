"""The whole molding cycle (``toggle plan --cycle --hold --eject``): its phases and time,
the motor's duty over it, its replay by ``hil run``, and the energy-optimal stroke."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from controllers.limits import drive_limits
from controllers.planner import default_duration, plan_config, planner_for
from controllers.profiles import read_profile_csv
from hil.cli import main as hil_main
from hil.experiment import profile_cycles, segment_cycles
from hil.samples import Trajectory
from toggle.cli import main
from toggle.elastics import clamp_stroke
from toggle.params import load_preset

HOLD, EJECT = 2.0, 0.5


@pytest.fixture(scope="module")
def cycle(tmp_path_factory):
    """``toggle plan --cycle`` with dwells: the cycle's profile CSV and the JSON report."""
    out = tmp_path_factory.mktemp("cycle") / "cycle.csv"
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        assert main(["plan", "--cycle", "--hold", str(HOLD), "--eject", str(EJECT),
                     "--cycle-out", str(out), "--duty-plot", str(out.with_suffix(".png")),
                     "--json"]) == 0
    return out, json.loads(printed.getvalue())


def test_the_cycle_is_its_phases_and_its_profile_returns_to_the_start(cycle):
    cycle, report = cycle
    molding = report["molding_cycle"]
    phases = molding["phases"]
    assert (phases["hold"], phases["eject"]) == (HOLD, EJECT)
    assert phases["close"] + phases["clamp_up"] == pytest.approx(report["duration"])
    assert phases["open"] == pytest.approx(report["opening"]["opening_time"])
    assert molding["cycle_time"] == pytest.approx(sum(phases.values()))
    s = read_profile_csv(cycle)
    assert s.time[-1] == pytest.approx(molding["cycle_time"], abs=2e-3)
    x_open, x_final = clamp_stroke(load_preset("chang2021"))
    assert s.position[0] == pytest.approx(x_open) and s.position[-1] == pytest.approx(x_open)
    held = (s.time > report["duration"] + 1e-3) & (s.time < report["duration"] + HOLD)
    assert np.all(s.position[held] == pytest.approx(x_final)) and not s.velocity[held].any()
    # the duty: the dwells add time, not torque; regeneration gives back the braking energy
    assert molding["rms_torque"] < molding["peak_torque"]
    assert 0 < molding["energy_regenerating"] < molding["energy_without_regeneration"]
    assert molding["motor"]["rated_torque"] == 1.2  # the preset's stated assumption
    assert cycle.with_suffix(".png").stat().st_size > 10_000  # --duty-plot


def test_hil_replays_the_cycle_as_it_is(cycle, tmp_path):
    """A profile that ends where it starts is a whole cycle: replayed as it is, not with
    its mirror as the return; the FMU back-end runs it and counts the cycles."""
    cycle = cycle[0]
    one = Trajectory.from_csv(cycle, period=1e-3)
    two = profile_cycles(one, 2)
    np.testing.assert_array_equal(two.x_cmd[:len(one)], one.x_cmd)
    assert two.duration == pytest.approx(2 * one.duration)
    x_open, x_final = clamp_stroke(load_preset("chang2021"))
    assert len(segment_cycles(two.x_cmd, x_open, x_final)) == 2
    assert hil_main(["run", "--profile", str(cycle), "--cycles", "1",
                     "--out", str(tmp_path / "run"), "--json"]) == 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["cycles_complete"] == 1


def test_a_motor_too_small_for_the_cycle_is_refused_by_how_much(capsys):
    assert main(["plan", "--cycle", "--hold", str(HOLD), "--rated-torque", "0.001"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1  # one line (a slow plan's progress bar may precede it)
    assert "too small" in errors[0]
    assert "exceeds the rated (continuous) torque 0.001 N m by" in errors[0]


def test_the_energy_optimal_stroke_saves_torque_squared_for_some_peak_force():
    """At the default plan's duration the energy objective (the integral of the squared
    motor torque) finds a stroke with less of it than the least-peak plan, at a higher
    peak input force."""
    cfg = plan_config("chang2021")
    planner = planner_for(cfg, drive_limits(cfg.mechanism))
    peak = planner.best(default_duration(planner))
    energy = planner.solve(peak.duration, "energy", start=peak)
    drive = cfg.mechanism.drive

    def torque_squared(plan) -> float:
        from controllers.duty import motor_duty
        s = plan.samples
        return motor_duty(s.time, s.velocity, s.acceleration, s.input_force, drive
                          ).torque_squared

    assert torque_squared(energy) < 0.9 * torque_squared(peak)
    assert energy.peak_force > peak.peak_force
