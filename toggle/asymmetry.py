"""Unequal halves forced to agree by the rigid, guided platen (issue 8; docs/unequal-halves.md).

The nine-link clamp moves only because its two halves are equal. With a
dimensional error the halves want the platen at different places,
L_U(x) != L_L(x) (both from :func:`toggle.kinematics.half_pose`, each with its
own dimensions). The platen is rigid and guided, so:

1. the mismatch first takes up free play (platen tilt in its bushing clearance,
   pin clearances): delta0;
2. the rest, s_e = max(|dL| - delta0, 0), is forced into the halves in series:
   pin contacts closed on their clearance (Hertz-type law s_c = (N / K_c)^(2/3),
   the Lankarani-Nikravesh exponent 3/2) and the halves' linear compliance
   c(x) = 1 / k_s + ((dL_L/dx)^2 + (dL_U/dx)^2) / k_d (links 4b and 5 of both
   halves, plus each half's drive side seen through its linkage: soft far from the
   toggle, stiff at it); an internal force pair N(x) solves
   s_e = (N / K_c)^(2/3) + c(x) N;
3. N loads every pin of both halves; their friction circles dissipate
   P / |v| = sum_j rho_j |F_j| |dphi_j/dx|, felt at the input as a force
   opposing the motion; the stored elastic energy U(x) adds the conservative
   force dU/dx = N ds_e/dx - N^2/2 dc/dx (returned on the way back).

The pin friction is velocity-strengthening in boundary lubrication (steady-state
rate-and-state law, mu_b(v_s) = mu + (a - b) ln((v_s + v_c) / (v_ref + v_c)), v_s the
sliding speed at the pin) and falls as the lubricant film builds up, the faster and
the more lightly loaded the pin (Stribeck, in the Hersey ratio h = v_s / |F| of slip
speed to pin load): mu = mu_b(v_s) exp(-(h / h_s)^2). The two make the rate dependence
of Tables 6-8: F_TP rises with speed where the pins are heavily loaded (link 8 off by
0.5-0.75 mm) and falls where they are lightly loaded (0.25 mm).

Issue 18 (docs/unequal-halves.md section 9): all of that friction acts through a
hysteretic slip state z (Dahl's law in the crosshead travel, :func:`advance_slip_state`),
friction = z D; of the take-up work dU/dx only a share lambda (``takeup_return``) is
stored and returned, the rest is lost in friction-locked slip and joins D. In steady
sliding z = sgn v: the stateless ``force``.

The model is written once, with numpy ufuncs on the output of ``half_pose``,
and compiled to a CasADi function of (x, v, lower dims, upper dims, params), so
it evaluates on floats, numpy arrays and CasADi SX alike; ``extra_input_force``
is what the FMU plant calls each step.
"""

from __future__ import annotations

import functools
import math
from dataclasses import astuple, dataclass, fields
from pathlib import Path
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from toggle.kinematics import half_pose, is_symbolic, stroke_limits
from toggle.params import DIMENSIONS, HalfDims, Mechanism, PinRadii
from toggle.statics import force_ratios

#: Mismatch below which |dL| is rounded (smooth |.| for solvers), m; exactly 0 at dL = 0.
_ABS_EPS = 1e-12
#: Velocity scale of the smooth sign of the friction force, m/s.
_SIGN_EPS = 1e-6
#: Pin load added to the Hersey ratio's denominator (an unloaded pin has full film), N.
_LOAD_EPS = 1e-9
#: Pin radii for the frictionless statics (unused at mu = 0; any valid radii).
_NO_PINS = PinRadii(B=1e-3, C=1e-3, D=1e-3)
#: Floor of the clearance excess in the internal force's start, m (an attometre: below
#: any clearance; the force is 0 there anyway).
_EXCESS_FLOOR = 1e-18
#: Newton steps for the internal force (monotone from an upper bound; 1e-15 relative).
_NEWTON_STEPS = 12


class AsymmetryError(ValueError):
    """Parameters outside their physical range, or halves that cannot be forced together."""


@dataclass(frozen=True)
class AsymmetryParams:
    """Physical parameters of the forced-agreement model, SI.

    Defaults: the desktop clamp of Chang et al. 2021, fitted on every force statistic of
    Tables 6 and 7 with the prototype's as-built error and platen friction (free_play,
    contact_stiffness, drive_stiffness; takeup_return and rate_strengthening from earlier
    fits, the latter at its limit of zero friction at rest; boundary friction, which the
    fits chose) and
    the rest from its materials and sizes (docs/unequal-halves.md, sections 4 and 9;
    the shipped fit: docs/unequal-halves-results.md, section 9.5).
    """

    free_play: float = 0.1441e-3  # delta0, m: platen tilt in the bushings + pin clearances
    contact_stiffness: float = 5.775e8  # K_c, N/m^1.5: N = K_c s_c^1.5 for the closed clearances
    series_stiffness: float = 3.3e7  # k_s, N/m: links 4b and 5 of both halves in series (A6061)
    drive_stiffness: float = 2.941e4  # k_d, N/m per half: crosshead tilt on its shaft, link 3, pins
    mu: float = 0.3  # pin friction coefficient at the reference slip speed (SUS304 pin in A6061)
    rate_strengthening: float = 0.04342  # a - b of the steady-state rate-and-state law
    reference_slip: float = 1.0e-3  # v_ref, m/s: slip speed at which the coefficient is mu
    slip_velocity: float = 1.0e-6  # v_c, m/s: regularises the log law at rest
    #: h_s, m/(s N): Hersey ratio (pin slip speed / pin load) at which the lubricant film has
    #: lowered the friction to 1/e of boundary friction; inf = boundary lubrication only.
    hersey_transition: float = math.inf
    pins: PinRadii = PinRadii(B=4.0e-3, C=4.0e-3, D=4.0e-3)
    #: Internal force above which the halves cannot be forced together elastically (yield), N.
    max_internal_force: float = 2.0e4
    #: lambda, 1: share of the take-up work the clamp gives back (1: the take-up is elastic,
    #: the stateless model of issue 8; 0: it is all lost in friction-locked slip)
    takeup_return: float = 0.1517
    #: x_s, m: crosshead travel over which the slip state turns after a reversal (Dahl)
    slip_distance: float = 0.1e-3

    def __post_init__(self) -> None:
        ranges = {
            "free_play": (0.0, 5e-3),
            "contact_stiffness": (1e5, 1e12),
            "series_stiffness": (1e4, 1e12),
            "drive_stiffness": (1e3, 1e12),
            "mu": (0.0, 1.0),
            "rate_strengthening": (0.0, 0.1),
            "reference_slip": (1e-9, 1.0),
            "slip_velocity": (1e-12, 1.0),
            "hersey_transition": (1e-12, math.inf),
            "max_internal_force": (1.0, 1e9),
            "takeup_return": (0.0, 1.0),
            "slip_distance": (1e-9, 1e-2),
        }
        for name, (lo, hi) in ranges.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                lo <= value <= hi and (math.isfinite(value) or hi == math.inf)
            ):
                raise AsymmetryError(f"{name} must lie in [{lo:g}, {hi:g}] (SI), got {value!r}")
        at_rest = self.mu - self.rate_strengthening * math.log(
            (self.reference_slip + self.slip_velocity) / self.slip_velocity)
        if at_rest < 0:
            raise AsymmetryError(
                f"the friction law gives a negative coefficient at rest ({at_rest:.3g}): "
                "raise mu or lower rate_strengthening"
            )
        if max(astuple(self.pins)) > 0.05:
            raise AsymmetryError(f"pin radii above 50 mm are not a desktop clamp: {self.pins}")

    def replace(self, **changes: float) -> AsymmetryParams:
        return type(self)(**{**{f.name: getattr(self, f.name) for f in fields(self)}, **changes})

    def vector(self) -> np.ndarray:
        """The parameters in the order of the compiled model's input ``q``."""
        return np.array([self.free_play, self.contact_stiffness, self.series_stiffness,
                         self.drive_stiffness, self.mu, self.rate_strengthening,
                         self.reference_slip, self.slip_velocity,
                         self.pins.B, self.pins.C, self.pins.D, 1 / self.hersey_transition,
                         self.takeup_return])


class Asymmetry(NamedTuple):
    """Model output at (x, v): forces in N, mismatch in m."""

    force: Any  # extra input force in steady sliding (slip state = sign of v), N
    friction: Any  # its dissipative part, N (sign of v)
    elastic: Any  # its conservative part lambda dU/dx, N
    internal_force: Any  # N, the force pair between the halves and the platen
    mismatch: Any  # L_U - L_L, m
    dissipation: Any  # D >= 0, N: pin friction plus the lost take-up, friction = z D


# --- the model, written once -------------------------------------------------------------


def _pin_loads(x: Any, pose: Any, dims: Any, n: Any) -> tuple[Any, Any, Any, Any, Any]:
    """Pin-force magnitudes |F_A|, |F_B|, |F_C|, |F_D|, |F_E| of a half with output force n.

    The axial forces of the two-force links 5 (A-B) and 3 (E-D) come from the statics
    (:func:`toggle.statics.force_ratios` with mu = 0: the friction is first order in mu);
    pin C carries their resultant, link 5 along u5 = (cos th5, sin th5) and link 3 along
    u3 = (cos th3, sin th3).
    """
    ratios = force_ratios(x, dims, _NO_PINS, 0.0)
    th3, th5 = pose.theta3, pose.theta5
    # pin C per unit n: |n| outside the root keeps its derivative finite at n = 0 (free play)
    c_x = ratios.link1 * np.cos(th5) - ratios.crosshead_link * np.cos(th3)
    c_y = ratios.link1 * np.sin(th5) - ratios.crosshead_link * np.sin(th3)
    f5, t3 = np.fabs(n * ratios.link1), np.fabs(n * ratios.crosshead_link)
    return f5, f5, np.fabs(n) * np.sqrt(c_x * c_x + c_y * c_y), t3, t3


def _friction_power(x: Any, v: Any, dims: Any, n: Any, q: Any) -> Any:
    """Friction-circle dissipation of one half per unit input speed, N (>= 0)."""
    pose = half_pose(x, dims, check=False)
    rate = [ca.jacobian(a, x) for a in (pose.theta3, pose.theta4, pose.theta5)]
    d3, d4, d5 = rate
    turns = (d5, d5 - d4, d4, d3 - d4, d3)  # relative rotation per unit x at A, B, C, D, E
    radii = (q[8], q[8], q[9], q[10], q[10])  # joint A as B, E as D (toggle.params.PinRadii)
    mu_ref, ab, v_ref, v_c, inv_hersey = q[4], q[5], q[6], q[7], q[11]
    total = 0
    for load, turn, r in zip(_pin_loads(x, pose, dims, n), turns, radii, strict=True):
        slip = r * np.fabs(turn) * np.fabs(v)
        film = slip / (load + _LOAD_EPS) * inv_hersey  # h / h_s
        mu = (mu_ref + ab * np.log((slip + v_c) / (v_ref + v_c))) * np.exp(-film * film)
        total = total + mu / np.sqrt(1 + mu * mu) * r * load * np.fabs(turn)
    return total


def _internal_force(excess: Any, compliance: Any, k_contact: Any) -> Any:
    """N solving excess = (N / K_c)^(2/3) + compliance N, by Newton on y = N^(1/3).

    g(y) = c y^3 + a y^2 - s is convex and increasing for y >= 0, so Newton from the
    upper bound min(sqrt(s / a), cbrt(s / c)) decreases monotonically to the root.
    """
    a = k_contact ** (-2.0 / 3.0)
    # the start's roots from a floor: at excess 0 (within the free play) their derivatives
    # are infinite, and 0 times infinity is NaN in the planner's exact derivatives
    s = np.fmax(excess, _EXCESS_FLOOR)
    y = np.fmin(np.sqrt(s / a), (s / compliance) ** (1.0 / 3.0))
    for _ in range(_NEWTON_STEPS):
        g = compliance * y**3 + a * y * y - excess
        y = y - g / (3 * compliance * y * y + 2 * a * y + 1e-300)
    return y**3 * (excess > 0)  # exactly 0 within the free play


@functools.cache
def _model() -> ca.Function:
    """CasADi function (x, v, lower[8], upper[8], q[13]) -> force, friction, elastic, N, dL, D."""
    x, v = ca.SX.sym("x"), ca.SX.sym("v")
    pl, pu = ca.SX.sym("lower", len(DIMENSIONS)), ca.SX.sym("upper", len(DIMENSIONS))
    q = ca.SX.sym("q", 13)
    dims_l = [pl[i] for i in range(len(DIMENSIONS))]
    dims_u = [pu[i] for i in range(len(DIMENSIONS))]
    free_play, k_contact, k_series, k_drive = q[0], q[1], q[2], q[3]

    L_l, L_u = half_pose(x, dims_l, check=False).L, half_pose(x, dims_u, check=False).L
    slope_l, slope_u = ca.jacobian(L_l, x), ca.jacobian(L_u, x)
    mismatch = L_u - L_l
    size = np.sqrt(mismatch * mismatch + _ABS_EPS**2) - _ABS_EPS
    excess = np.fmax(size - free_play, 0)
    compliance = 1 / k_series + (slope_l * slope_l + slope_u * slope_u) / k_drive
    n = _internal_force(excess, compliance, k_contact)
    # dU/dx at equilibrium: dU/ds_e = N, dU/dc at fixed s_e = -N^2 / 2 (envelope theorem)
    takeup = n * ca.jacobian(excess, x) - 0.5 * n * n * ca.jacobian(compliance, x)
    # the take-up: a share lambda is stored and returned (conservative), the rest is lost in
    # friction-locked slip, against the motion in either direction (docs/unequal-halves.md)
    returned = q[12]
    elastic = returned * takeup
    power = (_friction_power(x, v, dims_l, n, q) + _friction_power(x, v, dims_u, n, q)
             + (1 - returned) * np.fabs(takeup))
    friction = steady_slip_state(v) * power
    return ca.Function("asymmetry", [x, v, pl, pu, q],
                       [friction + elastic, friction, elastic, n, mismatch, power],
                       ["x", "v", "lower", "upper", "q"],
                       ["force", "friction", "elastic", "internal_force", "mismatch",
                        "dissipation"],
                       {"cse": True})


# --- the slip state (hysteresis) -----------------------------------------------------------


def steady_slip_state(v: Any) -> Any:
    """Slip state in steady sliding at speed v (m/s): a smooth sign, 0 at rest."""
    return v / np.sqrt(v * v + _SIGN_EPS**2)


def advance_slip_state(z: Any, dx: Any, slip_distance: float) -> Any:
    """Slip state after a monotone crosshead move dx (m) from state z (Dahl's law, exact).

    dz/dx = (sgn(dx) - z) / x_s: after a reversal the friction turns over a travel of a
    few x_s instead of at once, and it holds while the crosshead stands still.
    """
    target = np.sign(dx)
    return target - (target - z) * np.exp(-np.fabs(dx) / slip_distance)


def slip_state_along(x: np.ndarray, z0: float, slip_distance: float) -> np.ndarray:
    """Slip state at every point of a monotone path x (m) that starts in state z0."""
    x = np.asarray(x, dtype=float)
    return advance_slip_state(z0, x - x[0], slip_distance)


def hysteretic_force(out: Asymmetry, z: Any) -> Any:
    """Extra input force (N) in slip state z: z D + lambda dU/dx (z = sign v: ``out.force``)."""
    return z * out.dissipation + out.elastic


# --- public API ----------------------------------------------------------------------------


def _dims_vector(dims: HalfDims | Any) -> Any:
    if isinstance(dims, HalfDims):
        return np.array(dims.as_tuple())
    if isinstance(dims, tuple) and is_symbolic(*dims):  # eight symbolic dimensions
        return ca.vertcat(*dims)
    return dims


def asymmetry(
    x: Any, v: Any, lower: HalfDims | Any, upper: HalfDims | Any,
    params: AsymmetryParams = AsymmetryParams(),
) -> Asymmetry:
    """Forces of the forced agreement of two halves at crosshead position x (m), speed v (m/s).

    Floats or arrays (broadcast together) give numpy arrays; CasADi SX/MX in any
    argument give symbolic expressions. A numeric input where either half cannot
    assemble raises :class:`toggle.kinematics.AssemblyError` naming the half.
    """
    f = _model()
    if is_symbolic(x, v, lower, upper):
        out = f(x, v, _dims_vector(lower), _dims_vector(upper), params.vector())
        return Asymmetry(*out)
    xs, vs = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(v, dtype=float))
    if not np.all(np.isfinite(vs)):
        raise AsymmetryError(f"speed must be finite, got {v!r}")
    half_pose(xs, lower, label="lower half")  # raises AssemblyError where needed
    half_pose(xs, upper, label="upper half")
    out = f(xs.reshape(1, -1), vs.reshape(1, -1), _dims_vector(lower), _dims_vector(upper),
            params.vector())
    result = Asymmetry(*(np.asarray(o).reshape(xs.shape) for o in out))
    worst = int(np.argmax(result.internal_force))
    if result.internal_force.ravel()[worst] > params.max_internal_force:
        raise AsymmetryError(
            f"the halves cannot be forced together elastically: at x = {xs.ravel()[worst]:.6g} m "
            f"their mismatch {result.mismatch.ravel()[worst]:.3g} m needs an internal force of "
            f"{result.internal_force.ravel()[worst]:.3g} N > {params.max_internal_force:g} N"
        )
    return result


def extra_input_force(
    x: Any, v: Any, lower: HalfDims | Any, upper: HalfDims | Any,
    params: AsymmetryParams = AsymmetryParams(),
) -> Any:
    """Extra crosshead force (N) from unequal halves: the FMU plant's per-step call.

    Add it to the force the drive must deliver: positive resists closing (v > 0);
    zero for equal halves. Floats, arrays or CasADi SX (see :func:`asymmetry`).
    """
    return asymmetry(x, v, lower, upper, params).force


def toggle_force(
    mech: Mechanism, speed: float, params: AsymmetryParams = AsymmetryParams(),
    x_toggle: float | None = None,
) -> float:
    """Predicted extra input force at the toggle in the forward stroke, F_TP (N).

    ``x_toggle`` defaults to the lower (unaltered) half's toggle, the paper's 51.566 mm.
    """
    if not (math.isfinite(speed) and speed > 0):
        raise AsymmetryError(f"forward speed must be positive, got {speed!r} m/s")
    x_tp = stroke_limits(mech.lower)[1] if x_toggle is None else x_toggle
    return float(asymmetry(x_tp, speed, mech.lower, mech.upper, params).force)


def force_curves(
    mech: Mechanism, speed: float, params: AsymmetryParams = AsymmetryParams(), points: int = 300,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, forward force, backward force) over the lower half's stroke, m and N."""
    x_open, x_tp = stroke_limits(mech.lower)
    xs = np.linspace(x_open, x_tp, points)
    fwd = asymmetry(xs, speed, mech.lower, mech.upper, params).force
    back = asymmetry(xs, -speed, mech.lower, mech.upper, params).force
    return xs, fwd, back


def plot_force_curves(
    mech: Mechanism, path: Path, speed: float = 5e-3,
    errors: tuple[float, ...] = (0.0, 0.25e-3, 0.5e-3, 0.75e-3),
    params: AsymmetryParams = AsymmetryParams(),
) -> Path:
    """PNG of the extra input force against x, forward and backward, one curve per delta_r8."""
    from toggle.plots import plt, save_figure

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, err in enumerate(errors):
        xs, fwd, back = force_curves(mech.with_error("upper", "r5", err), speed, params)
        colour = f"C{i}"
        ax.plot(xs * 1e3, fwd, color=colour, label=f"Δr8 = {err * 1e3:.2f} mm forward")
        ax.plot(xs * 1e3, back, color=colour, ls="--", label=f"Δr8 = {err * 1e3:.2f} mm backward")
    ax.axhline(0, color="0.6", lw=0.8)
    ax.set_xlabel("input position x (mm)")
    ax.set_ylabel("extra input force (N)")
    ax.set_title(f"{mech.name}: unequal halves, v = {speed * 1e3:g} mm/s")
    ax.legend(fontsize=7, ncol=2)
    return save_figure(fig, Path(path))
