"""Friction-circle statics (Lin & Hsiao 2003, Eqs 9-18, 26-30) on the one kinematic model."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from toggle.elastics import clamp_stroke
from toggle.kinematics import half_motion
from toggle.params import load_preset
from toggle.statics import (
    CLOSING,
    OPENING,
    StaticsError,
    force_ratios,
    friction_terms,
    linkage_angles,
    mechanical_advantage,
    thrust_from_clamp_force,
    thrust_from_tiebar_force,
)

PRESETS = {name: load_preset(name) for name in ("lin2003_sm55", "chang2021")}


def _stroke_point(name: str, frac: float) -> tuple:
    """A crosshead position strictly inside the stroke (frac in (0, 1)) and the preset."""
    mech = PRESETS[name]
    x_open, x_final = clamp_stroke(mech)
    return mech, x_open + frac * (x_final - x_open)


presets = st.sampled_from(sorted(PRESETS))
fractions = st.floats(0.02, 0.995)
mus = st.floats(0.0, 0.3)


def test_final_angles_match_the_paper():
    """SM-55 final position: alpha~ = -beta~ = 0.7253 deg, phi~ = 84.9825 deg (section 3)."""
    mech = PRESETS["lin2003_sm55"]
    ang = linkage_angles(clamp_stroke(mech)[1], mech.lower)
    assert math.degrees(ang.alpha) == pytest.approx(0.7253, abs=1e-4)
    assert math.degrees(ang.beta) == pytest.approx(-0.7253, abs=1e-4)
    assert math.degrees(ang.phi) == pytest.approx(84.9825, abs=1e-4)
    assert math.degrees(ang.gamma) == pytest.approx(28.49, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(presets, fractions)
def test_frictionless_statics_is_virtual_work(name, frac):
    """Without friction, F0 dx = F_cl dL: F0 / F_cl equals dL/dx of the kinematics (AD)."""
    mech, x = _stroke_point(name, frac)
    q = force_ratios(x, mech.lower, mech.clamp.pins, 0.0).thrust
    assert q == pytest.approx(float(half_motion(x, mech.lower).dL_dx), rel=1e-9, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(presets, fractions, mus, mus)
def test_thrust_never_decreases_with_friction(name, frac, mu_a, mu_b):
    mech, x = _stroke_point(name, frac)
    lo, hi = sorted((mu_a, mu_b))
    f_lo, f_hi = (thrust_from_clamp_force(x, mech.lower, mech.clamp.pins, m, 1e5) for m in (lo, hi))
    assert f_hi >= f_lo - 1e-9


@settings(max_examples=40, deadline=None)
@given(presets, fractions, st.floats(0.005, 0.3))
def test_friction_lowers_the_mechanical_advantage(name, frac, mu):
    mech, x = _stroke_point(name, frac)
    pins = mech.clamp.pins
    with_friction = mechanical_advantage(x, mech.lower, pins, mu)
    assert with_friction < mechanical_advantage(x, mech.lower, pins, 0.0)


@settings(max_examples=60, deadline=None)
@given(presets, st.floats(0.02, 1.0), st.floats(0.005, 0.3))
def test_friction_opposes_the_motion(name, frac, mu):
    """Energy: friction only dissipates, so at the same clamp force
    F0(opening) < F0(frictionless) < F0(closing), also where opening needs a pull."""
    mech, x = _stroke_point(name, frac)
    f = [thrust_from_clamp_force(x, mech.lower, mech.clamp.pins, m, 1e5, s)
         for m, s in ((mu, OPENING), (0.0, CLOSING), (mu, CLOSING))]
    assert f[0] < f[1] < f[2]


def test_opening_near_the_toggle_pulls_through_a_tensioned_crosshead_link():
    mech = PRESETS["lin2003_sm55"]
    r = force_ratios(clamp_stroke(mech)[1], mech.lower, mech.clamp.pins, 0.25, OPENING)
    assert r.thrust < 0 and r.crosshead_link < 0


@settings(max_examples=60, deadline=None)
@given(presets, st.floats(0.02, 1.0), st.floats(0.005, 0.3), st.sampled_from([CLOSING, OPENING]))
def test_root_satisfies_eq15_with_the_moment_opposing_the_motion(name, frac, mu, direction):
    """Eq 15: M52 = rho_C |F52|, so M52 >= 0 while closing (Eq 28) and <= 0 while opening;
    a crosshead link in tension has its friction offsets on the other side."""
    mech, x = _stroke_point(name, frac)
    dims, pins = mech.lower, mech.clamp.pins
    a, b, phi, g = linkage_angles(x, dims)
    fr = friction_terms(mu, dims, pins, direction)
    r = force_ratios(x, dims, pins, mu, direction)
    link3 = np.sign(r.crosshead_link)
    b_line, p_line = b + fr.beta_mu, phi - link3 * fr.phi_mu
    f12 = 1.0 / np.cos(b_line)  # n2 F12 per unit F_cl (Eqs 9-10)
    f32 = r.crosshead_link  # n2 F32 per unit F_cl, signed (Eqs 11-12)
    assert f32 * np.cos(p_line) == pytest.approx(r.thrust, rel=1e-9, abs=1e-15)
    m52 = f32 * (dims.r4a * np.sin(a + g + p_line) + link3 * fr.rho_D) - f12 * (
        dims.r4b * np.sin(a + b_line) + fr.rho_B)
    f52 = math.hypot(f12 * np.cos(b_line) - f32 * np.cos(p_line),
                     f32 * np.sin(p_line) - f12 * np.sin(b_line))  # Eqs 13-14
    assert m52 == pytest.approx(fr.rho_C * f52, rel=1e-7, abs=1e-12)
    assert np.sign(m52) == direction
    assert r.tiebar == pytest.approx(1.0 - r.thrust)  # Eq 30


def test_tiebar_form_agrees_with_clamp_form():
    mech, x = _stroke_point("lin2003_sm55", 0.7)
    pins = mech.clamp.pins
    f0 = thrust_from_clamp_force(x, mech.lower, pins, 0.05, 5e5)
    q = force_ratios(x, mech.lower, pins, 0.05).thrust
    assert thrust_from_tiebar_force(x, mech.lower, pins, 0.05, 5e5 * (1 - q)) == pytest.approx(f0)


def test_symbolic_evaluation_matches_numeric():
    """The same functions take CasADi SX for x, mu and direction (planner, FMU)."""
    mech, x0 = _stroke_point("lin2003_sm55", 0.8)
    x, mu, s = ca.SX.sym("x"), ca.SX.sym("mu"), ca.SX.sym("s")
    f0 = thrust_from_clamp_force(x, mech.lower, mech.clamp.pins, mu, 1e5, s)
    fun = ca.Function("f0", [x, mu, s], [ca.SX(f0)])
    for m, d in ((0.07, CLOSING), (0.07, OPENING), (0.0, 0.3)):
        expected = thrust_from_clamp_force(x0, mech.lower, mech.clamp.pins, m, 1e5, d)
        assert float(fun(x0, m, d)) == pytest.approx(float(expected), rel=1e-12)
    dfdx = ca.Function("d", [x, mu, s], [ca.jacobian(ca.SX(f0), x)])
    assert np.isfinite(float(dfdx(x0, 0.05, 1.0)))


def test_vectorised_over_positions():
    mech = PRESETS["chang2021"]
    xs = np.linspace(*clamp_stroke(mech), 7)[1:-1]
    q = force_ratios(xs, mech.lower, mech.clamp.pins, 0.05).thrust
    assert q.shape == xs.shape
    assert q[0] == pytest.approx(force_ratios(xs[0], mech.lower, mech.clamp.pins, 0.05).thrust)


@pytest.mark.parametrize("mu, direction, match", [
    (-0.01, CLOSING, "mu"), (float("nan"), CLOSING, "mu"), (0.05, 2.0, "direction"),
])
def test_bad_friction_input_is_a_clear_error(mu, direction, match):
    mech, x = _stroke_point("lin2003_sm55", 0.5)
    with pytest.raises(StaticsError, match=match):
        force_ratios(x, mech.lower, mech.clamp.pins, mu, direction)
    assert issubclass(StaticsError, ValueError)


def test_self_locking_friction_is_a_clear_error():
    """Friction circles larger than the links allow: no equilibrium, a message not NaN."""
    mech, x = _stroke_point("chang2021", 0.5)
    huge = type(mech.clamp.pins)(B=30e-3, C=30e-3, D=20e-3)
    with pytest.raises(StaticsError, match="self-locking"):
        force_ratios(x, mech.lower, huge, 5.0)
