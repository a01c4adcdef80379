"""Design study of one clamp half over its toggle angle (seed 004, Li et al.).

For a half and a range of toggle angles: the strokes of crosshead and platen
and their ratio, the velocity ratio, the force amplification and the coping
angle; the ranking of a preset family's groups by four criteria; and a sweep of
any two dimensions of a half over a grid with the same criteria.

Every measure comes from the one mechanism model: positions and dL/dx from
:mod:`toggle.kinematics` (``half_pose``, ``half_motion``), the frictionless
force ratio from the force balance of :mod:`toggle.statics` on the pose's
angles. So "force ratio = 1 / velocity ratio" (virtual work) is a check of two
computations, not an identity. The force amplification Mp is the paper's, its
Eq 6: the strokes' ratio S0 / Sm from lock-up (8.19 for group 1 at 1 deg), which
``toggle design`` takes too; near lock-up it is twice the force ratio (the
platen stroke grows as the angle squared).

Definitions (seed 004's names; mapping in docs/li-micro-mapping.md):

* lock-up: the toggle position x_lock of :func:`toggle.kinematics.toggle_position`,
  links 4b and 5 collinear, theta4 = asin(e / (r4b + r5)) (the paper's gamma0).
* toggle angle alpha = theta4(x) - theta4(x_lock): the back toggle's rotation
  away from lock-up; opening moves the crosshead to smaller x.
* crosshead stroke S0 = x_lock - x, platen stroke Sm = L(x_lock) - L(x),
  stroke ratio Ms = Sm / S0 (Eq 3), velocity ratio Mv = dSm/dS0 = dL/dx (Eq 4),
  force amplification Mp = S0 / Sm (Eq 6, the strokes of Eqs 1 and 2 exact),
  mechanical advantage = platen force / crosshead force without friction (Eq 5's
  V0 / Vm read as speeds: 1 / Mv).
* coping angle psi = 2 pi - theta3: inclination of the crosshead link to the
  crosshead's line of motion, signed as the paper's Eq 7,
  sin psi = (H - h - L3 sin(gamma0 + theta + alpha)) / L4.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from toggle.kinematics import AssemblyError, half_motion, half_pose, toggle_position
from toggle.params import (
    DIMENSIONS,
    HalfDims,
    ParameterError,
    PinRadii,
    load_preset,
    preset_groups,
    split_group,
)
from toggle.statics import mechanical_advantage

#: Samples of the scans that bracket lock-up and the toggle-angle range.
_SCAN_POINTS = 4001
#: Bisection steps that refine a bracket of the scan to machine precision.
_BISECTIONS = 52
#: Pin radii do not enter the force balance without friction (mu = 0).
_FRICTIONLESS_PINS = PinRadii(B=1.0, C=1.0, D=1.0)


class ToggleRangeError(AssemblyError):
    """The half cannot reach the requested toggle angle (it fails to assemble first).

    ``alpha_limit`` (rad) is the largest toggle angle it reaches, ``x_limit`` (m)
    the crosshead position there.
    """

    def __init__(self, message: str, alpha_limit: float, x_limit: float) -> None:
        super().__init__(message)
        self.alpha_limit = alpha_limit
        self.x_limit = x_limit


def _scan(xs: np.ndarray, dims: HalfDims) -> np.ndarray:
    """theta4 at xs, NaN where any loop of the half fails to close."""
    with np.errstate(invalid="ignore"):
        pose = half_pose(xs, dims, check=False)
    theta4 = np.asarray(pose.theta4, dtype=float)
    ok = np.isfinite(pose.L) & np.isfinite(pose.theta3)
    return np.where(ok, theta4, np.nan)


class _Opening(NamedTuple):
    """Scan from lock-up towards smaller x; alpha rises on xs[:n]."""

    xs: np.ndarray
    alpha: np.ndarray
    n: int
    theta_lock: float


def _opening_scan(dims: HalfDims, x_lock: float) -> _Opening:
    xs = np.linspace(x_lock, -(dims.r3 + dims.r4a), _SCAN_POINTS)
    theta4 = _scan(xs, dims)
    alpha = theta4 - theta4[0]
    rising = np.isfinite(alpha) & (np.diff(alpha, prepend=-np.inf) > 0)
    n = len(xs) if rising.all() else int(np.argmin(rising))
    return _Opening(xs, alpha, n, float(theta4[0]))


def _range_error(dims: HalfDims, scan: _Opening, wanted: float, label: str) -> ToggleRangeError:
    """Locate where the half stops opening (to machine precision) and say why."""
    xs, n = scan.xs, scan.n
    x_ok = xs[n - 1]
    reason = f"{label}: the toggle angle stops increasing near x = {x_ok:.6g} m"
    if n < len(xs) and not np.isfinite(scan.alpha[n]):  # a loop fails: bisect the boundary
        x_bad = xs[n]
        for _ in range(_BISECTIONS):
            mid = 0.5 * (x_ok + x_bad)
            if np.isfinite(_scan(np.array([mid]), dims)[0]):
                x_ok = mid
            else:
                x_bad = mid
        try:  # the first failing scan point, not x_bad: the check allows rounding slack
            half_pose(xs[n], dims, label=label)
        except AssemblyError as exc:
            reason = str(exc)
    limit = float(_scan(np.array([x_ok]), dims)[0] - scan.theta_lock)
    return ToggleRangeError(
        f"{reason}; it reaches a toggle angle of only {math.degrees(limit):.4f} deg "
        f"(requested {math.degrees(wanted):.4f} deg)",
        alpha_limit=limit, x_limit=float(x_ok),
    )


def angle_reach(dims: HalfDims, *, label: str = "half") -> float:
    """Largest toggle angle (rad) the half reaches before it fails to assemble."""
    scan = _opening_scan(dims, toggle_position(dims))
    if scan.n == len(scan.xs):
        return float(scan.alpha[-1])
    return _range_error(dims, scan, math.inf, label).alpha_limit


def crosshead_positions(dims: HalfDims, alphas: Any, *, x_lock: float | None = None,
                        label: str = "half") -> np.ndarray:
    """Crosshead positions x (m) at toggle angles ``alphas`` (rad, >= 0).

    Inverts theta4(x) of :func:`toggle.kinematics.half_pose` by bisection on a
    bracket from a scan. Raises :class:`ToggleRangeError` when the half fails to
    assemble before the largest requested angle.
    """
    alphas = np.asarray(alphas, dtype=float)
    if alphas.size == 0 or not np.all(np.isfinite(alphas)) or np.any(alphas < 0):
        raise ValueError(f"toggle angles must be finite and >= 0 rad, got {alphas.size} values "
                         f"from {np.min(alphas, initial=np.nan):g} rad")
    scan = _opening_scan(dims, toggle_position(dims) if x_lock is None else x_lock)
    xs, alpha = scan.xs[:scan.n], scan.alpha[:scan.n]
    wanted = float(alphas.max())
    if wanted > alpha[-1]:  # beyond the scan: up to the refined limit, or fail
        error = _range_error(dims, scan, wanted, label)
        if wanted > error.alpha_limit:
            raise error
        xs, alpha = np.append(xs, error.x_limit), np.append(alpha, error.alpha_limit)
    i = np.clip(np.searchsorted(alpha, alphas), 1, len(xs) - 1)
    x_hi, x_lo = xs[i - 1], xs[i]  # alpha(x_hi) < target <= alpha(x_lo)
    for _ in range(_BISECTIONS):
        mid = 0.5 * (x_hi + x_lo)
        below = _scan(mid, dims) - scan.theta_lock < alphas
        x_hi, x_lo = np.where(below, mid, x_hi), np.where(below, x_lo, mid)
    return 0.5 * (x_hi + x_lo)


class AngleMeasures(NamedTuple):
    """Seed 004's measures of one half against toggle angle (SI: rad, m, 1)."""

    alpha: np.ndarray
    x: np.ndarray
    crosshead_stroke: np.ndarray
    platen_stroke: np.ndarray
    stroke_ratio: np.ndarray
    velocity_ratio: np.ndarray
    force_amplification: np.ndarray
    coping_angle: np.ndarray
    mechanical_advantage: np.ndarray


#: Smallest toggle angle the measures take, rad: the crosshead's distance from lock-up,
#: about r alpha^2, is then ~1e-13 m against positions of ~0.1 m (rounding 1e-17 m).
MIN_ANGLE = 1e-6


def angle_grid(alpha_lock: float, alpha_max: float, points: int) -> np.ndarray:
    """Toggle angles (rad) from ``alpha_lock`` (near lock-up, > 0) to ``alpha_max``."""
    if not (0 < alpha_lock < alpha_max < math.pi) or points < 2:
        raise ValueError(
            f"need 0 < alpha_lock < alpha_max < pi rad and >= 2 points, got "
            f"{float(alpha_lock):g}, {float(alpha_max):g} rad and {int(points)} points"
        )
    return np.linspace(alpha_lock, alpha_max, points)


def angle_measures(dims: HalfDims, alphas: Any, *, label: str = "half") -> AngleMeasures:
    """Strokes, stroke/velocity ratios, force amplification (Eq 6), coping angle and the
    frictionless force ratio at ``alphas``.

    Angles must be > 0: at lock-up the ratios are 0/0 and the force
    amplification is infinite.
    """
    alphas = np.asarray(alphas, dtype=float)
    if alphas.size == 0 or not np.all(alphas > 0):
        raise ValueError("toggle angles must be > 0 rad (the measures are singular at lock-up)")
    if np.any(alphas < MIN_ANGLE):
        raise ValueError(
            f"toggle angle {float(alphas.min()):.3g} rad is too close to lock-up: the "
            f"crosshead's distance from it (which grows as the angle squared) is lost in "
            f"rounding below {MIN_ANGLE:g} rad, and the stroke ratio with it")
    x_lock = toggle_position(dims)
    x = crosshead_positions(dims, alphas, x_lock=x_lock, label=label)
    motion = half_motion(x, dims, label=label)
    crosshead = x_lock - x
    platen = float(half_pose(x_lock, dims, label=label).L) - motion.L
    coping = np.mod(-motion.theta3 + math.pi, 2 * math.pi) - math.pi  # 2 pi - theta3, wrapped
    return AngleMeasures(
        alpha=alphas, x=x, crosshead_stroke=crosshead, platen_stroke=platen,
        stroke_ratio=platen / crosshead, velocity_ratio=motion.dL_dx,
        force_amplification=crosshead / platen, coping_angle=coping,
        mechanical_advantage=np.asarray(
            mechanical_advantage(x, dims, _FRICTIONLESS_PINS, 0.0), dtype=float),
    )


@dataclass(frozen=True)
class Criterion:
    """One ranking criterion: a number from the measures; higher is better."""

    key: str
    label: str
    unit: str  # "1" or "rad"
    value: Callable[[AngleMeasures], float]


#: The four criteria of seed 004's comparison (Figures 3-6), each "higher is better".
CRITERIA = (
    Criterion("stroke_ratio", "stroke ratio at the largest angle", "1",
              lambda m: float(m.stroke_ratio[-1])),
    Criterion("velocity_ratio", "peak velocity ratio", "1",
              lambda m: float(np.max(m.velocity_ratio))),
    Criterion("force_amplification", "force amplification (Eq 6) at the smallest angle", "1",
              lambda m: float(m.force_amplification[0])),
    # psi <= 0 over the li_micro range: the minimum is minus the largest inclination
    Criterion("coping_angle_min", "minimum coping angle", "rad",
              lambda m: float(np.min(m.coping_angle))),
)


def criteria(measures: AngleMeasures) -> dict[str, float]:
    """The values of :data:`CRITERIA` for one half's measures."""
    return {c.key: c.value(measures) for c in CRITERIA}


@dataclass(frozen=True)
class GroupResult:
    """Measures of one group, or why it does not assemble over the range."""

    group: str
    dims: HalfDims
    measures: AngleMeasures | None = None
    error: AssemblyError | None = None

    @property
    def valid(self) -> bool:
        return self.error is None

    @property
    def criteria(self) -> dict[str, float]:
        if self.measures is None:
            raise ValueError(f"group {self.group} has no measures: {self.error}")
        return criteria(self.measures)


def study_groups(groups: Mapping[str, HalfDims], alphas: Any) -> list[GroupResult]:
    """Measures of every group; a group that fails to assemble keeps its error."""
    out = []
    for name, dims in groups.items():
        try:
            out.append(GroupResult(name, dims, angle_measures(dims, alphas, label=f"group {name}")))
        except AssemblyError as exc:
            out.append(GroupResult(name, dims, error=exc))
    return out


def preset_halves(preset: str, half: str = "lower") -> tuple[dict[str, HalfDims], str]:
    """One half of every group of a preset family (or of a single preset) and the baseline.

    The baseline is the group ``preset`` names (``li_micro/6``), else the family's default
    group (seed 004: group 1, the actual machine).
    """
    family, group = split_group(preset)
    names = preset_groups(family)
    if not names:
        mech = load_preset(preset)
        return {mech.name: mech.half(half)}, mech.name
    baseline = group if group is not None else load_preset(family).name.rpartition("/")[2]
    if baseline not in names:
        raise ParameterError(f"{family} has no group {baseline!r}; groups: {', '.join(names)}")
    return {g: load_preset(family, group=g).half(half) for g in names}, baseline


def _places(scores: Mapping[str, float]) -> dict[str, int]:
    """Competition ranking ("1224"), highest score first; equal scores share a place."""
    order = sorted(scores, key=lambda g: -scores[g])
    places: dict[str, int] = {}
    for i, g in enumerate(order):
        prev = order[i - 1] if i else None
        tie = prev is not None and math.isclose(scores[g], scores[prev], rel_tol=1e-9)
        places[g] = places[prev] if tie else i + 1
    return places


def rank_groups(results: Sequence[GroupResult], baseline: str | None = None) -> dict[str, Any]:
    """Rank the valid groups on each criterion and overall by the sum of their places.

    Equal values share a place. Also names the criteria on which each group
    beats ``baseline`` (the paper's way of screening) and lists the invalid
    groups with the angle where they stop assembling.
    """
    values = {r.group: r.criteria for r in results if r.valid}
    places = {c.key: _places({g: v[c.key] for g, v in values.items()}) for c in CRITERIA}
    rank_sum = {g: sum(p[g] for p in places.values()) for g in values}
    overall = _places({g: -s for g, s in rank_sum.items()})
    out: dict[str, Any] = {
        "criteria": [{"key": c.key, "label": c.label, "unit": c.unit, "better": "higher"}
                     for c in CRITERIA],
        "order": sorted(values, key=lambda g: overall[g]),
        "place": overall,
        "rank_sum": rank_sum,
        "places": places,
        "values": values,
        "invalid": [
            {"group": r.group, "alpha_limit": getattr(r.error, "alpha_limit", None),
             "error": str(r.error)}
            for r in results if not r.valid
        ],
    }
    if baseline in values:
        base = values[baseline]
        better = {g: [k for k in base if v[k] > base[k] and not math.isclose(v[k], base[k])]
                  for g, v in values.items() if g != baseline}
        out["baseline"] = baseline
        out["better_than_baseline"] = better
        out["dominates_baseline"] = [g for g, ks in better.items() if len(ks) == len(CRITERIA)]
    return out


@dataclass(frozen=True)
class SweepResult:
    """Criteria over a grid of two dimensions; cells that fail are masked, with reasons."""

    names: tuple[str, str]
    values: tuple[np.ndarray, np.ndarray]  # m
    criteria: dict[str, np.ma.MaskedArray]  # shape (len(values[0]), len(values[1]))
    failures: list[tuple[int, int, str]]


def sweep(dims: HalfDims, first: tuple[str, Sequence[float]],
          second: tuple[str, Sequence[float]], alphas: Any) -> SweepResult:
    """The :data:`CRITERIA` of a half with two of its dimensions varied over a grid.

    ``first`` and ``second`` are (field name, values in m). A cell whose
    geometry is invalid or fails to assemble over ``alphas`` is masked and
    listed in ``failures`` with the reason (including the angle reached).
    """
    (n1, v1), (n2, v2) = first, second
    for name in (n1, n2):
        if name not in DIMENSIONS:
            raise ValueError(f"unknown dimension {name!r}; known: {', '.join(DIMENSIONS)}")
    if n1 == n2:
        raise ValueError(f"sweep needs two different dimensions, got {n1!r} twice")
    a1, a2 = np.asarray(v1, dtype=float), np.asarray(v2, dtype=float)
    for name, a in ((n1, a1), (n2, a2)):
        if a.ndim != 1 or a.size < 2 or not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: need at least two finite values, got {a.size} "
                             f"({'not all finite' if a.size else 'none'})")
    data = {c.key: np.zeros((a1.size, a2.size)) for c in CRITERIA}
    mask = np.zeros((a1.size, a2.size), dtype=bool)
    failures = []
    for i, p in enumerate(a1):
        for j, q in enumerate(a2):
            try:
                values = criteria(angle_measures(dims.replace(**{n1: p, n2: q}), alphas,
                                                 label=f"{n1} = {p:.6g} m, {n2} = {q:.6g} m"))
            except (AssemblyError, ParameterError) as exc:
                mask[i, j] = True
                failures.append((i, j, str(exc)))
                continue
            for k, v in values.items():
                data[k][i, j] = v
    return SweepResult((n1, n2), (a1, a2),
                       {k: np.ma.masked_array(v, mask=mask) for k, v in data.items()}, failures)
