"""Mechanical-error (tolerance) analysis of the two halves of the clamp.

Linearised: the output error of a half is the sum of exact AD sensitivities
times the dimensional errors (Chang et al. 2021, Eqs 19-37); worst-case and
RSS deviations (Eqs 38-41) and the asymmetry indices dL_wor and dL_rss
(Eqs 42-43) follow. Exact: the perturbed halves re-solved with the nonlinear
kinematics, deterministically (extreme deviations) and by Monte Carlo.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from toggle import mc_kernel, philox
from toggle.iso286 import it_tolerance
from toggle.kinematics import output_position, sensitivities, toggle_position
from toggle.params import DIMENSIONS, HALVES, HalfDims, Mechanism, ParameterError

#: Per half, per dimension: a tolerance band half-width or an error, metres.
Tolerances = Mapping[str, Mapping[str, float]]


def it_tolerances(mech: Mechanism, grade: int) -> dict[str, dict[str, float]]:
    """The full IT value of every dimension of both halves (seed 000, Table 2)."""
    return {
        half: {dim: it_tolerance(getattr(mech.half(half), dim), grade) for dim in DIMENSIONS}
        for half in HALVES
    }


@dataclass(frozen=True)
class HalfBudget:
    """Linearised output deviations of one half at an input position."""

    sensitivities: dict[str, float]  # dL/dp, dimensionless
    contributions: dict[str, float]  # dL/dp * error, m
    worst: float  # Eq 38 / 40, m
    rss: float  # Eq 39 / 41, m


def half_budget(x: float, dims: HalfDims, errors: Mapping[str, float]) -> HalfBudget:
    """Worst-case and RSS output deviation of one half for given errors (m)."""
    sens = {k: float(v) for k, v in sensitivities(x, dims).items()}
    contrib = {k: sens[k] * errors.get(k, 0.0) for k in DIMENSIONS}
    return HalfBudget(
        sensitivities=sens,
        contributions=contrib,
        worst=sum(abs(c) for c in contrib.values()),
        rss=math.sqrt(sum(c * c for c in contrib.values())),
    )


@dataclass(frozen=True)
class AsymmetryReport:
    """Asymmetry of the halves at x when the lower half sits at its lower deviations
    and the upper half at its upper deviations (seed 000, section 3.3)."""

    x: float
    lower: HalfBudget
    upper: HalfBudget
    dL_wor: float  # Eq 42, m
    dL_rss: float  # Eq 43, m
    dL_exact: float  # re-solved nonlinear mechanism, worst sign per dimension, m


def asymmetry(mech: Mechanism, tolerances: Tolerances, x: float | None = None) -> AsymmetryReport:
    """Asymmetry indices (Eqs 42-43) and the exact nonlinear asymmetry at x.

    ``x`` defaults to the toggle position of the lower half. The exact value
    re-solves both halves with every dimension moved by its full tolerance in
    the direction that increases the upper output (upper half) or decreases
    the lower output (lower half): the extreme the worst-case index linearises.
    """
    x = toggle_position(mech.lower) if x is None else float(x)
    lower = half_budget(x, mech.lower, {k: -t for k, t in tolerances["lower"].items()})
    upper = half_budget(x, mech.upper, tolerances["upper"])

    def pushed(dims: HalfDims, budget: HalfBudget, sign: float, tol: Mapping[str, float]) -> float:
        moved = {
            k: getattr(dims, k) + sign * math.copysign(tol.get(k, 0.0), budget.sensitivities[k])
            for k in DIMENSIONS
        }
        return float(output_position(x, dims.replace(**moved), label=f"perturbed half at x={x}"))

    exact = pushed(mech.upper, upper, 1.0, tolerances["upper"]) - pushed(
        mech.lower, lower, -1.0, tolerances["lower"]
    )
    return AsymmetryReport(x, lower, upper, upper.worst + lower.worst, upper.rss + lower.rss, exact)


#: The percentiles a Monte Carlo reports: +-3 sigma, +-1.96 sigma of a normal, the median.
QUANTILES = (0.135, 2.5, 50.0, 97.5, 99.865)


def _order_statistics(values: np.ndarray, ranks: list[int], found: dict[int, float],
                      offset: int = 0) -> None:
    """The values of the given ranks (and each rank + 1) of ``values`` into ``found``,
    partitioning in place around the middle rank and recursing on each side: about 2.5
    passes for the five quantiles, where one np.partition with all ten ranks makes seven
    (it selects each rank afresh over what lies to its right)."""
    if not ranks:
        return
    mid = ranks[len(ranks) // 2]
    values.partition(mid)
    found[offset + mid] = float(values[mid])
    if mid + 1 < values.size:
        found[offset + mid + 1] = float(values[mid + 1:].min())
    _order_statistics(values[:mid], [r for r in ranks if r < mid], found, offset)
    _order_statistics(values[mid + 1:], [r - mid - 1 for r in ranks if r > mid], found,
                      offset + mid + 1)


def percentiles(values: np.ndarray, qs: tuple[float, ...] = QUANTILES) -> np.ndarray:
    """``np.percentile(values, qs)`` (its default linear method, the same bits) for finite
    values, which are reordered in place: a Monte Carlo's ten million outputs in a third of
    its time."""
    n = values.size
    virtual = (n - 1) * np.true_divide(qs, 100)
    below = np.floor(virtual).astype(np.intp)
    above = np.minimum(below + 1, n - 1)
    found: dict[int, float] = {}
    _order_statistics(values, sorted(set(below.tolist())), found)
    a, b = np.array([found[i] for i in below]), np.array([found[i] for i in above])
    t = virtual - below
    diff = b - a  # numpy's lerp: from the nearer end
    return np.where(t >= 0.5, b - diff * (1 - t), a + diff * t)


@dataclass(frozen=True)
class Statistics:
    """Summary of a Monte Carlo sample, metres."""

    mean: float
    std: float
    percentiles: dict[str, float]

    @classmethod
    def of(cls, values: np.ndarray) -> Statistics:
        """The summary of ``values``, which are reordered in place (:func:`percentiles`)."""
        mean, std = float(values.mean()), float(values.std(ddof=1))
        return cls(mean, std, {f"p{q:g}": float(v)
                               for q, v in zip(QUANTILES, percentiles(values))})


@dataclass(frozen=True)
class MonteCarloResult:
    x: float
    samples: int
    lower: Statistics  # output error L - L_nominal of the lower half
    upper: Statistics
    asymmetry: Statistics  # L_upper - L_lower


def _scale(tol: Mapping[str, float], distribution: str) -> np.ndarray:
    """Scale of every dimension: a sampled dimension is nominal + scale * draw (sigma =
    band / 3 of a normal draw, the band itself of a uniform draw on [-1, 1))."""
    band = np.array([tol.get(k, 0.0) for k in DIMENSIONS])
    return band / 3.0 if distribution == "normal" else band


def _outputs(x: float, dims: HalfDims, scale: np.ndarray, key: philox.Key, start: int,
             stream: int, distribution: str, out: np.ndarray, label: str) -> None:
    """Output positions of samples ``start ..`` of a half (``stream``) into ``out``: by the
    compiled kernel, drawing in C, or by numpy (the same draws) where no C compiler works
    or where a sample's output is not finite (numpy then raises the
    :class:`~toggle.kinematics.AssemblyError` naming it, or clips a rounding-level
    excursion past an acos/asin limit, as it always has)."""
    nominal = np.array(dims.as_tuple())
    kernel = mc_kernel.load()
    if kernel is not None and not kernel.sampled(x, nominal, scale, key, start, stream,
                                                 distribution, out):
        return
    draws = philox.draws(key, start, out.size, stream, distribution)
    out[:] = output_position(x, list(nominal[:, None] + scale[:, None] * draws), label=label)


def monte_carlo(
    mech: Mechanism,
    tolerances: Tolerances,
    *,
    x: float | None = None,
    samples: int = 100_000,
    distribution: str = "normal",
    seed: int | None = 0,
    chunk: int = 65_536,
    progress: bool = False,
) -> MonteCarloResult:
    """Exact nonlinear Monte Carlo of both halves' outputs at x.

    Every dimension of both halves is drawn independently: normal with sigma =
    tolerance / 3, or uniform over +-tolerance, by the counter-based generator of
    :mod:`toggle.philox` (sample i's draws depend on the seed and i alone: the chunk
    size does not change the result). Draws and kinematics are evaluated in chunks by
    the compiled kernel (:mod:`toggle.mc_kernel`, C generated from the same closed form;
    numpy where no C compiler works, the same draws and results); a sample that cannot
    assemble raises :class:`~toggle.kinematics.AssemblyError` (the tolerances are too
    wide).
    """
    if distribution not in ("normal", "uniform"):
        raise ParameterError(f"distribution must be 'normal' or 'uniform', got {distribution!r}")
    if samples < 2:
        raise ParameterError(f"need at least 2 samples, got {samples}")
    x = toggle_position(mech.lower) if x is None else float(x)
    key = philox.key(seed)
    nominal = {h: float(output_position(x, mech.half(h))) for h in HALVES}
    scale = {h: _scale(tolerances[h], distribution) for h in HALVES}
    out = {h: np.empty(samples) for h in HALVES}
    starts = range(0, samples, chunk)
    for start in tqdm(starts, desc="Monte Carlo", unit="chunk", disable=not progress):
        for stream, h in enumerate(HALVES):
            _outputs(x, mech.half(h), scale[h], key, start, stream, distribution,
                     out[h][start:start + chunk], f"{h} half (sampled)")
    asym = out["upper"] - out["lower"]
    for h in HALVES:
        out[h] -= nominal[h]  # the output errors, in place (the arrays are 80 MB at 1e7)
    return MonteCarloResult(x=x, samples=samples, lower=Statistics.of(out["lower"]),
                            upper=Statistics.of(out["upper"]), asymmetry=Statistics.of(asym))
