"""Mechanical-error analysis (seed 000 section 3): sensitivities, Table 2, Monte Carlo."""

from __future__ import annotations

import math

import numpy as np
import pytest
from paper_closed_forms import error_coefficients, upper_pose

from toggle.iso286 import it_tolerance
from toggle.kinematics import half_pose, sensitivities, toggle_position
from toggle.params import DIMENSIONS, ParameterError
from toggle.tolerance import QUANTILES, asymmetry, it_tolerances, monte_carlo, percentiles

MM = 1e-3
UM = 1e-6


def lower_coefficients(x, d):
    p = half_pose(x, d)
    return error_coefficients(d, float(p.gamma1), float(p.gamma2), float(p.alpha4), float(p.l),
                              float(p.theta4), float(p.theta5), chain_sign=-1.0)


def upper_coefficients(x, d):
    p = upper_pose(x, d)
    return error_coefficients(d, p["gamma1"], p["gamma2"], p["alpha"], p["l"], p["theta7"],
                              p["theta8"], chain_sign=1.0)


@pytest.mark.parametrize("x_mm", [-3.0, 10.0, 30.0, 45.0, 51.566])
def test_ad_sensitivities_equal_paper_closed_forms(chang, x_mm):
    """Eqs 20-27 (lower) and 30-37 (upper), with an unequal upper half."""
    x = x_mm * MM
    upper = chang.upper.replace(r4b=chang.upper.r4b + 0.3 * MM, e=chang.upper.e - 0.2 * MM)
    for dims, oracle in ((chang.lower, lower_coefficients), (upper, upper_coefficients)):
        ad = sensitivities(x, dims)
        ref = oracle(x, dims)
        for k in DIMENSIONS:
            assert float(ad[k]) == pytest.approx(ref[k], rel=1e-9, abs=1e-12), k


def test_it_table_values_and_size_ranges():
    assert it_tolerance(10 * MM, 10) == pytest.approx(58 * UM)  # 10 is in "over 6 to 10"
    assert it_tolerance(10.001 * MM, 10) == pytest.approx(70 * UM)
    assert it_tolerance(45.162 * MM, 10) == pytest.approx(100 * UM)
    assert it_tolerance(64.071 * MM, 10) == pytest.approx(120 * UM)
    assert it_tolerance(100 * MM, 10) == pytest.approx(140 * UM)
    assert it_tolerance(500 * MM, 18) == pytest.approx(9700 * UM)
    assert it_tolerance(2 * MM, 1) == pytest.approx(0.8 * UM)
    with pytest.raises(ParameterError):
        it_tolerance(501 * MM, 10)
    with pytest.raises(ParameterError):
        it_tolerance(10 * MM, 19)


@pytest.mark.parametrize("grade", range(6, 13))
def test_table2_asymmetry_indices_equal_paper_equations(chang, grade):
    """Table 2 by Eqs 38-43 with the paper's closed forms and the full IT deviations."""
    x = toggle_position(chang.lower)
    tol = it_tolerances(chang, grade)
    lo = lower_coefficients(x, chang.lower)
    up = upper_coefficients(x, chang.upper)
    wor = sum(abs(lo[k] * tol["lower"][k]) + abs(up[k] * tol["upper"][k]) for k in DIMENSIONS)
    rss = math.sqrt(sum((lo[k] * tol["lower"][k]) ** 2 for k in DIMENSIONS)) + math.sqrt(
        sum((up[k] * tol["upper"][k]) ** 2 for k in DIMENSIONS))
    rep = asymmetry(chang, tol)
    assert rep.dL_wor == pytest.approx(wor, abs=1e-10)
    assert rep.dL_rss == pytest.approx(rss, abs=1e-10)
    # the toggle is insensitive to first order to all but r4b, r5 and e (seed-notes)
    assert rep.dL_wor == pytest.approx(
        2 * ((tol["lower"]["r4b"] + tol["lower"]["r5"]) / math.cos(math.asin(0.01 / 0.21))
             + tol["lower"]["e"] * math.tan(math.asin(0.01 / 0.21))), rel=1e-9)
    # exact re-solved asymmetry agrees with the linearised index to second order
    assert rep.dL_exact == pytest.approx(rep.dL_wor, rel=0.02)


def test_it10_half_deviations_are_in_the_papers_stated_range(chang):
    # Section 3.4: at IT10 the stochastic deviations at the toggle are about 0.2 to 0.3 mm.
    rep = asymmetry(chang, it_tolerances(chang, 10))
    for budget in (rep.lower, rep.upper):
        assert 0.19 * MM < budget.rss < budget.worst < 0.31 * MM
    assert rep.lower.contributions["r5"] < 0 < rep.upper.contributions["r5"]


def test_monte_carlo_sigma_agrees_with_rss_for_small_tolerances(chang):
    tol = it_tolerances(chang, 6)
    x = 30 * MM  # away from the toggle, where more dimensions matter
    rep = asymmetry(chang, tol, x)
    mc = monte_carlo(chang, tol, x=x, samples=200_000, seed=1)
    assert 3 * mc.lower.std == pytest.approx(rep.lower.rss, rel=0.01)
    assert 3 * mc.upper.std == pytest.approx(rep.upper.rss, rel=0.01)
    assert 3 * mc.asymmetry.std == pytest.approx(math.hypot(rep.lower.rss, rep.upper.rss), rel=0.01)
    assert abs(mc.asymmetry.mean) < 0.05 * mc.asymmetry.std
    uni = monte_carlo(chang, tol, x=x, samples=200_000, seed=2, distribution="uniform")
    # uniform over +-t has sigma t / sqrt(3)
    assert uni.lower.std == pytest.approx(rep.lower.rss / math.sqrt(3), rel=0.01)


def test_monte_carlo_rejects_bad_options(chang):
    tol = it_tolerances(chang, 8)
    with pytest.raises(ParameterError):
        monte_carlo(chang, tol, distribution="cauchy")
    with pytest.raises(ParameterError):
        monte_carlo(chang, tol, samples=1)


def test_monte_carlo_is_reproducible_with_a_seed(chang):
    tol = it_tolerances(chang, 9)
    a = monte_carlo(chang, tol, samples=5000, seed=7)
    b = monte_carlo(chang, tol, samples=5000, seed=7)
    c = monte_carlo(chang, tol, samples=5000, seed=8)
    assert a.asymmetry.std == b.asymmetry.std != c.asymmetry.std
    assert np.isfinite(a.asymmetry.percentiles["p99.865"])


@pytest.mark.parametrize("n", [2, 3, 10, 1001, 100_000])
def test_percentiles_are_numpys_to_the_bit(n):
    """The nested partitions select the same order statistics and interpolate as numpy's
    linear method does: normal, tied and sorted values."""
    rng = np.random.default_rng(n)
    for values in (rng.standard_normal(n), rng.integers(0, 4, n).astype(float),
                   np.sort(rng.standard_normal(n))[::-1]):
        expected = np.percentile(values, QUANTILES)
        np.testing.assert_array_equal(percentiles(values.copy()), expected)
