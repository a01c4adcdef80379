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

from toggle import mc_kernel
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


@dataclass(frozen=True)
class Statistics:
    """Summary of a Monte Carlo sample, metres."""

    mean: float
    std: float
    percentiles: dict[str, float]

    @classmethod
    def of(cls, values: np.ndarray) -> Statistics:
        qs = (0.135, 2.5, 50.0, 97.5, 99.865)
        pct = np.percentile(values, qs)
        return cls(float(values.mean()), float(values.std(ddof=1)),
                   {f"p{q:g}": float(v) for q, v in zip(qs, pct)})


@dataclass(frozen=True)
class MonteCarloResult:
    x: float
    samples: int
    lower: Statistics  # output error L - L_nominal of the lower half
    upper: Statistics
    asymmetry: Statistics  # L_upper - L_lower


def _draw(rng: np.random.Generator, tol: Mapping[str, float], n: int, distribution: str
          ) -> tuple[np.ndarray, np.ndarray]:
    """Scale of every dimension and the standard draws (dimensions x n): a sampled
    dimension is nominal + scale * draw."""
    band = np.array([tol.get(k, 0.0) for k in DIMENSIONS])
    if distribution == "normal":
        return band / 3.0, rng.standard_normal((len(DIMENSIONS), n))
    return band, rng.uniform(-1.0, 1.0, (len(DIMENSIONS), n))


def _outputs(x: float, dims: HalfDims, scale: np.ndarray, draws: np.ndarray, label: str
             ) -> np.ndarray:
    """Output positions of the sampled halves: by the compiled kernel, or by numpy where no
    C compiler works or where a sample's output is not finite (numpy then raises the
    :class:`~toggle.kinematics.AssemblyError` naming it, or clips a rounding-level
    excursion past an acos/asin limit, as it always has)."""
    nominal = np.array(dims.as_tuple())
    kernel = mc_kernel.load()
    if kernel is not None:
        out, bad = kernel.outputs(x, nominal, scale, draws)
        if not bad:
            return out
    return output_position(x, list(nominal[:, None] + scale[:, None] * draws), label=label)


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

    Every dimension of both halves is drawn independently (numpy): normal with
    sigma = tolerance / 3, or uniform over +-tolerance. The kinematics are
    evaluated in chunks by the compiled kernel (:mod:`toggle.mc_kernel`, C
    generated from the same closed form; numpy where no C compiler works, same
    results); a sample that cannot assemble raises
    :class:`~toggle.kinematics.AssemblyError` (the tolerances are too wide).
    """
    if distribution not in ("normal", "uniform"):
        raise ParameterError(f"distribution must be 'normal' or 'uniform', got {distribution!r}")
    if samples < 2:
        raise ParameterError(f"need at least 2 samples, got {samples}")
    x = toggle_position(mech.lower) if x is None else float(x)
    rng = np.random.default_rng(seed)
    nominal = {h: float(output_position(x, mech.half(h))) for h in HALVES}
    out = {h: np.empty(samples) for h in HALVES}
    starts = range(0, samples, chunk)
    for start in tqdm(starts, desc="Monte Carlo", unit="chunk", disable=not progress):
        n = min(chunk, samples - start)
        for h in HALVES:
            scale, draws = _draw(rng, tolerances[h], n, distribution)
            out[h][start:start + n] = _outputs(x, mech.half(h), scale, draws,
                                               f"{h} half (sampled)")
    return MonteCarloResult(
        x=x,
        samples=samples,
        lower=Statistics.of(out["lower"] - nominal["lower"]),
        upper=Statistics.of(out["upper"] - nominal["upper"]),
        asymmetry=Statistics.of(out["upper"] - out["lower"]),
    )
