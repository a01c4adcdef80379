"""Property tests of the kinematics over random assemblable geometries."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest
from conftest import half_dims
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from toggle.kinematics import (
    AssemblyError,
    half_motion,
    half_pose,
    mirror_angles,
    output_position,
    sensitivities,
    stroke_limits,
)
from toggle.params import DIMENSIONS, Mechanism

SETTINGS = settings(max_examples=40, deadline=None)


def limits(dims):
    try:
        return stroke_limits(dims)
    except AssemblyError:
        assume(False)


@SETTINGS
@given(half_dims(), st.floats(0.05, 0.95))
def test_symmetric_mechanism_has_equal_halves(dims, frac):
    x_open, x_tp = limits(dims)
    mech = Mechanism("sym", dims, dims)
    assert mech.symmetric
    x = x_open + frac * (x_tp - x_open)
    lo, up = half_pose(x, mech.lower), half_pose(x, mech.upper)
    assert float(up.L) == float(lo.L)
    # the upper half's angles are the mirror images of the lower half's
    t6, t7, t8 = mirror_angles(up)
    assert math.cos(float(t7)) == pytest.approx(math.cos(float(lo.theta4)), abs=1e-14)
    assert math.sin(float(t8)) == pytest.approx(-math.sin(float(lo.theta5)), abs=1e-14)
    assert sensitivities(x, mech.lower) == sensitivities(x, mech.upper)


@SETTINGS
@given(half_dims(), st.floats(0.05, 0.95))
def test_sensitivities_equal_central_finite_differences(dims, frac):
    x_open, x_tp = limits(dims)
    x = x_open + frac * (x_tp - x_open)
    ad = sensitivities(x, dims)
    h = 1e-7
    for k in DIMENSIONS:
        hi = output_position(x, dims.replace(**{k: getattr(dims, k) + h}))
        lo = output_position(x, dims.replace(**{k: getattr(dims, k) - h}))
        assert float(ad[k]) == pytest.approx(float(hi - lo) / (2 * h), rel=1e-5, abs=1e-6), k


@SETTINGS
@given(half_dims())
def test_L_is_continuous_and_maximal_at_the_toggle(dims):
    x_open, x_tp = limits(dims)
    xs = np.linspace(x_open, x_tp, 2001)
    m = half_motion(xs, dims)
    L_tp = float(output_position(x_tp, dims))
    assert L_tp == pytest.approx(math.sqrt((dims.r4b + dims.r5) ** 2 - dims.e**2), rel=1e-12)
    assert np.all(m.L <= L_tp + 1e-15)
    # continuity: successive steps bounded by the largest slope times the step
    steps = np.abs(np.diff(m.L))
    assert np.all(steps <= np.abs(m.dL_dx).max() * (xs[1] - xs[0]) * 1.01 + 1e-15)
    # the toggle is a maximum: L rises towards x_TP and falls just past it
    assert float(output_position(x_tp - 1e-4, dims)) < L_tp
    with contextlib.suppress(AssemblyError):  # it may lock up right after the toggle
        assert float(output_position(x_tp + 1e-4, dims)) < L_tp
