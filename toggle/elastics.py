"""Real-mold clamping: tie-bar stretch and link shortening (Lin & Hsiao 2003, Eqs 1-8, 19-25).

After the mold halves touch (crosshead at x_contact, seed 001's alpha_C) the
moving platen stops and further crosshead travel stretches the tie bars and
shortens links 1 and 2 until the toggle is straight (the final position).
As in the paper, the deformations are kept in the force balance (Eq 6) but
dropped in the geometry, so positions come from :func:`toggle.kinematics.half_pose`:

* Eq 7: S_bar = L(x) - L(x_contact), the platen-joint travel of the rigid linkage
  (L1 cos beta + L2 cos alpha is seed 000's L);
* Eq 25: S_bar = K(x) F_cl, with the compliance K (:func:`compliance`) the tie-bar
  stretch per unit clamping force plus the links' shortening projected on the axis;
  with Eqs 29-30 every force at x is linear in S_bar;
* Eq 8: U_E = (x - x_contact) - S_bar, the crosshead travel relative to the moving
  platen (seed 000's x is measured from the tailstock-side pivot C, which moves back
  by S_bar), checked against the paper's U_E = 26.08 mm;
* Eq 24: the tie-bar stretch S_C = F_c L_c / (n_c A_c E_c) (0.2923 mm in the paper's
  example; it is Eq 6's S_C, not Eq 7's S_bar = 0.3865 mm).

The final position is the toggle, alpha = -beta = asin(dA / (L1 + L2)) (Eqs 1, 3).
The paper gets alpha_C from the final tie-bar force for each mu separately
(:func:`contact_position`); given instead the mold-contact position (the mold-height
setting), :func:`analyse_clamping` gives the resulting forces.

:func:`clamp_state` is the per-time-step entry point (floats or CasADi SX): forces at
crosshead position x for a given contact position, friction and direction of motion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from toggle.kinematics import check_stroke, half_pose, stroke_limits
from toggle.params import HALVES, ClampData, HalfDims, Mechanism
from toggle.roots import brentq
from toggle.statics import CLOSING, check_friction, force_ratios, linkage_angles

#: |F0 / F_cl| below this counts as zero thrust (the frictionless toggle, where the
#: mechanical advantage is unbounded; the toggle position is found to ~1e-15 m).
_ZERO_THRUST_RATIO = 1e-9


class ClampingError(ValueError):
    """A clamping request the linkage cannot meet (message says why)."""


class ClampState(NamedTuple):
    """Forces (N) and stretch (m) at one crosshead position; axial link forces per member."""

    clamp_force: Any
    tiebar_force: Any
    thrust: Any
    tiebar_stretch: Any
    toggle_stretch: Any
    link1_force: Any
    link2_bf_force: Any
    link2_cf_force: Any
    crosshead_link_force: Any


def clamp_data(mech: Mechanism) -> ClampData:
    """The preset's [clamp] section, or a clear error if it has none."""
    if mech.clamp is None:
        raise ClampingError(
            f"preset {mech.name!r} has no [clamp] section (pins, sections, tie bars)"
        )
    return mech.clamp


def at_mold_height(mech: Mechanism, height: float) -> Mechanism:
    """The clamp with its tailstock set for a mold ``height`` m thick: the tie bars' span
    between their nuts is [clamp.tiebars] length plus the mold's excess over
    [clamp.die_height] reference (the tailstock moves along the bars with the mold; the
    linkage and its stroke move with it unchanged). Outside the die-height range it is
    refused."""
    clamp = clamp_data(mech)
    die = clamp.die_height
    if die is None:
        raise ClampingError(f"preset {mech.name!r} has no [clamp.die_height] (the tailstock's "
                            f"die-height range)")
    if not (math.isfinite(height) and die.min <= height <= die.max):
        raise ClampingError(f"mold height {height!r} m is outside the die-height range "
                            f"[{die.min:.6g}, {die.max:.6g}] m of {mech.name}")
    bars = replace(clamp.tiebars, length=clamp.tiebars.length + height - die.reference)
    return replace(mech, clamp=replace(clamp, tiebars=bars))


def compliance(
    x: Any, dims: HalfDims, clamp: ClampData, mu: Any, direction: Any = CLOSING
) -> Any:
    """K = S_bar / F_cl at x, m/N (Eq 25 divided by F_cl, with Eqs 19-24 and 29-30)."""
    r = force_ratios(x, dims, clamp.pins, mu, direction)
    ang = linkage_angles(x, dims)
    n, links, bars = clamp.counts, clamp.links, clamp.tiebars
    L1, L2, L4 = dims.r5, dims.r4b, dims.r4a
    l_cf = L4 * np.cos(ang.gamma)  # Eq 4 (gamma = gammaC, deformation dropped in Eq 5)
    tie = r.tiebar / bars.stiffness  # Eq 24
    link1 = r.link1 / n.n1 * L1 / (links.area1 * links.modulus1) * np.cos(ang.beta)  # Eq 22
    link2 = (r.link2_cf * l_cf + r.link2_bf * (L2 - l_cf)) / (
        n.n2 * links.area2 * links.modulus2
    ) * np.cos(ang.alpha)  # Eq 23
    return tie + link1 + link2


def clamp_state(
    x: Any,
    x_contact: Any,
    mech: Mechanism,
    mu: Any = None,
    direction: Any = CLOSING,
    *,
    half: str = "lower",
) -> ClampState:
    """Forces at crosshead position x with the molds touching at x_contact.

    Before contact (x < x_contact) every force is zero. ``mu`` defaults to the
    preset's kinetic value; ``direction`` as in :mod:`toggle.statics`. Works on
    floats, arrays and CasADi SX (no branch on the state).
    """
    clamp = clamp_data(mech)
    mu = clamp.mu if mu is None else mu
    dims = mech.half(half)
    s_bar = np.maximum(half_pose(x, dims).L - half_pose(x_contact, dims).L, 0.0)  # Eq 7
    r = force_ratios(x, dims, clamp.pins, mu, direction)
    f_cl = s_bar / compliance(x, dims, clamp, mu, direction)  # Eq 25
    n = clamp.counts
    return ClampState(
        clamp_force=f_cl,
        tiebar_force=r.tiebar * f_cl,
        thrust=r.thrust * f_cl,
        tiebar_stretch=r.tiebar * f_cl / clamp.tiebars.stiffness,
        toggle_stretch=s_bar,
        link1_force=r.link1 * f_cl / n.n1,
        link2_bf_force=r.link2_bf * f_cl / n.n2,
        link2_cf_force=r.link2_cf * f_cl / n.n2,
        crosshead_link_force=r.crosshead_link * f_cl / n.n3,
    )


def crosshead_travel(x: Any, x_contact: Any, dims: HalfDims) -> Any:
    """U_E (Eq 8, deformations dropped): crosshead travel since mold contact, m."""
    return (x - x_contact) - (half_pose(x, dims).L - half_pose(x_contact, dims).L)


def clamp_stroke(mech: Mechanism, half: str = "lower") -> tuple[float, float]:
    """(x_open, x_final) of the crosshead, m.

    x_final is the toggle, where alpha = -beta (Eq 3), from
    :func:`toggle.kinematics.stroke_limits`; a preset's ``x_open`` (the
    machine's actual open position) overrides the kinematic one.
    """
    dims = mech.half(half)
    x_open, x_final = stroke_limits(dims)
    preset_open = clamp_data(mech).x_open
    check_stroke(dims, preset_open, label=f"{half} half of {mech.name}")  # reachable?
    if preset_open is None:
        return x_open, x_final
    half_pose(preset_open, dims, label=f"{half} half at the preset's x_open")  # assembles?
    if not preset_open < x_final:
        raise ClampingError(
            f"preset {mech.name!r}: x_open = {preset_open} m is not before the toggle {x_final} m"
        )
    return preset_open, x_final


def contact_position(
    mech: Mechanism, mu: float, tiebar_force: float, *, half: str = "lower"
) -> float:
    """Crosshead position x_contact (alpha_C) at which the molds must touch so that
    the final tie-bar force is ``tiebar_force`` N (Eqs 25, 29-30 at the final position)."""
    check_friction(mu)
    clamp, dims = clamp_data(mech), mech.half(half)
    if not (math.isfinite(tiebar_force) and tiebar_force > 0):
        raise ClampingError(f"final tie-bar force must be positive, got {tiebar_force!r} N")
    x_open, x_final = clamp_stroke(mech, half)
    q = float(force_ratios(x_final, dims, clamp.pins, mu).thrust)
    if q >= 1:
        raise ClampingError(
            f"with mu = {mu} the linkage is self-locking at the toggle (F0/F_cl = {q:.3g} >= 1): "
            "no tie-bar tension can be built"
        )
    s_bar = float(compliance(x_final, dims, clamp, mu)) * tiebar_force / (1.0 - q)
    l_final, l_open = (float(half_pose(v, dims).L) for v in (x_final, x_open))
    if s_bar >= l_final - l_open:
        raise ClampingError(
            f"a final tie-bar force of {tiebar_force:.6g} N needs {s_bar * 1e3:.4g} mm of toggle "
            f"travel after mold contact, more than the stroke of "
            f"{(l_final - l_open) * 1e3:.4g} mm: "
            "the linkage cannot reach it"
        )
    return float(brentq(lambda v: float(half_pose(v, dims).L) - (l_final - s_bar), x_open, x_final,
                        xtol=1e-15, rtol=4 * np.finfo(float).eps))


def contact_for_clamp_force(mech: Mechanism, mu: float, force: float) -> float:
    """Crosshead position x_contact at which the molds must touch so that the dynamic
    plant (:func:`toggle.plant.plant_outputs`: the mean of both halves' :func:`clamp_state`)
    holds the clamp force ``force`` N at rest in the final position.

    The exact inverse of the plant's force, for planning and simulating a machine set to a
    clamp force; :func:`contact_position` is the paper's linearised route (Eq 25), which
    lands a few micrometres away (2.5 um on chang2021) and reproduces the paper's tables.
    """
    if not (math.isfinite(force) and force > 0):
        raise ClampingError(f"clamp force must be positive, got {force!r} N")
    x_open, x_final = clamp_stroke(mech)

    def at_rest(xc: float) -> float:  # friction direction 0: at rest
        return 0.5 * sum(float(clamp_state(x_final, xc, mech, mu, 0.0, half=h).clamp_force)
                         for h in HALVES)

    reach = at_rest(x_open)
    if force >= reach:
        raise ClampingError(
            f"a clamp force of {force:.6g} N is beyond reach: with the molds touching at the "
            f"open position the stroke builds only {reach:.6g} N"
        )
    return float(brentq(lambda xc: at_rest(xc) - force, x_open, x_final, xtol=1e-15))


@dataclass(frozen=True)
class ClampingResult:
    """One real-mold clamping run (SI units); ``final`` with kinetic friction mu,
    ``hold`` with static friction mu_s = static_factor * mu after arrival."""

    mu: float
    mu_static: float
    x_open: float
    x_contact: float
    x_final: float
    alpha_contact: float
    alpha_final: float
    crosshead_travel: float
    thrust_max: float
    x_at_thrust_max: float
    alpha_at_thrust_max: float
    final: ClampState
    hold: ClampState

    @property
    def mechanical_advantage_final(self) -> float:
        """F_cl / F0 at the final position with kinetic friction (inf without friction)."""
        if abs(self.final.thrust) <= _ZERO_THRUST_RATIO * self.final.clamp_force:
            return math.inf
        return self.final.clamp_force / self.final.thrust


def _numeric_state(state: ClampState) -> ClampState:
    return ClampState(*(float(v) for v in state))


def thrust_peak(
    mech: Mechanism, mu: float, x_contact: float, x_final: float, *, half: str = "lower"
) -> tuple[float, float]:
    """(F0_max, x where it occurs) between contact and the final position."""
    def thrust(v: Any) -> Any:
        return clamp_state(v, x_contact, mech, mu, half=half).thrust

    xs = np.linspace(x_contact, x_final, 401)
    i = int(np.argmax(thrust(xs)))
    lo, hi = xs[max(i - 1, 0)], xs[min(i + 1, xs.size - 1)]
    from scipy.optimize import minimize_scalar  # only here: its import costs 0.3 s

    best = minimize_scalar(lambda v: -float(thrust(v)), bounds=(lo, hi), method="bounded",
                           options={"xatol": 1e-13})
    return -float(best.fun), float(best.x)


def analyse_clamping(
    mech: Mechanism,
    mu: float | None = None,
    *,
    tiebar_force: float | None = None,
    x_contact: float | None = None,
    half: str = "lower",
) -> ClampingResult:
    """Real-mold clamping for one friction coefficient.

    Give either the final tie-bar force (default: the preset's) or the mold-contact
    crosshead position ``x_contact`` (a mold-height setting), not both.
    """
    clamp, dims = clamp_data(mech), mech.half(half)
    mu = clamp.mu if mu is None else float(mu)
    check_friction(mu)
    x_open, x_final = clamp_stroke(mech, half)
    if x_contact is None:
        force = clamp.final_tiebar_force if tiebar_force is None else float(tiebar_force)
        x_contact = contact_position(mech, mu, force, half=half)
    elif tiebar_force is not None:
        raise ClampingError("give either the final tie-bar force or the mold-contact position")
    elif not (x_open <= x_contact < x_final):
        raise ClampingError(
            f"mold-contact crosshead position {x_contact!r} m is outside the stroke "
            f"[{x_open:.6g}, {x_final:.6g}) m"
        )
    f0_max, x_max = thrust_peak(mech, mu, x_contact, x_final, half=half)
    alpha = linkage_angles(np.array([x_contact, x_final, x_max]), dims).alpha
    return ClampingResult(
        mu=mu,
        mu_static=clamp.static_factor * mu,
        x_open=x_open,
        x_contact=float(x_contact),
        x_final=x_final,
        alpha_contact=float(alpha[0]),
        alpha_final=float(alpha[1]),
        crosshead_travel=float(crosshead_travel(x_final, x_contact, dims)),
        thrust_max=f0_max,
        x_at_thrust_max=x_max,
        alpha_at_thrust_max=float(alpha[2]),
        final=_numeric_state(clamp_state(x_final, x_contact, mech, mu, half=half)),
        hold=_numeric_state(clamp_state(x_final, x_contact, mech, clamp.static_factor * mu,
                                        half=half)),
    )


class ClampCurves(NamedTuple):
    """Curves over the real-mold clamping (arrays): position, alpha, U_E, forces."""

    x: np.ndarray
    alpha: np.ndarray
    crosshead_travel: np.ndarray
    mechanical_advantage: np.ndarray
    state: ClampState


def clamping_curves(
    mech: Mechanism, result: ClampingResult, points: int = 201, *, half: str = "lower"
) -> ClampCurves:
    """F_c, F_cl, F0, MA, link forces against x, alpha and U_E, contact to final."""
    dims = mech.half(half)
    xs = np.linspace(result.x_contact, result.x_final, points)
    state = ClampState(*(np.asarray(v, dtype=float)
                         for v in clamp_state(xs, result.x_contact, mech, result.mu, half=half)))
    q = np.asarray(force_ratios(xs, dims, clamp_data(mech).pins, result.mu).thrust)
    with np.errstate(divide="ignore"):
        ma = np.where(np.abs(q) > _ZERO_THRUST_RATIO, 1.0 / np.where(q != 0, q, 1.0), np.inf)
    return ClampCurves(xs, np.asarray(linkage_angles(xs, dims).alpha),
                       np.asarray(crosshead_travel(xs, result.x_contact, dims)), ma, state)
