"""Unequal halves (issue 8): calibration on Tables 6 (and 7), prediction of 7-8, invariants."""

from __future__ import annotations

import json
import math
import re

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toggle.asymmetry import (
    AsymmetryError,
    AsymmetryParams,
    asymmetry,
    extra_input_force,
    force_curves,
    toggle_force,
)
from toggle.calibration import calibrate, compare, load_force_table
from toggle.kinematics import AssemblyError
from toggle.params import load_preset
from toggle_cli import main

MECH = load_preset("chang2021")
#: Prediction tolerance for Tables 7-8 (issue 8).
RELATIVE = 0.25
#: Issue 8's calibration on F_TP alone (Tables 6 and 7), the stateless model: the take-up all
#: returned, film friction. The shipped defaults are issue 18's fit of every statistic
#: (tests/test_rig_tables.py); these tests keep the F_TP-only calibration honest.
ISSUE8 = AsymmetryParams(free_play=0.1250e-3, contact_stiffness=8.675e8, drive_stiffness=1.0e5,
                         rate_strengthening=0.02, hersey_transition=8.732e-7, takeup_return=1.0)
#: Boundary lubrication only: the friction law a single-speed table can calibrate.
BOUNDARY = ISSUE8.replace(hersey_transition=math.inf)
#: Rows a Table-6-only calibration does not predict (docs/unequal-halves.md, section 6): at
#: delta_r8 = 0.25 mm the measured F_TP falls with speed (28.7, 22.6, 18.2 N) while it
#: rises at 0.5 and 0.75 mm; the load-dependent film that explains it needs a second speed.
NOT_FROM_TABLE6 = {(15e-3, 0.25e-3), (25e-3, 0.25e-3)}


@pytest.fixture(scope="module")
def table():
    return load_force_table()


@pytest.fixture(scope="module")
def table6_only(table):
    """Calibrated on Table 6 alone: stiffness and free play, boundary friction."""
    cal = calibrate(table, MECH, 5e-3, fit=("free_play", "contact_stiffness"), start=BOUNDARY)
    return cal, compare(table, MECH, cal.params)


@pytest.fixture(scope="module")
def tables67(table):
    """Calibrated on Tables 6 and 7 (three parameters): issue 8's values."""
    cal = calibrate(table, MECH, (5e-3, 15e-3),
                    fit=("free_play", "contact_stiffness", "hersey_transition"),
                    start=ISSUE8.replace(free_play=0.1e-3, contact_stiffness=1e9,
                                         hersey_transition=3e-6))
    return cal, compare(table, MECH, cal.params)


def _print(title, rows) -> None:
    print(f"\n{title}\n v mm/s  dr8 mm   F_TP meas  +-3sigma    model   rel.err")
    for r in rows:
        print(f"{r.speed * 1e3:7.0f} {r.error * 1e3:7.2f} {r.measured:11.3f} {r.three_sigma:9.3f}"
              f" {r.model:8.2f} {100 * r.relative_error:8.1f}%")


def _at(rows, speed):
    return [r for r in rows if np.isclose(r.speed, speed)]


def _holds(r) -> bool:
    """Issue 8's criterion: 25 % of the mean; the delta_r8 = 0 rows (F_TP ~ 1 N, band 3-4 N)
    by their absolute band, where a relative error means nothing."""
    return r.within_band if r.error == 0 else abs(r.relative_error) <= RELATIVE


def test_table6_alone_reproduces_table6_and_misses_the_light_rows_at_speed(table6_only):
    cal, rows = table6_only
    _print("calibrated on Table 6 alone (boundary friction)", rows)
    assert len(cal.fitted) <= 3 and cal.speeds == (5e-3,)
    assert all(r.within_band for r in _at(rows, 5e-3))
    for r in _at(rows, 15e-3) + _at(rows, 25e-3):
        key = (round(r.speed, 6), round(r.error, 7))
        assert _holds(r) != (key in NOT_FROM_TABLE6), r


def test_tables_6_7_calibration_is_issue8s_and_predicts_table8(tables67):
    cal, rows = tables67
    _print("calibrated on Tables 6 and 7 (film friction); Table 8 predicted", rows)
    default = ISSUE8
    for name in cal.fitted:  # converged from elsewhere to the shipped defaults (docs table)
        assert getattr(cal.params, name) == pytest.approx(getattr(default, name), rel=0.02)
    assert all(r.within_band for r in _at(rows, 5e-3) + _at(rows, 15e-3))
    table8 = _at(rows, 25e-3)
    assert len(table8) == 4 and all(_holds(r) for r in table8), table8
    # the measured speed trends: F_TP falls with speed at 0.25 mm, rises at 0.5 and 0.75 mm
    for error, sign in ((0.25e-3, -1), (0.5e-3, 1), (0.75e-3, 1)):
        model = [r.model for r in rows if r.error == error]
        assert np.all(sign * np.diff(model) > 0), (error, model)


def test_the_lubricant_film_only_lowers_friction():
    mech = MECH.with_error("upper", "r5", 0.5e-3)
    xs = np.linspace(0.0, 51.5e-3, 40)
    for speed in (5e-3, 25e-3):
        film = asymmetry(xs, speed, mech.lower, mech.upper, ISSUE8).friction
        boundary = asymmetry(xs, speed, mech.lower, mech.upper, BOUNDARY).friction
        assert np.all(film <= boundary + 1e-12) and np.all(film >= 0)
    # the lighter the load, the larger the drop (the Hersey ratio is slip speed / load)
    drop = [1 - toggle_force(MECH.with_error("upper", "r5", e), 25e-3, ISSUE8)
            / toggle_force(MECH.with_error("upper", "r5", e), 25e-3, BOUNDARY)
            for e in (0.25e-3, 0.75e-3)]
    assert drop[0] > drop[1] > 0


def test_equal_halves_add_no_force():
    xs = np.linspace(-3e-3, 51.5e-3, 50)
    for dims in (MECH.lower, MECH.lower.replace(r3=MECH.lower.r3 + 0.1e-3)):
        out = asymmetry(xs, 5e-3, dims, dims)
        assert np.all(out.force == 0) and np.all(out.internal_force == 0)
    assert extra_input_force(0.04, -0.02, MECH.lower, MECH.lower) == 0


def test_small_error_within_free_play_adds_no_force():
    mech = MECH.with_error("upper", "r5", 0.5 * ISSUE8.free_play)
    _, fwd, back = force_curves(mech, 5e-3, ISSUE8, points=50)
    assert np.all(fwd == 0) and np.all(back == 0)


@settings(max_examples=8, deadline=None)
@given(dr8=st.floats(-0.6e-3, 0.75e-3), dr3=st.floats(-0.1e-3, 0.1e-3),
       speed=st.floats(1e-3, 30e-3))
def test_closed_cycle_work_is_non_negative(dr8, dr3, speed):
    mech = MECH.with_error("upper", "r5", dr8).with_error("lower", "r3", dr3)
    xs, fwd, back = force_curves(mech, speed, points=400)
    work = np.trapezoid(fwd, xs) - np.trapezoid(back, xs)  # forward, then back along -x
    assert work >= -1e-9
    assert np.all(fwd >= asymmetry(xs, 0.0, mech.lower, mech.upper).force - 1e-9)


def test_force_rises_near_end_of_forward_stroke():
    mech = MECH.with_error("upper", "r5", 0.5e-3)
    xs, fwd, _ = force_curves(mech, 5e-3, points=200)
    early, late = fwd[xs < 30e-3], fwd[xs >= 35e-3]
    # 3x and 15x since issue 18's refit with the as-built error (a stiffer drive side,
    # 2.6e5 N/m per half, spreads the force over the stroke); 5x and 20x before
    assert late.max() > 3 * early.max()
    assert fwd[-1] > 15 * fwd[0]


def test_symbolic_matches_numeric():
    x, v = ca.SX.sym("x"), ca.SX.sym("v")
    upper = MECH.with_error("upper", "r5", 0.5e-3).upper
    expr = extra_input_force(x, v, MECH.lower, upper)
    f = ca.Function("f", [x, v], [expr])
    assert float(f(0.045, 0.01)) == pytest.approx(
        float(extra_input_force(0.045, 0.01, MECH.lower, upper)), rel=1e-12)


def test_bad_input_raises_clear_errors():
    with pytest.raises(AssemblyError, match="upper half"):
        asymmetry(0.05, 5e-3, MECH.lower, MECH.upper.replace(r3=5e-3))
    with pytest.raises(AsymmetryError, match="cannot be forced together"):
        asymmetry(0.05, 5e-3, MECH.lower, MECH.upper.replace(r5=MECH.upper.r5 + 5e-3))
    for bad in ({"free_play": -1e-6}, {"mu": 1.5}, {"contact_stiffness": float("nan")},
                {"mu": 0.01, "rate_strengthening": 0.05}, {"hersey_transition": 0.0},
                {"contact_stiffness": math.inf}):
        with pytest.raises(AsymmetryError):
            AsymmetryParams(**bad)
    with pytest.raises(AsymmetryError, match="speed"):
        asymmetry(0.05, float("inf"), MECH.lower, MECH.upper)


def test_calibration_rejects_more_than_three_parameters(table):
    with pytest.raises(ValueError, match="1 to 3"):
        calibrate(table, MECH, 5e-3,
                  fit=("free_play", "contact_stiffness", "mu", "drive_stiffness"))
    with pytest.raises(ValueError, match="no data"):
        calibrate(table, MECH, 7e-3)


def test_cli_json(capsys):
    assert main(["asymmetry", "--delta-r8", "0.5e-3", "--speed", "5e-3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["force_toggle"] == pytest.approx(
        float(asymmetry(out["x_toggle"], 5e-3, MECH.lower,
                        MECH.with_error("upper", "r5", 0.5e-3).upper).force))
    with pytest.raises(SystemExit) as info:  # a usage error, as in toggle plot asymmetry
        main(["asymmetry", "--speed=-1"])
    assert info.value.code == 2


def test_the_plant_adds_the_extra_force_only_for_unequal_halves():
    """The FMU, the simulated rig and the emulator all get the model through the plant."""
    import numpy as np

    from toggle.kinematics import stroke_limits
    from toggle.params import load_preset
    from toggle.plant import PlantConfig, plant_outputs

    mech = load_preset("chang2021")
    xs = np.linspace(*stroke_limits(mech.lower), 50)
    equal = plant_outputs(xs, 5e-3, 0.0, PlantConfig(mech)).input_force
    unequal = plant_outputs(xs, 5e-3, 0.0,
                            PlantConfig(mech.with_error("upper", "r5", 0.5e-3))).input_force
    assert np.all(unequal >= equal - 1e-9) and np.max(unequal - equal) > 50


def test_calibrate_cli(capsys):
    assert main(["calibrate", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["fitted"]) == {"free_play", "contact_stiffness", "hersey_transition"}
    assert all(math.isfinite(v) and v >= 0 for v in out["fitted"].values())
    assert len(out["rows"]) == 12 and out["calibration_speeds"] == [5e-3, 15e-3]
    assert main(["calibrate", "--speeds", "7e-3"]) == 2  # no such row: a clear error


@pytest.mark.parametrize("text, missing", [
    ('name = "a preset, not a table"\n', "[tables.force_toggle]"),
    ("speed = [5.0]\ndelta_r8 = [0.0]\n[tables.other]\nmean = [[1.0]]\n",
     "[tables.force_toggle]"),
    ("delta_r8 = [0.0]\n[tables.force_toggle]\nmean = [[1.0]]\nthree_sigma = [[1.0]]\n",
     "'speed'"),
])
def test_a_file_that_is_not_a_force_table_is_named_with_what_it_lacks(tmp_path, text, missing):
    """A preset given to toggle calibrate --table was refused with "...: 'tables'"."""
    path = tmp_path / "t.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"it has no {re.escape(missing)}"):
        load_force_table(path)
