"""Statics of the clamp with Coulomb friction at the pin joints (friction circles).

Lin & Hsiao 2003 (seed 001), Eqs 9-18 and 26-30, on the one mechanism model:
the angles come from :func:`toggle.kinematics.half_pose`, never from a second
copy of the position equations. Seed 001's names map onto one half as
L1 = r5, L2 = r4b, L3 = r3, L4 = r4a, gammaC = alpha4, dA = e, dE = r1 - r2, and
its angles are (checked against every number of its SM-55 example)

* alpha = theta4 (link 2, the triangular link's arm C-B, above the axis);
* beta  = 2 pi - theta5 = asin((L2 sin alpha - dA) / L1) (link 1, positive
  when B is above A; Eq 1 with the deformations dropped);
* phi   = 2 pi - theta3 (crosshead link; seed 000's theta3 is the direction
  of the vector E->D, so sin phi = (dE - L4 sin(alpha + gammaC)) / L3 as Eq 2
  says; the paper's final phi = 84.98 deg picks this assembly branch, the
  other one, 95.02 deg, misses every number);
* gamma = gammaC (Eq 5 with the deformations dropped).

API for time-stepping and optimisation
--------------------------------------
Every function below is written with numpy ufuncs and no Python branch on
the state, so it evaluates on floats, numpy arrays and CasADi SX symbols
(``casadi.GlobalOptions.setNumpyMode(True)`` is set by ``toggle.kinematics``):

* ``force_ratios(x, dims, pins, mu, direction)`` -> :class:`ForceRatios`: every
  force per unit clamping force F_cl, with ``thrust = F0 / F_cl`` (Eq 29).
* ``thrust_from_clamp_force(x, dims, pins, mu, clamp_force, direction)`` and
  ``thrust_from_tiebar_force(...)``: the static crosshead thrust F0, N.
* ``mechanical_advantage(...)`` = F_cl / F0 (Eq 29), inf at the frictionless toggle.

``direction`` is the sense of motion of the crosshead: +1 closing (x
increasing towards the toggle, the paper's real-mold clamping), -1 opening.
Friction opposes the motion, so every friction radius and friction angle
changes sign with it; this is exactly the paper's equations with
rho -> direction * rho. A value between -1 and 1 (for example
``np.tanh(v / v_eps)``) blends the two smoothly for a solver; 0 is frictionless.
The clamp/tie-bar force state (from :mod:`toggle.elastics`) is an input, so
one call costs a handful of transcendental functions.

Root of Eq 26 without a branch: with k3 = rho_C^2, b^2 - a c = k3 D, where
D = k1^2 + k2^2 - 2 k1 k2 k4 - k3 (1 - k4^2). The root whose moment M52 has
the sign of rho_C (Eq 15: M52 = rho_C |F52|, >= 0 when closing) is
F12 / F32 = a / (b + rho_C sqrt(D)); with rho_C >= 0 this is Eq 28 as printed.
Opening near the toggle the crosshead link goes into tension; then its friction
offsets flip sign (``force_ratios`` picks the consistent case with ``np.where``,
which CasADi maps to ``if_else``). Both choices were checked against Eq 15 and
against the energy inequality F0(opening) <= F0(frictionless) <= F0(closing).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from toggle.kinematics import half_pose, is_symbolic
from toggle.params import HalfDims, PinRadii

#: Directions of crosshead motion.
CLOSING = 1.0
OPENING = -1.0


class StaticsError(ValueError):
    """Friction or force input the statics cannot take (message says which)."""


class LinkageAngles(NamedTuple):
    """Seed 001's angles of one half, rad."""

    alpha: Any
    beta: Any
    phi: Any
    gamma: Any


class FrictionTerms(NamedTuple):
    """Signed friction radii (m) and friction angles (rad), Eqs 17-18."""

    rho_B: Any
    rho_C: Any
    rho_D: Any
    beta_mu: Any
    phi_mu: Any


class ForceRatios(NamedTuple):
    """Forces per unit clamping force F_cl, summed over all members of a kind.

    thrust: F0 / F_cl (Eq 29); tiebar: F_c / F_cl = 1 - thrust (Eq 30);
    link1: n1 F_AB / F_cl (Eq 19); link2_bf, link2_cf: n2 F_BF / F_cl and
    n2 F_CF / F_cl (Eqs 20-21); crosshead_link: n3 F_DE / F_cl. Axial forces
    are positive in compression (the crosshead link is in tension, < 0, when the
    crosshead pulls the clamp open against friction).
    """

    thrust: Any
    tiebar: Any
    link1: Any
    link2_bf: Any
    link2_cf: Any
    crosshead_link: Any


def _lengths(dims: HalfDims | Sequence[Any]) -> tuple[Any, Any, Any, Any]:
    """(L1, L2, L3, L4) = (r5, r4b, r3, r4a) of one half."""
    r1, r2, r3, r4a, r4b, r4c, r5, e = dims.as_tuple() if isinstance(dims, HalfDims) else dims
    return r5, r4b, r3, r4a


def check_friction(mu: Any, direction: Any = CLOSING) -> None:
    """Raise :class:`StaticsError` for mu < 0 or |direction| > 1 (numeric input only)."""
    if not is_symbolic(mu):
        m = np.asarray(mu, dtype=float)
        if not np.all(np.isfinite(m)) or np.any(m < 0):
            raise StaticsError(f"friction coefficient mu must be finite and >= 0, got {mu!r}")
    if not is_symbolic(direction):
        s = np.asarray(direction, dtype=float)
        if not np.all(np.isfinite(s)) or np.any(np.abs(s) > 1):
            raise StaticsError(
                f"direction must lie in [-1, 1] (+1 closing, -1 opening), got {direction!r}"
            )


def linkage_angles(x: Any, dims: HalfDims | Sequence[Any], *, check: bool = True) -> LinkageAngles:
    """Seed 001's alpha, beta, phi, gamma at crosshead position x (see module doc)."""
    pose = half_pose(x, dims, check=check)
    two_pi = 2.0 * math.pi
    return LinkageAngles(pose.theta4, two_pi - pose.theta5, two_pi - pose.theta3, pose.alpha4)


def friction_terms(
    mu: Any, dims: HalfDims | Sequence[Any], pins: PinRadii, direction: Any = CLOSING
) -> FrictionTerms:
    """Friction-circle radii rho = mu r / sqrt(1 + mu^2) (Eq 18) and the angles by
    which links 1 and 3 tilt off their centre lines (Eq 17), signed by ``direction``.

    Eq 17: a two-force link is tangent to the friction circles at both ends on
    opposite sides, so its force line turns by asin(2 rho / length).
    """
    check_friction(mu, direction)
    L1, _, L3, _ = _lengths(dims)
    f = direction * mu / np.sqrt(1.0 + mu * mu)
    rho_B, rho_C, rho_D = f * pins.B, f * pins.C, f * pins.D
    sin_b, sin_p = 2.0 * rho_B / L1, 2.0 * rho_D / L3
    for sin_mu, link in ((sin_b, "link 1 (r5)"), (sin_p, "the crosshead link (r3)")):
        if not is_symbolic(sin_mu) and np.any(np.abs(np.asarray(sin_mu, dtype=float)) >= 1):
            raise StaticsError(
                f"with mu = {mu!r} the friction circles at both ends of {link} overlap "
                "its length: the linkage is self-locking"
            )
    return FrictionTerms(rho_B, rho_C, rho_D, np.arcsin(sin_b), np.arcsin(sin_p))


def _thrust_ratio(
    angles: LinkageAngles, L2: Any, L4: Any, fr: FrictionTerms, link3_sign: float
) -> tuple[Any, Any, Any]:
    """Eqs 26-29 for an assumed sign of the crosshead-link force (+1 compression).

    Returns (F0 / F_cl, b + rho_C sqrt(D) (> 0 iff the link really is in
    compression), the line of action phi - phi_mu of the crosshead link).
    A link in tension keeps its friction moment opposing the rotation, so its
    force line moves to the other side of the friction circles: rho_D and
    phi_mu change sign (phi_mu is odd in rho_D).
    """
    alpha, beta, phi, gamma = angles
    rho_D, phi_mu = link3_sign * fr.rho_D, link3_sign * fr.phi_mu
    b_line = beta + fr.beta_mu  # line of action of link 1 (Eqs 10, 13)
    p_line = phi - phi_mu  # line of action of the crosshead link (Eqs 12, 13)
    # Eq 27
    k1 = L4 * np.sin(alpha + gamma + p_line) + rho_D
    k2 = L2 * np.sin(alpha + b_line) + fr.rho_B
    k3 = fr.rho_C * fr.rho_C
    k4 = np.cos(b_line - p_line)
    a = k1 * k1 - k3
    b = k1 * k2 - k3 * k4
    disc = k1 * k1 + k2 * k2 - 2.0 * k1 * k2 * k4 - k3 * (1.0 - k4 * k4)
    denominator = b + fr.rho_C * np.sqrt(disc)  # F12 / F32 = a / denominator (Eq 28)
    # Eqs 28-29 written as F0 / F_cl, finite at the frictionless toggle (k2 = 0)
    return denominator * np.cos(p_line) / (a * np.cos(b_line)), denominator, p_line


def force_ratios(
    x: Any,
    dims: HalfDims | Sequence[Any],
    pins: PinRadii,
    mu: Any,
    direction: Any = CLOSING,
) -> ForceRatios:
    """All member forces per unit clamping force at crosshead position x (Eqs 9-30).

    Closing, every link is in compression (the paper's case). Opening near the
    toggle with friction, the crosshead must pull: the crosshead link goes into
    tension and its friction offsets flip (see :func:`_thrust_ratio`); the
    thrust passes continuously through zero where the two cases meet.
    """
    _, L2, _, L4 = _lengths(dims)
    angles = linkage_angles(x, dims)
    fr = friction_terms(mu, dims, pins, direction)
    q_push, den_push, p_push = _thrust_ratio(angles, L2, L4, fr, 1.0)
    q_pull, _, p_pull = _thrust_ratio(angles, L2, L4, fr, -1.0)
    pushing = den_push > 0
    thrust = np.where(pushing, q_push, q_pull)
    p_line = np.where(pushing, p_push, p_pull)
    if not is_symbolic(thrust) and not np.all(np.isfinite(thrust)):
        raise StaticsError(
            f"no static equilibrium at x = {x!r} m with mu = {mu!r}: "
            "the friction circles are too large for this linkage (self-locking)"
        )
    alpha, beta = angles.alpha, angles.beta
    b_line = beta + fr.beta_mu
    link1 = np.cos(fr.beta_mu) / np.cos(b_line)  # Eq 19
    link2_bf = np.cos(alpha + b_line) / np.cos(b_line)  # Eq 20
    link2_cf = link2_bf - thrust * np.cos(alpha + p_line) / np.cos(p_line)  # Eq 21
    return ForceRatios(thrust, 1.0 - thrust, link1, link2_bf, link2_cf, thrust / np.cos(p_line))


def thrust_from_clamp_force(
    x: Any, dims: HalfDims | Sequence[Any], pins: PinRadii, mu: Any, clamp_force: Any,
    direction: Any = CLOSING,
) -> Any:
    """Static crosshead thrust F0 (N) holding clamping force F_cl (N) at x (Eq 29)."""
    return force_ratios(x, dims, pins, mu, direction).thrust * clamp_force


def thrust_from_tiebar_force(
    x: Any, dims: HalfDims | Sequence[Any], pins: PinRadii, mu: Any, tiebar_force: Any,
    direction: Any = CLOSING,
) -> Any:
    """Static crosshead thrust F0 (N) against total tie-bar force F_c (N) at x (Eqs 29-30)."""
    q = force_ratios(x, dims, pins, mu, direction).thrust
    return q / (1.0 - q) * tiebar_force


def mechanical_advantage(
    x: Any, dims: HalfDims | Sequence[Any], pins: PinRadii, mu: Any, direction: Any = CLOSING
) -> Any:
    """F_cl / F0 with friction (Eq 29); inf where F0 vanishes (frictionless toggle)."""
    q = force_ratios(x, dims, pins, mu, direction).thrust
    if is_symbolic(q):
        return 1.0 / q
    q = np.asarray(q, dtype=float)
    with np.errstate(divide="ignore"):
        return np.where(q != 0, 1.0 / np.where(q != 0, q, 1.0), np.inf)
