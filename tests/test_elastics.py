"""Real-mold clamping (Lin & Hsiao 2003, Eqs 1-8, 19-25): the SM-55 example and invariants."""

from __future__ import annotations

import dataclasses
import json
import math

import casadi as ca
import numpy as np
import pytest

from toggle.elastics import (
    ClampingError,
    analyse_clamping,
    clamp_state,
    clamp_stroke,
    clamping_curves,
    contact_for_clamp_force,
    contact_position,
)
from toggle.params import load_preset
from toggle_cli import main

KGF = 9.80665  # N, the paper's unit of force
SM55 = load_preset("lin2003_sm55")
CHANG = load_preset("chang2021")

# Section 3.1 (final tie-bar force 55 000 kgf): maximum crosshead thrust per mu, kgf.
PAPER_F0_MAX = {0.0: 808.78, 0.01: 884.42, 0.05: 1212.37, 0.10: 1674.88, 0.17: 2408.22}


@pytest.fixture(scope="module")
def runs():
    return {mu: analyse_clamping(SM55, mu, tiebar_force=55_000 * KGF) for mu in PAPER_F0_MAX}


@pytest.mark.parametrize("mu", sorted(PAPER_F0_MAX))
def test_maximum_thrust_matches_the_paper(runs, mu):
    assert runs[mu].thrust_max / KGF == pytest.approx(PAPER_F0_MAX[mu], rel=2e-4)


def test_contact_angle_stretch_and_travel_match_the_paper(runs):
    r = runs[0.0]
    assert math.degrees(r.alpha_contact) == pytest.approx(3.735, abs=1e-3)
    assert r.final.tiebar_stretch * 1e3 == pytest.approx(0.2923, abs=1e-4)  # S~_C, Eq 24
    assert r.crosshead_travel * 1e3 == pytest.approx(26.08, abs=5e-3)  # U~_E, Eq 8
    assert math.degrees(r.alpha_final) == pytest.approx(0.7253, abs=1e-4)
    assert r.final.tiebar_force == pytest.approx(55_000 * KGF, rel=1e-9)


def test_contact_angle_is_solved_per_mu(runs):
    """alpha_C grows with mu (3.7347 -> 3.7389 deg): friction loads the links more."""
    alphas = [runs[mu].alpha_contact for mu in sorted(runs)]
    assert all(a < b for a, b in zip(alphas[1:], alphas[2:]))
    assert math.degrees(alphas[-1]) == pytest.approx(3.7389, abs=2e-4)


def test_peak_lies_strictly_inside_the_clamping(runs):
    """Section 3.1: the maximum thrust is neither at contact nor at the final position."""
    for r in runs.values():
        assert r.x_contact < r.x_at_thrust_max < r.x_final
        assert r.thrust_max > r.final.thrust


def test_maximum_thrust_increases_with_friction():
    peaks = [analyse_clamping(CHANG, mu).thrust_max for mu in np.linspace(0, 0.3, 7)]
    assert np.all(np.diff(peaks) > 0)


def test_mold_height_input_reproduces_the_force_input(runs):
    """Given the contact position instead of the force, the same clamp force results."""
    r = runs[0.05]
    again = analyse_clamping(SM55, 0.05, x_contact=r.x_contact)
    assert again.final.tiebar_force == pytest.approx(55_000 * KGF, rel=1e-9)
    assert again.thrust_max == pytest.approx(r.thrust_max, rel=1e-9)


def test_crosshead_work_equals_tiebar_energy_without_friction():
    """Rigid links, mu = 0: the work of F0 over U_E (Eq 8) is the tie bars' strain energy."""
    stiff = dataclasses.replace(SM55.clamp.links, modulus1=1e20, modulus2=1e20)
    mech = dataclasses.replace(SM55, clamp=dataclasses.replace(SM55.clamp, links=stiff))
    r = analyse_clamping(mech, 0.0)
    c = clamping_curves(mech, r, points=4001)
    work = np.trapezoid(c.state.thrust, c.crosshead_travel)
    energy = 0.5 * r.final.tiebar_force * r.final.tiebar_stretch
    assert work == pytest.approx(energy, rel=1e-5)
    assert r.final.tiebar_stretch == pytest.approx(r.final.toggle_stretch, rel=1e-12)


def test_forces_vanish_before_contact_and_balance_after():
    r = analyse_clamping(CHANG)
    xs = np.array([r.x_contact - 1e-3, r.x_contact, 0.5 * (r.x_contact + r.x_final)])
    s = clamp_state(xs, r.x_contact, CHANG)
    assert s.clamp_force[0] == 0 and s.thrust[0] == 0 and s.clamp_force[1] == 0
    assert s.clamp_force[2] == pytest.approx(s.tiebar_force[2] + s.thrust[2])  # Eq 30


def test_clamp_state_is_symbolic():
    """The per-step FMU/planner entry point takes CasADi symbols."""
    r = analyse_clamping(SM55, 0.05)
    x = ca.SX.sym("x")
    f = ca.Function("f0", [x], [ca.SX(clamp_state(x, r.x_contact, SM55, 0.05).thrust)])
    assert float(f(r.x_at_thrust_max)) == pytest.approx(r.thrust_max, rel=1e-12)


def test_unreachable_clamp_force_is_a_clear_error():
    with pytest.raises(ClampingError, match="cannot reach"):
        contact_position(SM55, 0.05, 1e12)
    with pytest.raises(ClampingError, match="positive"):
        contact_position(SM55, 0.05, -1.0)


@pytest.mark.parametrize("x_contact", [-0.5, 0.2])
def test_mold_height_outside_the_stroke_is_a_clear_error(x_contact):
    with pytest.raises(ClampingError, match="outside the stroke"):
        analyse_clamping(SM55, 0.05, x_contact=x_contact)


def test_negative_friction_is_a_clear_error():
    with pytest.raises(ValueError, match="mu"):
        analyse_clamping(SM55, -0.1)


def test_missing_clamp_section_is_a_clear_error():
    with pytest.raises(ClampingError, match=r"\[clamp\]"):
        analyse_clamping(dataclasses.replace(SM55, clamp=None))


def test_stroke_of_both_presets():
    x_open, x_final = clamp_stroke(SM55)
    assert x_open == SM55.clamp.x_open < x_final
    assert clamp_stroke(CHANG)[1] * 1e3 == pytest.approx(51.566, abs=1e-3)  # seed 000's x_TP


def test_cli_json(capsys):
    assert main(["clamp", "--preset", "lin2003_sm55", "--mu", "0.05", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    for key in ("alpha_final", "alpha_contact", "tiebar_stretch", "crosshead_travel", "thrust_max",
                "thrust_final", "alpha_at_thrust_max", "mechanical_advantage_final"):
        assert key in data
    assert data["thrust_max"] / KGF == pytest.approx(PAPER_F0_MAX[0.05], rel=2e-4)
    assert main(["clamp", "--preset", "lin2003_sm55", "--mu", "0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mechanical_advantage_final"] is None  # unbounded


def test_cli_clamp_force_and_errors(capsys):
    assert main(["clamp", "--preset", "lin2003_sm55", "--clamp-force", "2e5", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["tiebar_force_final"] == pytest.approx(2e5)
    with pytest.raises(SystemExit) as info:  # a usage error, judged by argparse
        main(["clamp", "--preset", "lin2003_sm55", "--mu", "-1"])
    assert info.value.code == 2 and "argument --mu" in capsys.readouterr().err


def test_cli_plot_writes_figures(tmp_path):
    assert main(["plot", "clamp", "--preset", "lin2003_sm55", "--mu", "0", "0.05",
                 "--out", str(tmp_path)]) == 0
    names = {p.name for p in tmp_path.glob("*.png")}
    assert {f"{name}_lin2003_sm55.png" for name in (
        "fig4_tiebar_force", "fig5_mechanical_advantage", "fig6_thrust", "fig7_thrust_max",
        "fig8_motor_torque")} <= names


def test_cli_plot_at_a_vanishing_clamp_force_draws_every_figure(tmp_path):
    """Found by the CLI fuzz: at 1e-300 N there is no clamping travel, and the torque figure's
    time axis (1.25 times its duration) was empty, refused after figures 4-7 were written.
    The hold is drawn for 1 ms; every figure's data is computed before the first file."""
    assert main(["plot", "clamp", "--preset", "lin2003_sm55", "--clamp-force", "1e-300",
                 "--mu", "0.1", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "fig8_motor_torque_lin2003_sm55.png").stat().st_size > 0


@pytest.mark.parametrize("delta_r8", [0.0, 0.3e-3])
def test_contact_for_clamp_force_is_the_plants_exact_inverse(delta_r8):
    """The plant at rest in the final position holds exactly the requested clamp force
    (both halves, unequal ones too); the paper's linearised Eq 25 lands micrometres away."""
    from toggle.plant import PlantConfig, plant_outputs

    mech = CHANG.with_error("upper", "r5", delta_r8) if delta_r8 else CHANG
    mu, force = CHANG.clamp.mu, 1500.0
    x_c = contact_for_clamp_force(mech, mu, force)
    x_final = clamp_stroke(mech)[1]
    held = plant_outputs(x_final, 0.0, 0.0, PlantConfig(mech, mu=mu, x_contact=x_c)).clamp_force
    assert float(held) == pytest.approx(force, rel=1e-9)
    assert 0 < abs(x_c - contact_position(mech, mu, force)) < 20e-6
    with pytest.raises(ClampingError, match="beyond reach"):
        contact_for_clamp_force(mech, mu, 1e9)
    with pytest.raises(ClampingError, match="positive"):
        contact_for_clamp_force(mech, mu, float("nan"))
