"""Mechanical-error (tolerance) analysis of the two halves of the clamp.

Linearised: the output error of a half is the sum of exact AD sensitivities
times the dimensional errors (Chang et al. 2021, Eqs 19-37); worst-case and
RSS deviations (Eqs 38-41) and the asymmetry indices dL_wor and dL_rss
(Eqs 42-43) follow. Exact: the perturbed halves re-solved with the nonlinear
kinematics, deterministically (extreme deviations) and by Monte Carlo.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from toggle import mc_kernel, philox
from toggle.iso286 import it_tolerance
from toggle.kinematics import output_position, sensitivities, toggle_position
from toggle.mc_summary import OUTPUTS, PILOT, QUANTILES, Summary, percentiles
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
    progress: Callable[[int], object] | None = None,
) -> MonteCarloResult:
    """Exact nonlinear Monte Carlo of both halves' outputs at x.

    Every dimension of both halves is drawn independently: normal with sigma =
    tolerance / 3, or uniform over +-tolerance, by the counter-based generator of
    :mod:`toggle.philox` (sample i's draws depend on the seed and i alone: the chunk
    size does not change the result). Draws and kinematics are evaluated in chunks by
    the compiled kernel (:mod:`toggle.mc_kernel`, C generated from the same closed form;
    numpy where no C compiler works, the same draws and results) and summarised as they
    come, no sample kept (:mod:`toggle.mc_summary`); ``progress`` is called with the
    count of each chunk's samples once they are done. A sample that cannot assemble
    raises :class:`~toggle.kinematics.AssemblyError` (the tolerances are too wide).
    """
    if distribution not in ("normal", "uniform"):
        raise ParameterError(f"distribution must be 'normal' or 'uniform', got {distribution!r}")
    if samples < 2:
        raise ParameterError(f"need at least 2 samples, got {samples}")
    if chunk < 1:
        raise ParameterError(f"chunk must be at least 1 sample, got {chunk}")
    x = toggle_position(mech.lower) if x is None else float(x)
    key = philox.key(seed)
    nominal = {h: float(output_position(x, mech.half(h))) for h in HALVES}
    scale = {h: _scale(tolerances[h], distribution) for h in HALVES}
    kernel = mc_kernel.load()
    pilot = min(samples, PILOT)
    buffers = [np.empty(max(pilot, min(chunk, samples))) for _ in HALVES]

    def outputs(start: int, n: int, into: list[np.ndarray] = buffers) -> list[np.ndarray]:
        for stream, h in enumerate(HALVES):
            _outputs(x, mech.half(h), scale[h], key, start, stream, distribution,
                     into[stream][:n], f"{h} half (sampled)")
        return [out[:n] for out in into]

    first = outputs(0, pilot)
    summary = Summary(samples, (nominal["lower"], nominal["upper"]), *first)
    summary.add(0, *first, kernel)
    if progress is not None:
        progress(pilot)
    for start in range(pilot, samples, chunk):
        n = min(chunk, samples - start)
        summary.add(start, *outputs(start, n), kernel)
        if progress is not None:
            progress(n)
    found = summary.statistics()
    if any(pct is None for _, _, pct in found.values()):  # a window missed: all the samples
        whole = [np.empty(samples) for _ in HALVES]
        for start in range(0, samples, chunk):
            outputs(start, min(chunk, samples - start),
                    [out[start:start + chunk] for out in whole])
        values = dict(zip(OUTPUTS, summary.values(*whole)))
        found = {k: (mean, std, percentiles(values[k]) if pct is None else pct)
                 for k, (mean, std, pct) in found.items()}
    stats = {k: Statistics(mean, std, {f"p{q:g}": float(v) for q, v in zip(QUANTILES, pct)})
             for k, (mean, std, pct) in found.items()}
    return MonteCarloResult(x=x, samples=samples, **stats)
