"""Unequal halves (issue 8): calibration on Table 6, prediction of Tables 7-8, invariants."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toggle.asymmetry import AsymmetryError, AsymmetryParams, asymmetry, force_curves, toggle_force
from toggle.calibration import calibrate, compare, load_force_table
from toggle.kinematics import AssemblyError, stroke_limits
from toggle.params import load_preset
from toggle.plant import PlantConfig, plant_outputs

MECH = load_preset("chang2021")
TABLE = load_force_table()


@pytest.fixture(scope="module")
def calibrated():
    return calibrate(TABLE, MECH, 5e-3, fit=("free_play", "contact_stiffness"))


def test_calibrated_on_table6_reproduces_table6_within_three_sigma(calibrated):
    assert len(calibrated.fitted) <= 3
    rows = [c for c in compare(TABLE, MECH, calibrated.params) if c.speed == 5e-3]
    assert len(rows) == 4
    assert all(c.within_band for c in rows), rows


def test_prediction_of_tables7_and_8_side_by_side(calibrated):
    """Model (calibrated at 5 mm/s only) against the measured F_TP at 15 and 25 mm/s.

    Within 25 % where the link error dominates (delta_r8 = 0.5 and 0.75 mm). At 0 mm the
    measured forces (0.8-0.9 N) are noise around zero: the model gives 0 and must lie in
    the three-sigma band. At 0.25 mm the paper's own forces fall with speed (28.7, 22.6,
    18.2 N), unlike every other row: its other small errors partly cancel link 8's
    (section 5.1), which no model of delta_r8 alone can follow; reported, not asserted.
    """
    rows = [c for c in compare(TABLE, MECH, calibrated.params) if c.speed > 5e-3]
    table = "\n".join(
        f"v={c.speed * 1e3:4.0f} mm/s dr8={c.error * 1e3:4.2f} mm measured {c.measured:7.2f}"
        f" +-{c.three_sigma:5.2f} N model {c.model:7.2f} N ({c.relative_error:+.0%})"
        for c in rows)
    print(table)
    for c in rows:
        if c.error >= 0.5e-3:
            assert abs(c.relative_error) <= 0.25, table
        elif c.error == 0:
            assert c.within_band, table
    at_half = [c.model for c in rows if c.error == 0.5e-3]
    assert at_half[0] < at_half[1]  # the force rises with speed, as measured


def test_equal_halves_add_no_force():
    xs = np.linspace(*stroke_limits(MECH.lower), 50)
    out = asymmetry(xs, 5e-3, MECH.lower, MECH.upper)
    assert np.all(out.force == 0) and np.all(out.internal_force == 0)
    cfg = PlantConfig(MECH)
    unequal = PlantConfig(MECH.with_error("upper", "r5", 0.5e-3))
    a = plant_outputs(xs, 5e-3, 0.0, cfg).input_force
    b = plant_outputs(xs, 5e-3, 0.0, unequal).input_force
    assert np.all(b >= a - 1e-9) and np.max(b - a) > 50


def test_force_rises_near_the_end_of_the_forward_stroke():
    mech = MECH.with_error("upper", "r5", 0.5e-3)
    xs, fwd, back = force_curves(mech, 5e-3)
    early, late = fwd[xs < 0.02], fwd[xs >= 0.035]
    assert late.max() > 10 * max(early.max(), 1.0)
    assert np.all(back <= 1e-9)  # backward the friction opposes the motion


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 0.75e-3), st.floats(1e-3, 30e-3))
def test_a_closed_cycle_never_makes_energy(delta, speed):
    mech = MECH.with_error("upper", "r5", delta)
    xs, fwd, back = force_curves(mech, speed, points=400)
    work = np.trapezoid(fwd, xs) - np.trapezoid(back, xs)  # forward work + backward work
    assert work >= -1e-9
    assert np.all(fwd - back >= -1e-9)


def test_bad_input_gets_a_clear_error():
    with pytest.raises(AsymmetryError, match="free_play"):
        AsymmetryParams(free_play=-1e-3)
    with pytest.raises(AsymmetryError, match="mu"):
        AsymmetryParams(mu=3.0)
    with pytest.raises(AsymmetryError, match="speed"):
        toggle_force(MECH, -5e-3)
    with pytest.raises(AssemblyError):
        asymmetry(0.0, 5e-3, MECH.lower, MECH.upper.replace(r5=0.005, e=0.2))
    with pytest.raises(AsymmetryError, match="cannot be forced together"):
        toggle_force(MECH.with_error("upper", "r5", 3e-3), 5e-3,
                     AsymmetryParams(max_internal_force=1e3))
