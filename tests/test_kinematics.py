"""Kinematics of seed 000 (Chang, Lee & Hsu 2021): numbers of section 3.4 and Figure 6."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from paper_closed_forms import upper_pose

from toggle.kinematics import (
    AssemblyError,
    half_motion,
    half_pose,
    mirror_angles,
    open_position,
    output_position,
    stroke,
    stroke_limits,
    toggle_position,
)
from toggle.params import HalfDims, ParameterError, load_mechanism, load_preset, paper_dimension

MM = 1e-3


def test_stroke_toggle_and_open_positions(chang):
    # Paper: x from -3.439 to 51.566 mm, stroke 45.003 mm, theta8(x_TP) = -2.729 deg.
    x_open, x_tp = stroke_limits(chang.lower)
    assert x_tp == pytest.approx(51.566 * MM, abs=0.001 * MM)
    assert x_open == pytest.approx(-3.439 * MM, abs=0.001 * MM)
    assert stroke(chang.lower) == pytest.approx(45.003 * MM, abs=0.001 * MM)
    theta8 = mirror_angles(half_pose(toggle_position(chang.upper), chang.upper))[2]
    assert math.degrees(theta8) == pytest.approx(-2.729, abs=0.001)


def test_open_position_has_link3_horizontal_and_toggle_is_collinear(chang):
    d = chang.lower
    assert float(half_pose(open_position(d), d).theta3) == pytest.approx(2 * math.pi, abs=1e-12)
    pose = half_pose(toggle_position(d), d)
    # links 4b and 5 collinear: theta5 = theta4 (mod 2 pi), L = sqrt((r4b + r5)^2 - e^2)
    assert math.remainder(float(pose.theta5) - float(pose.theta4), 2 * math.pi) == pytest.approx(
        0, abs=1e-9
    )
    assert float(pose.L) == pytest.approx(math.sqrt((d.r4b + d.r5) ** 2 - d.e**2), rel=1e-14)


def test_upper_half_mirror_matches_paper_equations_with_unequal_dims(chang):
    upper = chang.upper.replace(r5=chang.upper.r5 + 0.5 * MM, r3=chang.upper.r3 - 0.2 * MM)
    for x in np.linspace(-3 * MM, 51 * MM, 7):
        ref = upper_pose(float(x), upper)
        pose = half_pose(float(x), upper)
        t6, t7, t8 = mirror_angles(pose)
        assert float(pose.L) == pytest.approx(ref["L"], rel=1e-13)
        assert float(t6) == pytest.approx(ref["theta6"], abs=1e-12)
        assert float(t7) == pytest.approx(ref["theta7"], abs=1e-12)
        assert float(t8) == pytest.approx(ref["theta8"], abs=1e-12)


def test_scalar_array_and_symbolic_evaluations_agree(chang):
    xs = np.linspace(0.0, 50 * MM, 11)
    vec = half_pose(xs, chang.lower).L
    scal = [float(half_pose(float(x), chang.lower).L) for x in xs]
    np.testing.assert_allclose(vec, scal, rtol=0, atol=1e-15)
    x = ca.SX.sym("x")
    f = ca.Function("L", [x], [ca.SX(half_pose(x, chang.lower).L)])
    np.testing.assert_allclose(np.asarray(f(xs.reshape(1, -1))).ravel(), vec, rtol=1e-14)


def test_velocity_ratio_and_its_derivative_equal_finite_differences(chang):
    xs = np.linspace(0.0, 50 * MM, 9)
    m = half_motion(xs, chang.lower)
    h = 1e-6
    L = lambda x: output_position(x, chang.lower)  # noqa: E731
    np.testing.assert_allclose(m.dL_dx, (L(xs + h) - L(xs - h)) / (2 * h), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(m.d2L_dx2, (L(xs + h) - 2 * L(xs) + L(xs - h)) / h**2,
                               rtol=1e-3, atol=1e-2)
    np.testing.assert_allclose(m.mechanical_advantage, 1 / m.dL_dx)


def test_mechanical_advantage_grows_without_bound_towards_the_toggle(chang):
    x_open, x_tp = stroke_limits(chang.lower)
    ma = half_motion(np.array([x_open, 0.5 * (x_open + x_tp), x_tp - 1e-6]), chang.lower)
    assert ma.mechanical_advantage[0] < ma.mechanical_advantage[1] < ma.mechanical_advantage[2]
    assert ma.mechanical_advantage[2] > 1e3


@pytest.mark.parametrize("x", [90 * MM, -90 * MM, np.array([0.0, 0.095])])
def test_unassemblable_input_raises_naming_loop_and_input(chang, x):
    with pytest.raises(AssemblyError, match=r"x = .* crosshead link 3"):
        half_pose(x, chang.lower)
    with pytest.raises(AssemblyError):
        half_motion(x, chang.lower)


def test_platen_loop_failure_is_named(chang):
    short = chang.lower.replace(r5=5 * MM, e=0.2)
    with pytest.raises(AssemblyError, match="link 5"):
        half_pose(0.0, short)


def test_geometry_that_never_assembles_is_reported(chang):
    broken = chang.lower.replace(r1=0.5, r2=0.0)
    with pytest.raises(AssemblyError, match="cannot assemble at any input"):
        stroke_limits(broken)


def test_parameter_validation():
    with pytest.raises(ParameterError, match="triangle"):
        HalfDims(0.1, 0.05, 0.036, 0.064, 0.1, 0.2, 0.11, 0.01)
    with pytest.raises(ParameterError, match="positive"):
        HalfDims(0.1, 0.05, -0.036, 0.064, 0.1, 0.04, 0.11, 0.01)
    with pytest.raises(ParameterError, match="finite"):
        HalfDims(0.1, 0.05, float("nan"), 0.064, 0.1, 0.04, 0.11, 0.01)
    with pytest.raises(ParameterError, match="unknown preset"):
        load_preset("no_such_clamp")
    assert paper_dimension("r8") == ("upper", "r5")
    assert paper_dimension("eL") == ("lower", "e")


def test_user_file_loads_like_a_preset_and_errors_are_per_half(tmp_path, chang):
    f = tmp_path / "mine.toml"
    f.write_text(
        'name = "mine"\n[half]\n' + "".join(f"{k} = {v!r}\n" for k, v in
                                            zip(("r1", "r2", "r3", "r4a", "r4b", "r4c", "r5", "e"),
                                                chang.lower.as_tuple()))
        + "[upper]\nr5 = 0.1105\n"
    )
    mech = load_mechanism(f)
    assert mech.lower == chang.lower
    assert mech.upper == chang.upper.replace(r5=0.1105)
    assert not mech.symmetric
    assert chang.with_error("upper", "r5", 0.5 * MM).upper.r5 == pytest.approx(0.1105)
    bad = tmp_path / "bad.toml"
    bad.write_text('[half]\nr1 = 0.1\n')
    with pytest.raises(ParameterError, match=r"the lower half has no r2, r3, .* \(give it in"):
        load_mechanism(bad)


def test_clamp_whose_crosshead_link_never_turns_horizontal_opens_at_its_nearest():
    """SM-55 (seed 001): L4 < dE, so theta3 peaks below 360 deg; x_open is that peak."""
    sm55 = load_preset("lin2003_sm55").lower
    x_open, x_tp = stroke_limits(sm55)
    theta3 = lambda x: float(half_pose(x, sm55).theta3)  # noqa: E731
    assert theta3(x_open) < 2 * math.pi
    assert theta3(x_open) >= max(theta3(x_open - 1e-4), theta3(x_open + 1e-4))
    assert x_open < x_tp
    pose = half_pose(x_tp, sm55)
    assert math.degrees(2 * math.pi - float(pose.theta5)) == pytest.approx(-0.7253, abs=1e-4)
