"""The toggle press of Dong & Sun 2022 (seed 003): reconstruction, dead centres, sensitivities."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from toggle import press
from toggle.kinematics import AssemblyError
from toggle.params import ParameterError

MM = 1e-3
#: Table 3 (seed 003): sensitivity of the BDC position per error source, paper's labels.
TABLE3 = {"l1": 2.2811, "l2": 0.89720, "l3": -0.58339, "l4": -0.22975, "l5": 1.0552,
          "l6": -0.36936, "Cx": -1.9443, "Cz": 0.12448, "e": -0.81850}


@pytest.fixture(scope="module")
def dims() -> press.PressDims:
    return press.load_press("dong2022").dims


def test_bdc_matches_paper(dims):
    # Section 5.4: "the ideal theoretical BDC value ... is 398.23 mm" (displacement from TDC).
    assert press.bdc_displacement(dims) == pytest.approx(398.23 * MM, abs=0.05 * MM)


def test_dead_centres_are_the_extremes(dims):
    tdc, bdc = press.dead_centres(dims)
    scan = press.slider_position(np.linspace(0, 2 * np.pi, 20001), dims)
    assert press.slider_position(bdc, dims) >= scan.max() - 1e-12
    assert press.slider_position(tdc, dims) <= scan.min() + 1e-12
    f = press._motion_function()
    for theta in (tdc, bdc):
        assert abs(float(f(theta, np.array(dims.as_tuple()))[1])) < 1e-10


def test_sensitivities_equal_central_differences(dims):
    exact = press.bdc_sensitivities(dims)
    h = 1e-6
    for i, name in enumerate(press.PRESS_DIMENSIONS):
        up, down = list(dims.as_tuple()), list(dims.as_tuple())
        up[i] += h
        down[i] -= h
        fd = (press.bdc_displacement(press.PressDims(*up))
              - press.bdc_displacement(press.PressDims(*down))) / (2 * h)
        assert exact[name] == pytest.approx(fd, abs=1e-6), name


def test_table3_signs_values_and_ranking(dims):
    sens = press.bdc_sensitivities(dims)
    for name, paper in TABLE3.items():
        assert np.sign(sens[name]) == np.sign(paper), name
        assert sens[name] == pytest.approx(paper, rel=0.15), name
    ours = sorted(sens, key=lambda k: -abs(sens[k]))
    assert ours == sorted(TABLE3, key=lambda k: -abs(TABLE3[k]))
    assert ours[:2] == ["l1", "Cx"]


def test_batch_equals_scalar(dims):
    rng = np.random.default_rng(1)
    params = np.array(dims.as_tuple())[:, None] + 5e-5 * rng.standard_normal((9, 4))
    batch = press.bdc_displacement_batch(params, dims)
    scalar = [press.bdc_displacement(press.PressDims(*params[:, j])) for j in range(4)]
    assert batch == pytest.approx(scalar, abs=1e-12)


def test_symbolic_evaluation(dims):
    theta = ca.SX.sym("theta")
    s = ca.SX(press.slider_position(theta, dims))
    f = ca.Function("s", [theta], [s])
    assert float(f(1.0)) == pytest.approx(float(press.slider_position(1.0, dims)), abs=1e-12)


def test_paper_parameter_list_as_labelled_cannot_run(dims):
    # The parameter list read with the loop labels (l1 = 575 crank, l3 = 205 upper rod,
    # l4 = 1891, l5 = 585): the chain cannot follow a full crank turn.
    listed = press.PressDims(l1=dims.l3, l2=dims.l2, l3=dims.l1, l4=dims.l5, l5=dims.l4,
                             l6=dims.l6, Cx=dims.Cx, Cz=dims.Cz, e=dims.e)
    with pytest.raises(AssemblyError, match="crank angle"):
        press.dead_centres(listed)


def test_slider_line_on_far_side_misses_bdc(dims):
    # e taken as x = -23 mm (away from the crank) gives a different press.
    far = press.PressDims(**{**{k: getattr(dims, k) for k in press.PRESS_DIMENSIONS},
                             "e": -dims.e})
    assert abs(press.bdc_displacement(far) - 398.23 * MM) > 10 * MM


def test_bad_input():
    with pytest.raises(ParameterError, match="l1"):
        press.PressDims(-0.2, 1.7, 0.575, 0.585, 1.891, 0.835, 1.5, 0.57, -0.023)
    with pytest.raises(ParameterError, match="triangle"):
        press.PressDims(0.2, 1.7, 0.575, 0.1, 1.891, 0.835, 1.5, 0.57, -0.023)
    with pytest.raises(ParameterError, match="unknown press preset"):
        press.load_press("no_such_press")
    with pytest.raises(ParameterError, match="missing"):
        press.press_from_dict({"press": {"l1": 0.2, "chain_spacing": 1.0}})


def test_short_bottom_rod_raises_assembly_error(dims):
    short = press.PressDims(**{**{k: getattr(dims, k) for k in press.PRESS_DIMENSIONS},
                               "l6": 0.3})
    with pytest.raises(AssemblyError, match="bottom rod"):
        press.bdc_displacement(short)
