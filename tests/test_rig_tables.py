"""Issue 18: the hysteretic rig model against seed 000's Tables 3-8, and its invariants."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toggle.asymmetry import (
    AsymmetryParams,
    advance_slip_state,
    asymmetry,
    hysteretic_force,
    slip_state_along,
)
from toggle.cli import main
from toggle.kinematics import stroke_limits
from toggle.params import load_preset
from toggle.plant import CompiledPlant, DriveState, HystereticPlant, PlantConfig
from toggle.rig_calibration import (
    RELATIVE,
    RigModel,
    calibrate_rig,
    compare_tables,
    load_paper_tables,
    simulate_tables,
)

NOMINAL = load_preset("chang2021")
X_OPEN, X_TP = stroke_limits(NOMINAL.lower)
#: Rows of the predicted Tables 5 and 8 (delta_r8 > 0) the shipped model misses, as
#: (statistic, delta_r8 in mm); asserted to miss, so an improvement is noticed.
#: docs/unequal-halves.md section 9 says why.
KNOWN_MISSES = {
    ("force_forward_max", 0.25), ("force_backward_min", 0.25), ("force_backward_rms", 0.25),
    ("force_toggle", 0.25), ("stroke", 0.75),
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
       takeup=st.floats(0, 1), slip=st.floats(1e-5, 1e-3))
def test_closed_cycle_work_is_non_negative(dr8, a, b, speeds, takeup, slip):
    """Two back-and-forth cycles between random points at random speeds: the second
    (closed, the slip state periodic to rounding) takes work >= 0 from the drive."""
    lo = X_OPEN + a * (X_TP - X_OPEN) * 0.9
    hi = lo + max(b * (X_TP - lo), 1e-3) if lo + 1e-3 < X_TP else X_TP
    lo = min(lo, hi - 1e-3)
    mech = NOMINAL.with_error("upper", "r5", dr8)
    params = AsymmetryParams(takeup_return=takeup, slip_distance=slip)
    grid = np.linspace(lo, hi, 400)
    z, work = -1.0, []
    for cycle in range(2):
        total = 0.0
        for k, path in enumerate((grid, grid[::-1])):
            v = speeds[2 * cycle + k] * (1 if k == 0 else -1)
            zs = slip_state_along(path, z, slip)
            force = hysteretic_force(asymmetry(path, v, mech.lower, mech.upper, params), zs)
            total += float(np.sum(0.5 * (force[1:] + force[:-1]) * np.diff(path)))
            z = float(zs[-1])
        work.append(total)
    assert work[1] >= -1e-9 * max(1.0, abs(work[0]))


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
    """Table 8 and Table 5 (25 mm/s) predicted by the model fitted on 5 and 15 mm/s: each
    delta_r8 > 0 row within 25 % or the printed 3 sigma (stroke: 0.05 mm), except the
    listed misses; the F_TP = 0 row within its absolute band."""
    predicted = [r for r in shipped if r.speed == pytest.approx(25e-3)]
    for r in predicted:
        key = (r.statistic, round(r.error * 1e3, 2))
        if r.error == 0:
            continue
        assert r.holds() == (key not in KNOWN_MISSES), (key, r)
    tp0 = next(r for r in predicted if r.statistic == "force_toggle" and r.error == 0)
    assert abs(tp0.in_sigma) <= 1.0
    # the misses are near misses: every predicted force within 2 x the criterion at 0.5+ mm
    for r in predicted:
        if r.error >= 0.5e-3 and r.statistic != "stroke":
            assert abs(r.relative) <= 2 * RELATIVE, r


def test_the_forward_peak_and_antisymmetry_follow_the_data(shipped):
    """What the stateless model missed (issue 18): F_F(max) within 15 % of the measured
    at 0.75 mm, and the backward extreme at least 0.7 of the forward one."""
    by = {(r.statistic, r.speed, r.error): r for r in shipped}
    for v in (5e-3, 15e-3, 25e-3):
        fmax = by[("force_forward_max", v, 0.75e-3)]
        bmin = by[("force_backward_min", v, 0.75e-3)]
        assert abs(fmax.relative) <= 0.15
        assert -bmin.simulated >= 0.7 * fmax.simulated


def test_measured_stroke_from_the_reading_model(shipped):
    """The stroke reads 0.38-0.67 mm over the 45.003 mm of theory (measured: 0.38-0.56)."""
    for r in shipped:
        if r.statistic == "stroke":
            assert 0.38e-3 <= r.simulated - 45.003e-3 <= 0.67e-3


def test_calibration_recovers_a_known_parameter_with_its_uncertainty(tables):
    """Synthetic tables from a known model: fitting one parameter on one speed recovers it
    within two of its reported standard errors (and the reported error is finite)."""
    truth = RigModel().with_values({"drive_stiffness": 8.0e4})
    synthetic = simulate_tables(tables, NOMINAL, truth)
    data = type(tables)(tables.speeds, tables.errors, synthetic, tables.three_sigma)
    fit = calibrate_rig(data, NOMINAL, [5e-3], ["drive_stiffness"],
                        statistics=["force_forward_max", "force_toggle"])
    assert fit.values["drive_stiffness"] == pytest.approx(8.0e4, rel=1e-3)
    assert math.isfinite(fit.std_error["drive_stiffness"])


def test_calibration_refuses_bad_requests(tables):
    with pytest.raises(ValueError, match="cannot fit"):
        calibrate_rig(tables, NOMINAL, [5e-3], ["nonsense"])
    with pytest.raises(ValueError, match="no table"):
        calibrate_rig(tables, NOMINAL, [7e-3], ["mu"])
    with pytest.raises(ValueError, match="at most"):
        calibrate_rig(tables, NOMINAL, [5e-3], ["mu", "mu"])


def test_tables_cli_json_and_figures(tmp_path, capsys):
    assert main(["tables", "--json", "--plot", str(tmp_path)]) == 0
    out = json.loads(capsys.readouterr().out.split("\n", 6)[-1])
    assert len(out["rows"]) == 72
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs == sorted(f"tables_{s}.png" for s in (
        "force_forward_max", "force_forward_rms", "force_backward_min",
        "force_backward_rms", "force_toggle", "stroke"))


def test_hil_run_at_0_75_mm_stays_under_the_force_limit_and_matches_table8(tmp_path, tables):
    """``hil run --delta-r8 0.75e-3 --speed 25e-3 --cycles 2`` with the default 400 N limit
    completes; its F_TP (read as the rig read it) and F_F(max) are within 25 % of Table 8."""
    from hil.cli import main as hil_main

    out = tmp_path / "run"
    assert hil_main(["run", "--delta-r8", "0.75e-3", "--speed", "25e-3", "--cycles", "2",
                     "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cycles_complete"] == 2 and not summary["aborted"]
    i, j = tables.speed_index(25e-3), 3
    for key in ("force_toggle", "force_forward_max"):
        measured = tables.mean[key][i, j]
        assert summary[key]["mean"] == pytest.approx(measured, rel=RELATIVE), key
