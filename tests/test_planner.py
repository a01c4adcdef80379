"""The stroke planner's plan: boundary conditions and limits, below both baselines, the FMU's
replay of it, warm starts, the best of several starts against the lower bound, another
mold height and another press (SM-55). The planner's other tests: test_planner_cache.py
(the compiled problem), test_planner_limits.py (minimum time, refusals, the bound),
test_planner_cycle.py (mold protection, opening stroke, cycle), test_planner_cli.py
(``toggle plan``), test_planner_speed.py (issue 37's speed-ups)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from planner_support import DURATION, SM55_MASSES

from controllers.limits import drive_limits
from controllers.planner import planner_for
from controllers.plans import CREEP_FACTOR, plan_config
from controllers.profiles import minimum_time, s_curve
from controllers.stroke_reports import baselines
from fmu_src.build import build_fmu
from toggle.elastics import clamp_stroke
from toggle.params import Dynamics, load_preset
from toggle.plant import plant_outputs
from toggle_cli import main


@pytest.fixture(scope="module")
def fmu(tmp_path_factory: pytest.TempPathFactory):
    return build_fmu(tmp_path_factory.mktemp("fmu"))


def test_plan_meets_the_boundary_conditions_and_limits(chang_plan):
    cfg, limits, planner, plan = chang_plan
    s = plan.samples
    assert plan.duration == pytest.approx(DURATION, rel=1e-9)
    assert s.position[0] == pytest.approx(planner.x_open, abs=1e-12)
    assert s.position[-1] == pytest.approx(planner.x_final, abs=1e-9)
    assert abs(s.velocity[-1]) < 1e-9 and abs(s.acceleration[-1]) < 1e-7
    tol = 1 + 1e-6
    # limits are imposed at the nodes; between them the cubic may overshoot the speed a little
    assert np.all(s.velocity >= -1e-9) and s.velocity.max() <= limits.velocity * (1 + 1e-3)
    assert np.abs(s.acceleration).max() <= limits.acceleration * tol
    assert np.abs(plan.profile.jerk).max() <= limits.jerk * tol
    # the platen's speed at mold contact, from the plant at the contact instant (platen moving)
    x, v, a = plan.profile.sample(np.array([plan.t_contact]))
    out = plant_outputs(x, v, a, cfg.with_(x_contact=None))
    assert float(out.platen_velocity[0]) <= planner.contact_speed * tol
    assert float(x[0]) == pytest.approx(cfg.x_contact, abs=1e-9)
    # the plant holds the clamp force at rest in the locked position
    assert planner.clamp_force() == pytest.approx(2000.0, rel=0.01)
    # no creeping through the clamping (where the smooth friction model fades out)
    clamping = (s.time > plan.t_contact) & (s.time < plan.t_contact + 0.5 * (
        DURATION - plan.t_contact))
    assert s.velocity[clamping].min() >= CREEP_FACTOR * cfg.velocity_epsilon * (1 - 1e-2)


def test_peak_force_below_both_baselines(chang_plan):
    cfg, limits, _, plan = chang_plan
    base = baselines(cfg, limits, plan.duration)
    for samples in base.values():
        assert samples.time[-1] == pytest.approx(plan.duration)
        assert samples.position[-1] == pytest.approx(plan.samples.position[-1], abs=1e-12)
        assert plan.peak_force < samples.peak_force * (1 - 0.01)  # at least 1 % lower


def _replay(fmu, cfg, plan, h):
    """Replay the plan through the FMU at step h; return (t, plan positions, FMU results).

    fmpy applies the input set at t_k during the step to t_k + h and reports the output at
    t_k + h, so the positions are fed one step early."""
    from fmpy import simulate_fmu

    t = np.linspace(0.0, plan.duration, round(plan.duration / h) + 1)
    x = plan.profile.sample(t)[0]
    signal = np.array(list(zip(t - h, x)), dtype=[("time", float), ("x_cmd", float)])
    res = simulate_fmu(str(fmu), start_time=0.0, stop_time=t[-1], step_size=h,
                       output_interval=h, input=signal, output=["x", "input_force"],
                       start_values={"x_contact": cfg.x_contact, "x_cmd": x[0],
                                     "drive_bandwidth": 0.0})  # the ideal drive (docs/fmu.md)
    assert res["time"].size == t.size
    np.testing.assert_allclose(res["x"], x, atol=1e-9)
    return t, x, res


def test_fmu_replay_reproduces_the_predicted_force(chang_plan, fmu):
    """The FMU's ideal drive reads velocity and acceleration off the parabola through the last
    three commands, so at the HIL period (1 ms) and ten times finer its force agrees with the
    plan's prediction at the same instants within 1 % of the peak."""
    cfg, _, _, plan = chang_plan
    for h in (1e-3, 1e-4):
        t, x, res = _replay(fmu, cfg, plan, h)
        predicted = np.asarray(plant_outputs(*plan.profile.sample(t), cfg).input_force)
        assert np.abs(res["input_force"] - predicted)[2:].max() <= 0.01 * plan.peak_force


def test_warm_replan_is_faster_and_reuses_the_problem(chang_plan):
    cfg, limits, planner, plan = chang_plan
    again = planner_for(cfg, limits)
    assert again is planner  # the built problem is kept
    replan = again.solve(DURATION * 1.05, start=plan)
    assert replan.warm and replan.duration == pytest.approx(DURATION * 1.05, rel=1e-9)
    assert replan.iterations < plan.iterations
    assert replan.solve_time < plan.solve_time
    cold = again.solve(DURATION * 1.05, warm=False)
    assert replan.peak_force == pytest.approx(cold.peak_force, rel=1e-2)  # local optima


def test_other_mold_height_warm_starts_from_the_previous_plan(chang_plan):
    cfg, limits, planner, plan = chang_plan
    moved = planner_for(plan_config("chang2021", x_contact=cfg.x_contact - 0.2e-3), limits)
    assert moved.problem is planner.problem  # the mold height is a parameter: no rebuild
    replan = moved.solve(DURATION, start=plan)
    assert replan.warm and replan.iterations < plan.iterations
    x, v, a = replan.profile.sample(np.array([replan.t_contact]))
    assert float(x[0]) == pytest.approx(moved.config.x_contact, abs=1e-9)
    assert moved.clamp_force() > 2000.0  # an earlier contact clamps harder
    cold = moved.solve(DURATION, warm=False)
    assert replan.peak_force == pytest.approx(cold.peak_force, rel=1e-2)


def test_best_plan_finds_the_lower_optimum_and_respects_the_bound(chang_plan):
    """The default-duration peak plan: below 14.99 N (a single cold start may stop at a local
    optimum near 15.04 N) and above the reachable-set bound, within 0.5 % of it."""
    _, _, planner, single = chang_plan
    bound = planner.lower_bound()
    plan = planner.best(DURATION)
    # (a single cold start may stop at the other family's optimum, near 15.0 N)
    assert plan.peak_force <= min(14.99, single.peak_force * (1 + 1e-9))
    assert bound <= plan.peak_force <= bound * 1.005
    assert 14.9 < bound  # the quasi-static peak at creep speed is 15.18 N


def test_the_best_peak_does_not_grow_with_the_duration(chang_plan):
    """More time never needs more force (a longer stroke can idle): the best of several
    starts is monotone within the solver's tolerance (it once jumped by 0.5 %)."""
    _, _, planner, _ = chang_plan
    peaks = [planner.worst_peak(planner.best(d)) for d in (2.0, 3.0, 6.0)]
    assert all(b <= a * (1 + 1e-4) for a, b in zip(peaks, peaks[1:]))


@pytest.mark.parametrize("x_contact", [0.0515, 0.05156])
def test_a_mold_set_at_the_toggle_is_planned(chang_plan, x_contact, capsys):
    """Molds within 0.1 mm of the toggle ran 8-19 s and were reported infeasible ("the motor
    torque limit binds"): the creep floor left no room to stop in such a short clamping."""
    cfg, limits, planner, _ = chang_plan
    near = planner_for(cfg.with_(x_contact=x_contact), limits)
    assert near.problem is planner.problem and not near.clamping_creeps(2)
    plan = near.solve(DURATION, warm=False)
    s = plan.samples
    assert s.position[-1] == pytest.approx(near.x_final, abs=1e-9)
    s_curve_peak = baselines(cfg.with_(x_contact=x_contact), limits, DURATION)["s_curve"]
    assert s.peak_force < s_curve_peak.peak_force
    assert planner.clamping_creeps(max(2, planner.n2 // 10))  # the preset's mold keeps it
    if x_contact == 0.0515:  # the command too (a zero bound divided by zero there)
        assert main(["plan", "--x-contact", str(x_contact), "--duration", str(DURATION),
                     "--json"]) == 0
        report = json.loads(capsys.readouterr().out)
        assert report["gap_to_bound_percent"] is None or report["peak_force_lower_bound"] > 0


def test_sm55_plans():
    mech = replace(load_preset("lin2003_sm55"), dynamics=Dynamics(**SM55_MASSES))
    cfg = plan_config(mech)
    limits = drive_limits(mech)
    assert limits.velocity == pytest.approx(2000 / 60 * (30 / 42) * 0.020)
    planner = planner_for(cfg, limits, intervals=100)
    plan = planner.solve(1.5)
    base = baselines(cfg, limits, plan.duration)
    assert plan.peak_force < min(b.peak_force for b in base.values())
    assert plan.peak_force <= limits.force(mech.drive)


def test_plan_config_is_the_plants_configuration_with_the_preset_clamp_force():
    """One plant configuration (the FMU's) and one contact solver: the default mold is the
    preset's clamp force held by the plant, exactly what --clamp-force of it gives."""
    from toggle.plant import configure

    cfg = plan_config("chang2021", errors={"r8": 0.25e-3}, masses={"platen": 4.0})
    same = configure("chang2021", errors={"r8": 0.25e-3}, masses={"platen": 4.0})
    assert cfg.mechanism == same.mechanism
    force = cfg.mechanism.clamp.final_tiebar_force
    assert cfg.x_contact == plan_config("chang2021", errors={"r8": 0.25e-3}, masses={
        "platen": 4.0}, clamp_force=force).x_contact
    held = plant_outputs(clamp_stroke(cfg.mechanism)[1], 0.0, 0.0, cfg).clamp_force
    assert float(held) == pytest.approx(force, rel=1e-9)


def test_dimension_errors_are_named_as_the_fmu_names_them():
    from fmu_src.toggle_clamp_fmu import ERRORS as FMU_ERRORS
    from toggle_cli.plan_setup import ERRORS

    assert ERRORS == FMU_ERRORS
    nominal = plan_config("chang2021")
    longer = plan_config("chang2021", errors={"r8": 0.25e-3}, x_contact=nominal.x_contact)
    assert longer.mechanism.upper.r5 == pytest.approx(nominal.mechanism.upper.r5 + 0.25e-3)


@settings(max_examples=30, deadline=None)
@given(duration=st.floats(1.0, 20.0), jerk=st.sampled_from([math.inf, 8.0, 0.5]))
def test_baselines_take_the_duration_within_the_limits(duration, jerk):
    S, v, a = 0.055, 0.04, 0.4
    if duration < minimum_time(S, v, a, jerk):
        return
    prof = s_curve(0.0, S, duration, v, a, jerk)
    t = np.linspace(0, prof.duration, 2001)
    x, vel, acc = prof.sample(t)
    assert prof.duration == pytest.approx(duration, rel=1e-9)
    assert x[-1] == pytest.approx(S, abs=1e-12) and abs(vel[-1]) < 1e-12
    assert vel.max() <= v * (1 + 1e-9) and np.abs(acc).max() <= a * (1 + 1e-9)
    assert np.all(np.diff(x) >= -1e-15)
