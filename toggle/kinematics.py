"""Closed-form kinematics of one half of the nine-link double-toggle clamp.

This module is the one source of the clamp's position equations (Chang, Lee &
Hsu 2021, Eqs 2-17). They are written once, with numpy ufuncs, so the same
function evaluates on floats, on numpy arrays (vectorised Monte Carlo) and on
CasADi SX symbols (exact derivatives, optimisation, code generation):
``casadi.GlobalOptions.setNumpyMode(True)`` makes numpy ufuncs dispatch on SX.

Geometry of a half (the lower one; the upper half is its mirror image, so the
same function serves it with the upper half's own dimensions): the fixed pivot
of the triangular link 4 is the origin; the crosshead pin moves along a line at
vertical distance d = r1 - r2 from it, at horizontal position x; link 3 (r3)
joins the crosshead pin to the corner of link 4 at r4a from the pivot; link 5
(r5) joins the corner at r4b to the platen joint, at vertical offset e from the
pivot, whose horizontal position is the output L(x).

Signs lost in the extracted text of the paper, reconstructed from Figure 4 and
checked against its numbers (stroke 45.003 mm, theta8 = -2.729 deg at x_TP):

* Eq 4:  theta4 = 90 deg - (alpha4 + gamma1 + gamma2)
* Eq 14: theta3 = 270 deg - gamma1 + acos((l^2 + r3^2 - r4a^2) / (2 l r3))
* Eq 15: theta5 = 360 deg - asin((r4b sin theta4 - e) / r5)
* Eq 2:  L = r4b cos theta4 + sqrt(r5^2 - (r4b sin theta4 - e)^2)
* Eqs 5, 16, 17 (upper half): theta7 = 360 deg - theta4, theta6 = 360 deg - theta3,
  theta8 = -asin((r7b sin theta7 + eU) / r8) = 360 deg - theta5 (leading minus).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from toggle.params import DIMENSIONS, HalfDims
from toggle.roots import brentq

ca.GlobalOptions.setNumpyMode(True)

_TWO_PI = 2.0 * math.pi
#: Rounding slack on the arguments of acos/asin/sqrt before a geometry is
#: declared unassemblable (values this close to the limit are clipped).
_DOMAIN_SLACK = 1e-12


class AssemblyError(ValueError):
    """The mechanism cannot assemble at the requested input position."""


class HalfPose(NamedTuple):
    """Position of one half at input x (rad and m; seed 000's angle conventions)."""

    L: Any
    theta3: Any
    theta4: Any
    theta5: Any
    gamma1: Any
    gamma2: Any
    alpha4: Any
    l: Any


class HalfMotion(NamedTuple):
    """Position, velocity ratio and its derivative for one half (numeric)."""

    L: np.ndarray
    dL_dx: np.ndarray
    d2L_dx2: np.ndarray
    theta3: np.ndarray
    theta4: np.ndarray
    theta5: np.ndarray
    mechanical_advantage: np.ndarray


#: CasADi types, including the wrappers numpy mode returns from ufuncs.
_SYMBOLIC_TYPES = (ca.SX, ca.MX, ca.casadi.ArrayInterface)


def is_symbolic(*values: Any) -> bool:
    """Whether any value is a CasADi expression (the model then builds, not computes)."""
    return any(isinstance(v, _SYMBOLIC_TYPES) for v in values)


def _within(arg: Any, lo: float, hi: float, loop: str, x: Any, label: str) -> Any:
    """Check a numeric acos/asin/sqrt argument; return it clipped to [lo, hi].

    Symbolic arguments pass unchanged: an optimiser keeps them feasible
    through its constraints, not through this check.
    """
    if isinstance(arg, float):  # scalar fast path (np.float64 is a float)
        if lo - _DOMAIN_SLACK <= arg <= hi + _DOMAIN_SLACK:
            return min(max(arg, lo), hi)
        arg = np.asarray(arg)
    elif is_symbolic(arg):
        return arg
    arg = np.asarray(arg, dtype=float)
    bad = ~((arg >= lo - _DOMAIN_SLACK) & (arg <= hi + _DOMAIN_SLACK))
    if np.any(bad):
        i = int(np.flatnonzero(bad.ravel())[0])
        xi = float(np.broadcast_to(np.asarray(x, dtype=float), arg.shape).ravel()[i])
        value = float(arg.ravel()[i])
        raise AssemblyError(
            f"{label} cannot assemble at x = {xi:.6g} m: {loop} "
            f"(argument {value:.6g} outside [{lo:g}, {hi:g}])"
        )
    return np.clip(arg, lo, hi)


def _values(dims: HalfDims | Sequence[Any]) -> tuple[Any, ...]:
    if isinstance(dims, HalfDims):
        return dims.as_tuple()
    values = tuple(dims)
    if len(values) != len(DIMENSIONS):
        raise ValueError(f"expected {len(DIMENSIONS)} dimensions {DIMENSIONS}, got {len(values)}")
    return values


def _chain(x: Any, dims: HalfDims | Sequence[Any], check: bool, label: str) -> tuple[Any, ...]:
    """The output chain of a half: (L, theta4, theta5, gamma1, gamma2, alpha4, l, domain)."""
    r1, r2, r3, r4a, r4b, r4c, r5, e = _values(dims)

    def domain(arg: Any, loop: str) -> Any:
        return _within(arg, -1.0, 1.0, loop, x, label) if check else arg

    d = r1 - r2
    l = np.sqrt(x * x + d * d)  # Eq 12
    gamma1 = np.arcsin(x / l)  # Eq 7
    gamma2 = np.arccos(domain((l * l + r4a * r4a - r3 * r3) / (2 * l * r4a), _CROSSHEAD_LOOP))
    alpha4 = np.arccos(domain((r4a * r4a + r4b * r4b - r4c * r4c) / (2 * r4a * r4b),
                              "triangular link 4"))  # Eq 6
    theta4 = math.pi / 2 - (alpha4 + gamma1 + gamma2)  # Eq 4
    s5 = domain((r4b * np.sin(theta4) - e) / r5, "loop of link 5 and the platen joint")
    theta5 = _TWO_PI - np.arcsin(s5)  # Eq 15
    L = r4b * np.cos(theta4) + r5 * np.sqrt(1 - s5 * s5)  # Eq 2
    return L, theta4, theta5, gamma1, gamma2, alpha4, l, domain


_CROSSHEAD_LOOP = "loop of crosshead link 3 and link 4 (|r3 - r4a| <= l <= r3 + r4a)"


def half_pose(
    x: Any, dims: HalfDims | Sequence[Any], *, check: bool = True, label: str = "half"
) -> HalfPose:
    """Pose of one half at input position x (Eqs 2, 4, 6-8, 12, 14, 15).

    ``dims`` is a :class:`HalfDims` or eight values in its field order (floats,
    arrays broadcasting with x, or CasADi SX). With ``check`` a numeric input
    where the half cannot assemble raises :class:`AssemblyError` naming the
    loop and the input; without it such points come out as NaN (used only to
    scan for the assemblable range).
    """
    L, theta4, theta5, gamma1, gamma2, alpha4, l, domain = _chain(x, dims, check, label)
    r3, r4a = _values(dims)[2:4]
    theta3 = 1.5 * math.pi - gamma1 + np.arccos(
        domain((l * l + r3 * r3 - r4a * r4a) / (2 * l * r3), _CROSSHEAD_LOOP)
    )  # Eq 14
    return HalfPose(L, theta3, theta4, theta5, gamma1, gamma2, alpha4, l)


class HalfJoints(NamedTuple):
    """Joint centres of one half at input x, m, in the half's own frame: the fixed pivot of
    the triangular link at the origin, y towards the clamp axis (the crosshead pin at height
    d = r1 - r2, the platen joint at e). Each is an (x, y) pair of floats or arrays."""

    pivot: tuple[Any, Any]  # triangular link 4 on the tailstock platen (seed 000: D, A)
    crosshead: tuple[Any, Any]  # link 3 on the crosshead (input link 2)
    corner: tuple[Any, Any]  # link 3 on the triangular link, r4a from the pivot
    elbow: tuple[Any, Any]  # link 5 on the triangular link, r4b from the pivot (E, B)
    platen: tuple[Any, Any]  # link 5 on the moving platen (F, C): (L, e)


def half_joints(x: Any, dims: HalfDims, *, label: str = "half") -> HalfJoints:
    """Where every joint of one half is at input x (numeric), from :func:`half_pose`'s angles:
    the drawing of the mechanism, not a second solution of its loops."""
    pose = half_pose(x, dims, label=label)
    x = np.asarray(x, dtype=float)
    crosshead = (x, np.full_like(x, dims.d))
    corner = (x + dims.r3 * np.cos(pose.theta3), dims.d + dims.r3 * np.sin(pose.theta3))
    elbow = (dims.r4b * np.cos(pose.theta4), dims.r4b * np.sin(pose.theta4))
    platen = (elbow[0] + dims.r5 * np.cos(pose.theta5), elbow[1] + dims.r5 * np.sin(pose.theta5))
    return HalfJoints((np.zeros_like(x), np.zeros_like(x)), crosshead, corner, elbow, platen)


def clamp_joints(x: float, lower: HalfDims, upper: HalfDims) -> dict[str, HalfJoints]:
    """Every joint of both halves at crosshead position x, m, in the clamp's frame: the clamp
    axis is y = 0, the tailstock pivots at x = 0, the lower half below the axis (its pivot at
    y = -r1) and the upper half its mirror image above it, each with its own dimensions."""
    out = {}
    for name, dims, sign in (("lower", lower, -1.0), ("upper", upper, 1.0)):
        local = half_joints(x, dims, label=f"{name} half")
        out[name] = HalfJoints(*((px, sign * (dims.r1 - py)) for px, py in local))
    return out


def output_position(x: Any, dims: HalfDims | Sequence[Any], *, label: str = "half") -> Any:
    """Output (platen joint) position L(x) of one half, m (the pose without theta3)."""
    return _chain(x, dims, True, label)[0]


def mirror_angles(pose: HalfPose) -> tuple[Any, Any, Any]:
    """Upper-half angles (theta6, theta7, theta8) of a pose computed for the upper half.

    The upper half is the lower half's mirror image: theta6 = 2 pi - theta3,
    theta7 = 2 pi - theta4 and theta8 = 2 pi - theta5 (in (-pi/2, pi/2)).
    """
    return _TWO_PI - pose.theta3, _TWO_PI - pose.theta4, _TWO_PI - pose.theta5


@functools.cache
def _motion_function() -> ca.Function:
    """CasADi function (x, p) -> (L, dL/dx, d2L/dx2, dL/dp) of one half."""
    x = ca.SX.sym("x")
    p = ca.SX.sym("p", len(DIMENSIONS))
    L = ca.SX(half_pose(x, [p[i] for i in range(len(DIMENSIONS))]).L)
    dL = ca.jacobian(L, x)
    d2L = ca.jacobian(dL, x)
    return ca.Function("half_motion", [x, p], [L, dL, d2L, ca.jacobian(L, p)],
                       ["x", "p"], ["L", "dL_dx", "d2L_dx2", "dL_dp"])


def motion_terms(x: Any, dims: HalfDims) -> tuple[Any, Any, Any]:
    """(L, dL/dx, d2L/dx2) by the AD function, for numeric or symbolic x.

    No assembly check: symbolic callers (the plant, the planner) keep x inside
    :func:`assemblable_range` themselves.
    """
    values = _values(dims)
    if is_symbolic(*values):  # symbolic dimensions (the native FMU's parameters)
        L, dL, d2L, _ = _motion_function()(x, ca.vertcat(*values))
        return L, dL, d2L
    p = np.array(values)
    if is_symbolic(x):
        L, dL, d2L, _ = _motion_function()(x, p)
        return L, dL, d2L
    x = np.asarray(x, dtype=float)
    out = _motion_function()(x.reshape(1, -1), p)
    return tuple(np.asarray(o).reshape(x.shape) for o in out[:3])


def _evaluate(
    x: Any, dims: HalfDims, label: str
) -> tuple[np.ndarray, HalfPose, list[np.ndarray]]:
    """The checked pose by the numpy path (AssemblyError where needed), then the AD function."""
    x_arr = np.asarray(x, dtype=float)
    pose = half_pose(x_arr, dims, label=label)
    out = _motion_function()(x_arr.reshape(1, -1), np.array(dims.as_tuple()))
    return x_arr, pose, [np.asarray(o) for o in out]


#: A velocity ratio dL/dx this small is the toggle's zero, m/m (rounding leaves ~1e-16;
#: the advantage it stands for, above 1e12, is no clamp's).
TOGGLE_RATIO = 1e-12


def half_motion(x: Any, dims: HalfDims, *, label: str = "half") -> HalfMotion:
    """L, dL/dx, d2L/dx2 (exact, by AD), angles and ideal mechanical advantage.

    The ideal mechanical advantage of the whole clamp is output force over
    input force without friction; by virtual work it is 1 / (dL/dx). At the toggle it is
    unbounded: where |dL/dx| is below :data:`TOGGLE_RATIO` (rounding there gave dL/dx =
    -1.6e-16, an advantage of -6.4e15) it is +inf.
    """
    x_arr, pose, (L, dL, d2L, _) = _evaluate(x, dims, label)
    shape = x_arr.shape
    dL = dL.reshape(shape)
    at_toggle = np.abs(dL) <= TOGGLE_RATIO
    with np.errstate(divide="ignore", over="ignore"):
        ma = np.where(at_toggle, np.inf, 1.0 / np.where(at_toggle, 1.0, dL))
    return HalfMotion(L.reshape(shape), dL, d2L.reshape(shape), np.asarray(pose.theta3),
                      np.asarray(pose.theta4), np.asarray(pose.theta5), ma)


def sensitivities(x: Any, dims: HalfDims, *, label: str = "half") -> dict[str, np.ndarray]:
    """Exact sensitivities dL/dp of the output to every dimension at fixed x."""
    x_arr, _, (_, _, _, jac) = _evaluate(x, dims, label)
    jac = jac.reshape(-1, len(DIMENSIONS))
    return {name: jac[:, i].reshape(x_arr.shape) for i, name in enumerate(DIMENSIONS)}


def _assemblable_grid(dims: HalfDims, n: int = 4001) -> tuple[np.ndarray, HalfPose]:
    """Scan x over the geometric reach and return the points that assemble."""
    reach = dims.r3 + dims.r4a
    xs = np.linspace(-reach, reach, n)
    with np.errstate(invalid="ignore"):
        pose = half_pose(xs, dims, check=False)
    ok = np.isfinite(pose.L) & np.isfinite(pose.theta3)
    if not np.any(ok):
        shown = ", ".join(f"{k} = {v * 1e3:.4g}" for k, v in zip(DIMENSIONS, dims.as_tuple()))
        raise AssemblyError(f"the half ({shown} mm) cannot assemble at any input position")
    return xs[ok], HalfPose(*(np.asarray(v)[ok] if np.ndim(v) else v for v in pose))


@functools.lru_cache(maxsize=256)
def assemblable_range(dims: HalfDims) -> tuple[float, float]:
    """The interval of input positions around the stroke where the half assembles, m.

    The ends are found to 1e-12 m by bisection between the scan's last
    assemblable point and the next one that is not.
    """
    reach = dims.r3 + dims.r4a
    xs = np.linspace(-reach, reach, 4001)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(half_pose(xs, dims, check=False).theta3)
    x_open, x_tp = stroke_limits(dims)
    i = int(np.searchsorted(xs, x_open))
    lo, hi = i, i
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    while hi < xs.size - 1 and ok[hi + 1]:
        hi += 1

    def edge(good: float, bad: float) -> float:
        while abs(bad - good) > 1e-12:
            mid = 0.5 * (good + bad)
            with np.errstate(invalid="ignore"):
                fine = bool(np.isfinite(half_pose(mid, dims, check=False).theta3))
            good, bad = (mid, bad) if fine else (good, mid)
        return good

    x_lo = edge(xs[lo], xs[lo - 1]) if lo > 0 else float(xs[0])
    x_hi = edge(xs[hi], xs[hi + 1]) if hi < xs.size - 1 else float(xs[-1])
    return float(x_lo), float(x_hi)


def _roots(xs: np.ndarray, g: np.ndarray, f: Any) -> list[float]:
    """All roots of f on the grid xs, where g = f(xs), refined by Brent's method."""
    idx = np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)
    tol = 4 * np.finfo(float).eps
    return [float(brentq(f, xs[i], xs[i + 1], xtol=1e-15, rtol=tol)) for i in idx]


@functools.lru_cache(maxsize=256)
def stroke_limits(dims: HalfDims) -> tuple[float, float]:
    """Open and toggle input positions (x_open, x_TP) of one half, m.

    x_TP is a maximum of L(x): there links 4b and 5 are collinear
    (dL/dtheta4 = 0), i.e. sin(theta4) = e / (r4b + r5). theta4(x) is not
    monotonic, so L(x) has a second equal maximum further on (about 70.5 mm
    for chang2021); the toggle is the first one. The open position is where
    link 3 is horizontal (theta3 = 360 deg), the last such root before the
    toggle; a clamp whose link 3 never becomes horizontal (L4 < dE, as the
    SM-55 of seed 001) opens where link 3 comes nearest to it (the maximum of
    theta3 before the toggle). Roots come from a scan of the assemblable range,
    refined by Brent's method; results are cached per (immutable) half.
    """
    xs, pose = _assemblable_grid(dims)
    target = math.asin(dims.e / (dims.r4b + dims.r5))
    collinear = _roots(xs, np.asarray(pose.theta4) - target,
                       lambda x: float(half_pose(x, dims).theta4) - target)
    if not collinear:
        raise AssemblyError(
            "no toggle: links 4b and 5 never become collinear in the assemblable range "
            f"[{xs[0]:.6g}, {xs[-1]:.6g}] m"
        )
    x_tp = collinear[0]
    horizontal = [x for x in _roots(xs, np.asarray(pose.theta3) - _TWO_PI,
                                    lambda x: float(half_pose(x, dims).theta3) - _TWO_PI)
                  if x < x_tp]
    if horizontal:
        return horizontal[-1], x_tp
    before = xs < x_tp
    i = int(np.argmax(np.where(before, np.asarray(pose.theta3), -np.inf)))
    lo, hi = xs[max(i - 1, 0)], xs[min(i + 1, int(np.count_nonzero(before)) - 1)]
    from scipy.optimize import minimize_scalar  # only here: its import costs 0.3 s

    best = minimize_scalar(lambda x: -float(half_pose(x, dims).theta3), bounds=(lo, hi),
                           method="bounded", options={"xatol": 1e-13})
    return float(best.x), x_tp


def _crank_horizontal(dims: HalfDims) -> list[float]:
    """Where link 3 is horizontal (theta3 = 360 deg), from the loop of links 3 and 4 alone
    (theta3 does not depend on link 5: a link 5 too short must not move the open position
    to wherever the half happens to assemble)."""
    reach = dims.r3 + dims.r4a
    xs = np.linspace(-reach, reach, 4001)

    def theta3(x: Any) -> Any:
        with np.errstate(invalid="ignore"):
            return half_pose(x, dims, check=False).theta3 - _TWO_PI
    # a sign change only between neighbours where the loop closes (NaN compares false)
    g = np.asarray(theta3(xs))
    with np.errstate(invalid="ignore"):
        idx = np.flatnonzero(g[:-1] * g[1:] < 0)
    tol = 4 * np.finfo(float).eps
    return [float(brentq(lambda x: float(theta3(x)), xs[i], xs[i + 1], xtol=1e-15, rtol=tol))
            for i in idx]


@functools.lru_cache(maxsize=256)
def check_stroke(dims: HalfDims, x_open: float | None = None, *, label: str = "half") -> None:
    """Refuse dimensions that cannot make the double-toggle clamp: the half must have a
    toggle and assemble at every position from its open position (``x_open``, a preset's
    own, or where link 3 is horizontal) to it. :func:`stroke_limits` alone would open such a
    half wherever it happens to assemble (``r5 = 5e-3`` in chang2021: a 5.38 mm stroke
    starting at 36.6 mm); this names the loop that fails and where (:class:`AssemblyError`).
    """
    x_first, x_tp = stroke_limits(dims)
    how = ""
    if x_open is None:
        horizontal = [x for x in _crank_horizontal(dims) if x < x_tp]
        x_open, how = (horizontal[-1], "link 3 horizontal, ") if horizontal else (x_first, "")
    where = f"its open position ({how}x = {x_open * 1e3:.4g} mm)"
    if not x_open < x_tp:
        raise AssemblyError(f"not a double-toggle clamp: the {label} opens at x = "
                            f"{x_open * 1e3:.4g} mm, not before its toggle at {x_tp * 1e3:.4g} mm")
    xs = np.linspace(x_open, x_tp, 401)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(half_pose(xs, dims, check=False).L)
    if np.all(ok):
        return
    bad = float(xs[np.flatnonzero(~ok)[0]])
    try:
        half_pose(bad, dims)
    except AssemblyError as exc:  # "... at x = X m: LOOP (argument A outside [-1, 1])"
        why = str(exc).split(": ", 1)[-1].split(" (argument")[0] + " does not close"
    else:  # pragma: no cover - NaN without a domain error
        why = "loops do not close"
    raise AssemblyError(
        f"not a double-toggle clamp: the {label} cannot move from {where} to the toggle "
        f"(x = {x_tp * 1e3:.4g} mm); at x = {bad * 1e3:.4g} mm the {why}")


def toggle_position(dims: HalfDims) -> float:
    """Input position x_TP of the toggle (first maximum of L(x)), m."""
    return stroke_limits(dims)[1]


def open_position(dims: HalfDims) -> float:
    """Input position x_open where link 3 is horizontal (theta3 = 360 deg), m."""
    return stroke_limits(dims)[0]


def stroke(dims: HalfDims) -> float:
    """Output stroke L(x_TP) - L(x_open) of one half, m."""
    x_open, x_tp = stroke_limits(dims)
    return float(output_position(x_tp, dims) - output_position(x_open, dims))
