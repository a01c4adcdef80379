"""Issue 18: the hysteretic rig model against seed 000's Tables 3-8, and its invariants."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.host.backends import RigSetup
from toggle.asymmetry import (
    AsymmetryParams,
    advance_slip_state,
    asymmetry,
    hysteretic_force,
    slip_state_along,
)
from toggle.kinematics import stroke_limits
from toggle.params import load_preset
from toggle.plant import (
    CompiledPlant,
    DriveState,
    HystereticPlant,
    PlantConfig,
    plant_outputs,
)
from toggle.rig_calibration import (
    FORCE_FITTABLE,
    RELATIVE,
    RigModel,
    calibrate_rig,
    compare_tables,
    load_paper_tables,
    simulate_tables,
)
from toggle.rig_calibration import _start as _start  # noqa: PLC2701 (the fit's start)
from toggle.rig_tables import (
    CHANG2021_AS_BUILT,
    CHANG2021_DYNAMICS,
    rig_config,
    rig_dynamics,
    rig_errors,
)
from toggle_cli import main

NOMINAL = load_preset("chang2021")
X_OPEN, X_TP = stroke_limits(NOMINAL.lower)
#: Rows of the predicted Tables 5 and 8 (25 mm/s) the shipped model misses, as
#: (statistic, delta_r8 in mm); asserted to miss, so an improvement is noticed.
#: docs/unequal-halves-results.md section 9.6 says why (delta_r8 = 0: by the printed 3 sigma).
KNOWN_MISSES = {
    ("force_forward_max", 0.0), ("force_forward_rms", 0.0), ("force_backward_min", 0.0),
    ("force_backward_rms", 0.0),
}


@pytest.fixture(scope="module")
def tables():
    return load_paper_tables()


@pytest.fixture(scope="module")
def shipped(tables):
    """Every statistic of the shipped (calibrated) rig model, side by side with the paper."""
    rows = compare_tables(tables, simulate_tables(tables, NOMINAL, RigModel()))
    print("\n| statistic | v mm/s | dr8 mm | measured | simulated | res/3sigma | rel % | ok |")
    for r in rows:
        s = 1e3 if r.statistic == "stroke" else 1.0
        print(f"| {r.statistic} | {r.speed * 1e3:g} | {r.error * 1e3:.2f} | "
              f"{r.measured * s:.3f} ± {r.three_sigma * s:.3f} | {r.simulated * s:.3f} | "
              f"{r.in_sigma:+.1f} | {100 * r.relative:+.1f} | {r.holds()} |")
    return rows


# ---- the slip state and the lost take-up: invariants --------------------------------------


@settings(max_examples=40, deadline=None)
@given(z=st.floats(-1, 1), dx1=st.floats(0, 2e-3), dx2=st.floats(0, 2e-3),
       sign=st.sampled_from([-1.0, 1.0]), slip=st.floats(1e-6, 1e-3))
def test_slip_state_steps_compose_exactly_and_stay_bounded(z, dx1, dx2, sign, slip):
    once = advance_slip_state(z, sign * (dx1 + dx2), slip)
    twice = advance_slip_state(advance_slip_state(z, sign * dx1, slip), sign * dx2, slip)
    assert once == pytest.approx(twice, abs=1e-12)
    assert -1.0 <= once <= 1.0
    assert advance_slip_state(z, 0.0, slip) == z  # at rest the friction holds


@settings(max_examples=25, deadline=None)
@given(x=st.floats(X_OPEN, X_TP), v=st.floats(-0.03, 0.03), z=st.floats(-1, 1),
       takeup=st.floats(0, 1))
def test_equal_halves_add_exactly_nothing_in_any_slip_state(x, v, z, takeup):
    params = AsymmetryParams(takeup_return=takeup)
    out = asymmetry(x, v, NOMINAL.lower, NOMINAL.lower, params)
    assert hysteretic_force(out, z) == 0.0 and out.dissipation == 0.0


@settings(max_examples=20, deadline=None)
@given(dr8=st.floats(0.1e-3, 0.75e-3), a=st.floats(0.0, 0.8), b=st.floats(0.0, 1.0),
       speeds=st.lists(st.floats(1e-3, 3e-2), min_size=4, max_size=4),
       takeup=st.floats(0, 1), slip=st.floats(1e-5, 1e-3), platen=st.floats(0, 50),
       rate=st.floats(0, 5), play=st.floats(0, 0.3e-3))
def test_closed_cycle_work_is_non_negative(dr8, a, b, speeds, takeup, slip, platen, rate,
                                           play):
    """Two back-and-forth cycles between random points at random speeds: the second
    (closed, the slip state periodic to rounding) takes work >= 0 from the drive, with the
    platen's friction and a free play too (the whole plant at constant speed)."""
    lo = X_OPEN + a * (X_TP - X_OPEN) * 0.9
    hi = lo + max(b * (X_TP - lo), 1e-3) if lo + 1e-3 < X_TP else X_TP
    lo = min(lo, hi - 1e-3)
    nominal = NOMINAL.with_error("upper", "r5", dr8)
    mech = replace(nominal, dynamics=replace(nominal.dynamics, platen_friction=platen,
                                             platen_rate=rate))
    params = AsymmetryParams(takeup_return=takeup, slip_distance=slip, free_play=play)
    cfg = PlantConfig(mech, asymmetry=params)
    grid = np.linspace(lo, hi, 400)
    z, work = -1.0, []
    for cycle in range(2):
        total = 0.0
        for k, path in enumerate((grid, grid[::-1])):
            v = speeds[2 * cycle + k] * (1 if k == 0 else -1)
            zs = slip_state_along(path, z, slip)
            force = plant_outputs(path, v, 0.0, cfg, slip_state=zs).input_force
            total += float(np.sum(0.5 * (force[1:] + force[:-1]) * np.diff(path)))
            z = float(zs[-1])
        work.append(total)
    assert work[1] >= -1e-9 * max(1.0, abs(work[0]))


def test_exact_derivatives_are_finite_within_the_free_play():
    """The planner differentiates the plant exactly (CasADi): with the rig's free play the
    halves' clearance stays open over part of the stroke, where the internal force is
    exactly 0 and its derivatives must be 0, not 0 times infinity (NaN)."""
    cfg = rig_config(NOMINAL, 0.0, AsymmetryParams())
    x, v = ca.SX.sym("x"), ca.SX.sym("v")
    out = plant_outputs(x, v, 0.0, cfg)
    jac = ca.Function("force_jacobian", [x, v], [out.input_force, ca.jacobian(out.input_force,
                                                                   ca.vertcat(x, v))])
    xs = np.linspace(X_OPEN, X_TP, 200)
    force, grad = (np.array(a) for a in jac.map(200)(xs, 10e-3))
    inside = np.asarray(asymmetry(xs, 10e-3, cfg.mechanism.lower, cfg.mechanism.upper,
                                  cfg.asymmetry).internal_force) == 0
    assert 0 < inside.sum() < len(xs)  # the clearance is open over part of the stroke
    assert np.all(np.isfinite(force)) and np.all(np.isfinite(grad))


def test_steady_sliding_is_the_stateless_plant():
    """Far from a reversal the slip state is the sign of v: the stateful plant equals the
    stateless one (which the planner and today's FMU use)."""
    cfg = PlantConfig(NOMINAL.with_error("upper", "r5", 0.5e-3))
    plant = CompiledPlant(cfg)
    stepped = HystereticPlant(cfg, slip_state=-1.0)
    x, h, v = 0.040, 1e-3, 10e-3
    for _ in range(300):  # 3 mm forward, thirty slip distances
        x += v * h
        out = stepped(DriveState(x, v, 0.0, x))
    assert out.input_force == pytest.approx(plant(x, v, 0.0).input_force, rel=1e-6)
    back = stepped(DriveState(x - 1e-6, -v, 0.0, x - 1e-6))  # 1 um back: the friction turns slowly
    assert back.input_force > 0.9 * out.input_force > 0
    assert plant(x - 1e-6, -v, 0.0).input_force < 0


# ---- Tables 3-8: calibrated on 6-7 (and 3-4), predicting 8 (and 5) ------------------------


def test_forces_and_stroke_of_the_predicted_tables(shipped):
    """Table 8 and Table 5 (25 mm/s) predicted by the model fitted on 5 and 15 mm/s: every
    row asserted, each within 25 % or the printed 3 sigma (stroke: 0.05 mm; delta_r8 = 0:
    the printed 3 sigma only) except the listed misses, which are asserted to miss."""
    predicted = [r for r in shipped if r.speed == pytest.approx(25e-3)]
    assert len(predicted) == 24
    for r in predicted:
        key = (r.statistic, round(r.error * 1e3, 2))
        assert r.holds() == (key not in KNOWN_MISSES), (key, r)
    # every force at 0.25-0.75 mm within 25 % (not only within 3 sigma)
    for r in predicted:
        if r.error > 0 and r.statistic != "stroke":
            assert abs(r.relative) <= RELATIVE, r


def test_the_prototypes_own_error_makes_the_zero_rows(shipped):
    """delta_r8 = 0: the platen's friction and the as-built error give the forces along the
    stroke (equal halves gave ~0 N) and still almost nothing at the toggle: every F_TP
    within its band; the other forces within a factor of 2 of the measured, with their
    sign (section 9.6 says why not within 3 sigma), except the 5 mm/s backward rows, whose
    -147 N and 60 N RMS are three and two times the other speeds'."""
    for r in shipped:
        if r.error != 0 or r.statistic == "stroke":
            continue
        if r.statistic == "force_toggle":
            assert abs(r.in_sigma) <= 1.0, r
        elif not (r.speed == pytest.approx(5e-3) and "backward" in r.statistic):
            assert 0.5 <= r.simulated / r.measured <= 2.0, r


def test_the_zero_error_series_are_unlike_every_other_series(tables):
    """The premise of why the delta_r8 = 0 rows at 25 mm/s are not predicted (docs section
    9.9), checked on the data: (1) at 15 and 25 mm/s their forward stroke has a short spike,
    F_F(max) / F_F(rms) 5.6 and 4.6, more than 1.5 times the largest of the ten other series
    (2.9); (2) the direction asymmetry F_F(max) + F_B(min), which in the model comes from
    the conservative (speed-independent) force, flips from -81 N at 5 mm/s to +68 N at
    15 mm/s, beyond the combined printed 3 sigma, where no other series moves by more than
    25 N."""
    mean, band = tables.mean, tables.three_sigma
    crest = mean["force_forward_max"] / mean["force_forward_rms"]
    others = np.delete(crest, 0, axis=1).ravel().tolist() + [crest[0, 0]]
    assert len(others) == 10
    assert min(crest[1, 0], crest[2, 0]) > 1.5 * max(others)
    asym = mean["force_forward_max"] + mean["force_backward_min"]
    spread = band["force_forward_max"] + band["force_backward_min"]
    assert asym[0, 0] + spread[0, 0] < 0 < asym[1, 0] - spread[1, 0]
    assert asym[1, 0] - asym[0, 0] > 140
    assert np.ptp(asym[:, 1:], axis=0).max() < 25


def test_a_run_is_compared_with_the_paper_only_where_it_repeats_a_condition():
    """The run summary's Tables 3-8 column: a --speed run of chang2021 at one of the tables'
    speeds and link-8 errors gets that cell (Table 3 + i for the stroke, 6 + i for forces),
    anything else (the default planned job, another error, another preset) none."""
    from dataclasses import replace as replace_settings

    from hil.cli.main import build_parser
    from hil.cli.run import paper_statistics
    from hil.host.run_settings import resolve_settings

    def settings(*argv: str):
        return resolve_settings(build_parser().parse_args(["run", *argv]))

    def paper(*argv: str):
        return paper_statistics(settings(*argv))

    cell = paper("--speed", "15e-3", "--delta-r8", "0.5e-3")
    assert cell["force_toggle"] == {"table": 7, "mean": 122.541, "three_sigma": 11.237}
    assert cell["stroke"]["table"] == 4 and cell["stroke"]["mean"] == pytest.approx(45.564e-3)
    assert paper("--speed", "15e-3", "--delta-r8", "0.3e-3") is None
    assert paper("--delta-r8", "0.5e-3") is None  # the planned job: no table repeats it
    other = replace_settings(settings("--speed", "15e-3"), preset="lin2003_sm55")
    assert paper_statistics(other) is None


def test_measured_stroke_from_the_reading_model(shipped):
    """The stroke reads 0.38-0.67 mm over the 45.003 mm of theory (measured: 0.38-0.56)."""
    for r in shipped:
        if r.statistic == "stroke":
            assert 0.38e-3 <= r.simulated - 45.003e-3 <= 0.67e-3


def test_calibration_recovers_known_parameters_with_their_uncertainty(tables):
    """Synthetic tables from a known model (an as-built error and a stiffness off the
    shipped ones): fitting both on one speed from the shipped values and from a far start
    (the least cost kept) recovers them, with finite reported errors."""
    truth = RigModel().with_values({"as_built_r1U": 1.0e-3, "drive_stiffness": 2.0e5})
    synthetic = simulate_tables(tables, NOMINAL, truth)
    data = type(tables)(tables.speeds, tables.errors, synthetic, tables.three_sigma)
    fit = calibrate_rig(data, NOMINAL, [15e-3], ["as_built_r1U", "drive_stiffness"],
                        statistics=["force_forward_max", "force_forward_rms", "force_toggle"],
                        starts=[{"as_built_r1U": 0.3e-3, "drive_stiffness": 1e6}])
    assert fit.cost < 1e-12
    assert fit.values["as_built_r1U"] == pytest.approx(1.0e-3, rel=1e-3)
    assert fit.values["drive_stiffness"] == pytest.approx(2.0e5, rel=1e-3)
    assert all(math.isfinite(e) for e in fit.std_error.values())


def test_the_as_built_error_is_the_rigs_not_the_models():
    """The preset stays symmetric (equal halves add exactly nothing) and without the platen's
    friction; the simulated rig of chang2021 (rig tables, hil run's FMU, the emulator: one
    rig_errors, one rig_dynamics) adds its as-built error to delta_r8 and its platen's
    friction; a preset without a rig gets delta_r8 alone."""
    assert NOMINAL.symmetric and NOMINAL.dynamics.platen_friction == 0
    assert rig_errors("chang2021", 0.5e-3) == {**CHANG2021_AS_BUILT,
                                               "r8": CHANG2021_AS_BUILT.get("r8", 0.0) + 0.5e-3}
    assert rig_errors("lin2003_sm55", 0.5e-3) == {"r8": 0.5e-3}
    assert RigSetup(delta_r8=0.25e-3).errors == rig_errors("chang2021", 0.25e-3)
    params = AsymmetryParams()
    assert not rig_config(NOMINAL, 0.0, params).mechanism.symmetric
    assert rig_dynamics("chang2021") == CHANG2021_DYNAMICS and rig_dynamics("li_micro") == {}
    assert RigSetup().dynamics == CHANG2021_DYNAMICS and RigSetup(as_built=False).dynamics == {}
    bare = rig_config(NOMINAL, 0.0, params, dynamics={}, as_built={})
    assert bare.mechanism == NOMINAL
    xs = np.linspace(X_OPEN, X_TP, 50)
    out = plant_outputs(xs, 10e-3, 0.0, bare, slip_state=0.3)
    model = plant_outputs(xs, 10e-3, 0.0, PlantConfig(NOMINAL), slip_state=0.3)
    assert np.array_equal(out.input_force, model.input_force)


def test_every_fittable_parameter_starts_where_its_model_value_is_an_end(tables):
    """A parameter the help lists as fittable, sitting at an end of its transform (a
    friction the preset does not have at 0, the film law's h_s = inf, no free play, a
    share of 0 or 1), starts the fit at a finite point (it failed with 'math domain
    error' and 'array must not contain infs or NaNs'); a fit from there converges."""
    ends = {"log": (0.0, math.inf), "logit": (0.0, 1.0), "length": (0.0,), "time": (0.0,)}
    model = RigModel()
    for name, kind in FORCE_FITTABLE.items():
        assert math.isfinite(_start(name, kind, model.value(name))), name
        for value in ends[kind]:
            try:
                model.with_values({name: value})
            except (ValueError, TypeError):
                continue  # outside the parameter's range: a fit never sits there
            assert math.isfinite(_start(name, kind, value)), (name, value)
    for name in ("guide_friction", "hersey_transition"):
        fit = calibrate_rig(tables, NOMINAL, [5e-3], [name], ["force_forward_rms"])
        assert math.isfinite(fit.values[name]) and fit.values[name] > 0
        assert math.isfinite(fit.cost)


def test_a_parameter_ending_at_a_limit_of_the_model_is_reported_held(tables):
    """mu cannot fall: the shipped rate law is at its limit of zero friction at rest, which
    the model refuses beyond. Its difference step crossed the refusal, so its standard
    error came out as 3.5e-8 (a meaningless certainty); it is now reported at a limit,
    without one, and the free parameter's error is computed without its column."""
    fit = calibrate_rig(tables, NOMINAL, [15e-3], ["mu", "free_play"],
                        ["force_toggle", "force_forward_rms"])
    assert fit.at_limit == ("mu",)
    assert math.isnan(fit.std_error["mu"]) and fit.values["mu"] == pytest.approx(0.3, abs=1e-3)
    assert 0 < fit.std_error["free_play"] < fit.values["free_play"]


def test_calibration_refuses_bad_requests(tables):
    with pytest.raises(ValueError, match="cannot fit"):
        calibrate_rig(tables, NOMINAL, [5e-3], ["nonsense"])
    with pytest.raises(ValueError, match="no table"):
        calibrate_rig(tables, NOMINAL, [7e-3], ["mu"])
    with pytest.raises(ValueError, match="at most"):
        calibrate_rig(tables, NOMINAL, [5e-3], ["mu", "mu"])


def test_tables_cli_json_and_figures(tmp_path, capsys):
    assert main(["tables", "--json", "--out", str(tmp_path)]) == 0
    out = json.loads(capsys.readouterr().out)  # stdout is the JSON alone
    assert len(out["rows"]) == 72
    assert sorted(out["figures"]) == sorted(str(p) for p in tmp_path.glob("*.png"))
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs == sorted(f"tables_{s}.png" for s in (
        "force_forward_max", "force_forward_rms", "force_backward_min",
        "force_backward_rms", "force_toggle", "stroke"))


def test_hil_run_at_0_75_mm_stays_under_the_force_limit_and_matches_table8(tmp_path, tables,
                                                                           capsys):
    """``hil run --delta-r8 0.75e-3 --speed 25e-3 --cycles 2`` with the default 400 N limit
    completes with the rig's as-built error recorded; its F_TP (read as the rig read it) and
    F_F(max) are within 25 % of Table 8, and its summary prints them beside Table 8's."""
    from hil.cli.main import main as hil_main

    out = tmp_path / "run"
    assert hil_main(["run", "--delta-r8", "0.75e-3", "--speed", "25e-3", "--cycles", "2",
                     "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "Table 8: 300.124 +- 23.999 N" in printed and "Table 5: 45.557" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cycles_complete"] == 2 and not summary["aborted"]
    meta = json.loads((out / "meta.json").read_text())  # the rig's errors: as built + dr8
    assert meta["plant"]["dimensional_errors_m"] == rig_errors("chang2021", 0.75e-3)
    assert meta["plant"]["dynamics_beyond_preset"] == CHANG2021_DYNAMICS
    i, j = tables.speed_index(25e-3), 3
    for key in ("force_toggle", "force_forward_max"):
        measured = tables.mean[key][i, j]
        assert summary[key]["mean"] == pytest.approx(measured, rel=RELATIVE), key
