"""The whole molding cycle (``toggle plan --cycle --hold --eject``): its phases and time,
the motor's duty over it, its replay by ``hil run``, and the energy-optimal stroke."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
from hil_host import hil, recorded_samples, sent_samples

from controllers.limits import drive_limits
from controllers.planner import default_duration, planner_for
from controllers.plans import plan_config
from controllers.profiles import read_profile_csv, read_profile_settings
from hil.cli.main import main as hil_main
from hil.emulators.mcu_model import RigHardware
from hil.emulators.rig_emulator import spawn_emulator
from hil.emulators.rig_physics import ClampPhysics
from hil.host.backends import RigSetup
from hil.host.experiment import profile_cycles, segment_cycles
from hil.host.samples import Trajectory
from toggle.elastics import clamp_stroke
from toggle.params import load_preset
from toggle_cli import main

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


@pytest.mark.real_time
def test_hil_replays_the_cycle_as_it_is_on_both_back_ends(cycle, tmp_path):
    """A profile that ends where it starts is a whole cycle: replayed as it is, not with
    its mirror as the return; the FMU back-end runs it and counts the cycles, and the
    emulated real rig (``hil run --real``, the mold the cycle was planned for bolted in)
    runs the same cycle in real time: every sample the emulator sent is recorded once, in
    order, and the two back-ends give the same stroke to the encoder's resolution and the
    same RMS forces to 0.5 % (measured: 0.17 N forward, 0.09 N backward of 39 N; the
    step generator's velocity ripple, docs/rig.md, "Bring-up and runs", which also puts
    F_F(max) 3.4 N further out)."""
    cycle = cycle[0]
    one = Trajectory.from_csv(cycle, period=1e-3)
    two = profile_cycles(one, 2)
    np.testing.assert_array_equal(two.x_cmd[:len(one)], one.x_cmd)
    assert two.duration == pytest.approx(2 * one.duration)
    x_open, x_final = clamp_stroke(load_preset("chang2021"))
    assert len(segment_cycles(two.x_cmd, x_open, x_final)) == 2
    assert hil_main(["run", "--profile", str(cycle), "--cycles", "1",
                     "--out", str(tmp_path / "run"), "--json"]) == 0
    sim = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert sim["cycles_complete"] == 1

    setup = RigSetup()
    mold = float(read_profile_settings(cycle)["x_contact"])
    emulator = spawn_emulator(ClampPhysics(setup.preset, setup.delta_r8, setup.mu, mold),
                              RigHardware(x_origin=setup.stroke[0]), realtime=True)
    try:
        code, _, err = hil("run", "--real", "--port", emulator.port, "--profile", str(cycle),
                           "--cycles", "1", "--out", str(tmp_path / "rig"), "--json",
                           timeout=180)
    finally:
        log = emulator.close()
    assert code == 0, err
    rig = json.loads((tmp_path / "rig" / "summary.json").read_text())
    assert rig["cycles_complete"] == 1
    recorded = recorded_samples(tmp_path / "rig")
    assert recorded == sent_samples(log, recorded[0])
    assert len(recorded) * 1e-3 >= one.duration  # the whole cycle, dwells included
    for key in ("stroke_initial", "stroke_final", "stroke"):
        assert rig[key]["mean"] == pytest.approx(sim[key]["mean"], abs=2e-6), key
    for key in ("force_forward_rms", "force_backward_rms"):
        assert rig[key]["mean"] == pytest.approx(sim[key]["mean"], rel=5e-3), key


def test_a_motor_too_small_for_the_cycle_is_refused_by_how_much(capsys):
    assert main(["plan", "--cycle", "--hold", str(HOLD), "--rated-torque", "0.001"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(errors) == 1  # one line (a slow plan's progress bar may precede it)
    assert "too small" in errors[0]
    assert "exceeds the rated (continuous) torque 0.001 N m by" in errors[0]


def test_the_energy_optimal_stroke_saves_electrical_energy_for_some_peak_force():
    """At the default plan's duration the energy objective finds a stroke of less
    electrical energy (controllers.duty on its 1 ms samples: the screw's efficiency by the
    direction of power flow, the copper losses) than the least-peak plan, at a higher peak
    input force; its objective is that energy (over f_ref S) to the nodes' trapezoidal
    rule and the smoothed switch of efficiency."""
    cfg = plan_config("chang2021")
    planner = planner_for(cfg, drive_limits(cfg.mechanism))
    peak = planner.best(default_duration(planner))
    energy = planner.solve(peak.duration, "energy", start=peak)
    drive = cfg.mechanism.drive

    def electrical(plan) -> float:
        from controllers.duty import motor_duty
        s = plan.samples
        return motor_duty(s.time, s.velocity, s.acceleration, s.input_force, drive
                          ).electrical()["energy_regenerating"]

    assert electrical(energy) < electrical(peak)
    assert energy.peak_force > peak.peak_force
    assert float(energy.solution["f"][0]) * planner.f_ref * planner.stroke == pytest.approx(
        electrical(energy), rel=0.02)
