"""Precision synthesis: sensitivities, reliability and tolerance allocation (Dong & Sun 2022).

Generic over a mechanism given as an *error function* (:class:`ErrorModel`):
two chains ("left" and "right") whose outputs s1, s2 depend on their own
error sources. The slider (or platen) position error and tilt are

    dS = (ds1 + ds2) / 2,    dbeta = (ds1 - ds2) / W,

with W the lever arm between the chains' output joints (the paper's
ye1 + ye2, Eq 3). Every source is normal with sigma = band / 6 = t / 3 for a
tolerance +-t (3-sigma convention, Eq 28), independently in each chain.

Reliabilities are computed exactly by nonlinear Monte Carlo and by the
linearised normal approximation the paper uses (P = erf(R / (sqrt 2 sigma))).
The allocation minimises the cost sum K_i x_i^(-a_i) (Eq 21, x_i the
tolerance in ``cost_unit``) under both linearised reliability constraints,
as a smooth NLP solved by IPOPT (CasADi) instead of the paper's genetic
algorithm.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import casadi as ca
import numpy as np
from scipy.special import erf

from toggle.interrupts import signals_survive
from toggle.kinematics import half_pose, sensitivities, toggle_position
from toggle.params import DIMENSIONS, PAPER_NAMES, Mechanism, ParameterError

CHAINS = ("left", "right")


@dataclass(frozen=True)
class SynthesisSettings:
    """Requirements, cost model and bounds of the allocation (SI; defaults from seed 003).

    The cost exponent a_i was lost from the extracted text; a = 1 (the
    reciprocal cost-tolerance model) is assumed. The bounds 0.010-0.125 mm
    are the range of the paper's optimised tolerances (Table 4).
    """

    position_limit: float = 0.05e-3  # R1, m
    position_reliability: float = 0.90  # p1
    tilt_limit: float = 2e-4  # R2, rad
    tilt_reliability: float = 0.95  # p2
    cost_link: float = 8.25  # K_i of link lengths
    cost_position: float = 5.63  # K_i of pivot/hole positions
    cost_exponent: float = 1.0  # a_i (assumption, see above)
    cost_unit: float = 1e-3  # x_i is the tolerance in this unit (mm)
    tolerance_min: float = 0.010e-3  # m
    tolerance_max: float = 0.125e-3  # m
    reference_link: float = 0.02e-3  # the paper's original allocation, +-m
    reference_position: float = 0.1e-3
    samples: int = 1_000_000  # Monte Carlo check
    seed: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value) and value >= 0
            ):
                raise ParameterError(f"synthesis setting {f.name} must be a number >= 0, "
                                     f"got {value!r}")
        for name in ("position_reliability", "tilt_reliability"):
            if not 0 < getattr(self, name) < 1:
                raise ParameterError(f"{name} must be in (0, 1), got {getattr(self, name)}")
        if not 0 < self.tolerance_min < self.tolerance_max:
            raise ParameterError("need 0 < tolerance_min < tolerance_max")


def settings_from_table(table: Any, origin: str) -> SynthesisSettings:
    """[synthesis] table of a preset (SI); missing keys keep the seed-003 defaults."""
    if not isinstance(table, dict):
        raise ParameterError(f"{origin}: [synthesis] must be a table")
    unknown = set(table) - {f.name for f in fields(SynthesisSettings)}
    if unknown:
        raise ParameterError(f"{origin}: [synthesis]: unknown {sorted(unknown)}")
    return SynthesisSettings(**table)


@dataclass(frozen=True)
class ErrorModel:
    """A two-chain mechanism as an error function of its error sources.

    output(chain, params) evaluates the exact output of one chain for
    parameter columns params (n_sources x N, m), vectorised; gradient is its
    exact derivative at the nominal parameters; spacing(left, right) is the
    tilt lever arm W for parameter columns of both chains.
    """

    name: str
    sources: tuple[str, ...]
    kinds: tuple[str, ...]  # "link" or "position": cost class of each source
    nominal: Mapping[str, np.ndarray]
    gradient: Mapping[str, np.ndarray]
    output: Callable[[str, np.ndarray], np.ndarray]
    spacing: Callable[[np.ndarray, np.ndarray], Any]
    reference_output: float  # nominal output (the press's BDC, the clamp's toggle output), m
    output_label: str
    settings: SynthesisSettings

    @property
    def nominal_spacing(self) -> float:
        return float(self.spacing(self.nominal["left"], self.nominal["right"]))


def refine_extremum(f: Callable[[np.ndarray], np.ndarray], q0: np.ndarray, step: float,
                    iterations: int = 2) -> np.ndarray:
    """Value of f at the stationary point nearest q0, vectorised over the columns.

    Newton steps on f'(q) = 0 with central differences of spacing ``step``:
    starting from the nominal extremum, the shift is tiny and two steps reach
    machine precision. Used for the Monte Carlo of dead centres and toggles.
    """
    q = np.asarray(q0, dtype=float)
    for _ in range(iterations):
        fm, f0, fp = f(q - step), f(q), f(q + step)
        curvature = fp - 2 * f0 + fm
        if np.any(curvature == 0):
            raise ValueError("flat output: no isolated extremum to refine")
        q = q - 0.5 * step * (fp - fm) / curvature
    return np.asarray(f(q), dtype=float)


# --- the clamp (seed 000) as an error model -------------------------------------------------

#: Cost class of the clamp's dimensions: link lengths, or pivot/joint offsets.
CLAMP_KINDS = tuple("position" if d in ("r1", "r2", "e") else "link" for d in DIMENSIONS)


def clamp_error_model(mech: Mechanism, settings: SynthesisSettings | None = None) -> ErrorModel:
    """The clamp through the core kinematics: upper half = "left", lower half = "right".

    Output of a half: its platen-joint position at its toggle (the maximum of
    L(x), the clamp's analogue of the press's BDC). Tilt of the moving platen:
    (L_upper - L_lower) / W, with W = (r1 - e)_upper + (r1 - e)_lower the
    spacing of the two platen joints (e is measured towards the clamp axis,
    like d = r1 - r2).
    """
    halves = {"left": mech.upper, "right": mech.lower}
    x_tp = {c: toggle_position(d) for c, d in halves.items()}

    def output(chain: str, params: np.ndarray) -> np.ndarray:
        rows = [params[i] for i in range(len(DIMENSIONS))]
        return refine_extremum(lambda x: half_pose(x, rows, label=f"{chain} chain").L,
                               np.full(params.shape[1], x_tp[chain]), 1e-5)

    def spacing(left: np.ndarray, right: np.ndarray) -> Any:
        r1, e = DIMENSIONS.index("r1"), DIMENSIONS.index("e")
        return (left[r1] - left[e]) + (right[r1] - right[e])

    grads = {c: np.array([float(v) for v in sensitivities(x_tp[c], d).values()])
             for c, d in halves.items()}
    return ErrorModel(
        name=mech.name,
        sources=tuple(f"{PAPER_NAMES['lower'][d]}/{PAPER_NAMES['upper'][d]}" for d in DIMENSIONS),
        kinds=CLAMP_KINDS,
        nominal={c: np.array(d.as_tuple()) for c, d in halves.items()},
        gradient=grads,
        output=output,
        spacing=spacing,
        reference_output=float(half_pose(x_tp["right"], mech.lower).L),
        output_label="platen-joint position at the toggle",
        settings=settings or SynthesisSettings(),
    )


# --- sensitivity and significance -----------------------------------------------------------


@dataclass(frozen=True)
class SourceSensitivity:
    """Sensitivity (d output / d source, per chain) and significance of one error source.

    Significance of the position (Eq 19) normalises |sensitivity| over all sources of
    both chains (Figure 6: l1 and Cx 51 %). To first order the tilt is (ds1 - ds2) / W,
    whose |sensitivity| shares are the position's again (a chart of them drew the same bars
    twice); the tilt's significance is its share of the tilt's variance, sensitivity^2 over
    the sum of them, which is what Figure 7 shows (l1, Cx and l5 85 %). The lever-arm
    sources enter at second order only and have none.
    """

    source: str
    left: float
    right: float
    significance_position: float
    significance_tilt: float


def sensitivity_table(model: ErrorModel) -> list[SourceSensitivity]:
    g_left, g_right = model.gradient["left"], model.gradient["right"]
    pos = 0.5 * (np.abs(g_left) + np.abs(g_right))  # |d dS / d source|, both chains
    tilt = (g_left**2 + g_right**2) / model.nominal_spacing**2  # variance per source
    return [SourceSensitivity(s, float(g_left[i]), float(g_right[i]), float(pos[i] / pos.sum()),
                              float(tilt[i] / tilt.sum()))
            for i, s in enumerate(model.sources)]


# --- cost and reliability -------------------------------------------------------------------


def _vector(model: ErrorModel, tolerances: Mapping[str, float]) -> np.ndarray:
    missing = set(model.sources) - set(tolerances)
    if missing:
        raise ParameterError(f"no tolerance for error sources {sorted(missing)}")
    t = np.array([float(tolerances[s]) for s in model.sources])
    if not np.all(np.isfinite(t) & (t >= 0)):
        raise ParameterError(f"tolerances must be finite and >= 0, got {dict(tolerances)}")
    return t


def cost(model: ErrorModel, tolerances: Mapping[str, float]) -> float:
    """Relative manufacturing cost sum K_i x_i^(-a) of an allocation (Eq 22)."""
    st = model.settings
    t = _vector(model, tolerances)
    if np.any(t <= 0):
        raise ParameterError("a zero tolerance has infinite cost")
    k = np.array([st.cost_link if kind == "link" else st.cost_position for kind in model.kinds])
    return float(np.sum(k * (t / st.cost_unit) ** (-st.cost_exponent)))


def reference_tolerances(model: ErrorModel) -> dict[str, float]:
    """The paper's original uniform allocation: +-0.02 mm links, +-0.1 mm positions."""
    st = model.settings
    return {s: st.reference_link if kind == "link" else st.reference_position
            for s, kind in zip(model.sources, model.kinds)}


@dataclass(frozen=True)
class Reliability:
    """P(|dS| <= R1) and P(|dbeta| <= R2), with the sample statistics of a Monte Carlo run."""

    position: float
    tilt: float
    position_sigma: float  # m
    tilt_sigma: float  # rad
    position_mean: float = 0.0
    tilt_mean: float = 0.0
    samples: int = 0  # 0: linearised normal approximation


def _linear_sigmas(model: ErrorModel, t: Any) -> tuple[Any, Any]:
    """Linearised sigma of dS and dbeta for tolerances t (numbers or CasADi symbols)."""
    var = 0
    for chain in CHAINS:
        g = model.gradient[chain]
        var = var + sum((g[i] * t[i] / 3) ** 2 for i in range(len(model.sources)))
    return np.sqrt(var) / 2, np.sqrt(var) / model.nominal_spacing


def linear_reliability(model: ErrorModel, tolerances: Mapping[str, float]) -> Reliability:
    """Reliabilities of the linearised model: dS and dbeta normal with zero mean."""
    st = model.settings
    s_pos, s_tilt = _linear_sigmas(model, _vector(model, tolerances))
    with np.errstate(divide="ignore"):
        p_pos = float(erf(st.position_limit / (math.sqrt(2) * s_pos))) if s_pos > 0 else 1.0
        p_tilt = float(erf(st.tilt_limit / (math.sqrt(2) * s_tilt))) if s_tilt > 0 else 1.0
    return Reliability(p_pos, p_tilt, float(s_pos), float(s_tilt))


def monte_carlo_reliability(model: ErrorModel, tolerances: Mapping[str, float], *,
                            samples: int | None = None, seed: int | None = None,
                            chunk: int = 200_000) -> Reliability:
    """Reliabilities by exact nonlinear Monte Carlo (both chains re-solved per sample)."""
    st = model.settings
    samples = st.samples if samples is None else int(samples)
    if samples < 2:
        raise ParameterError(f"need at least 2 Monte Carlo samples, got {samples}")
    sigma = _vector(model, tolerances)[:, None] / 3
    rng = np.random.default_rng(st.seed if seed is None else seed)
    base = {c: float(model.output(c, model.nominal[c][:, None])[0]) for c in CHAINS}
    d_pos, d_tilt = np.empty(samples), np.empty(samples)
    for start in range(0, samples, chunk):
        n = min(chunk, samples - start)
        params = {c: model.nominal[c][:, None] + sigma * rng.standard_normal((sigma.size, n))
                  for c in CHAINS}
        ds = {c: model.output(c, params[c]) - base[c] for c in CHAINS}
        d_pos[start:start + n] = 0.5 * (ds["left"] + ds["right"])
        d_tilt[start:start + n] = (ds["left"] - ds["right"]) / model.spacing(params["left"],
                                                                             params["right"])
    return Reliability(
        position=float(np.mean(np.abs(d_pos) <= st.position_limit)),
        tilt=float(np.mean(np.abs(d_tilt) <= st.tilt_limit)),
        position_sigma=float(d_pos.std(ddof=1)),
        tilt_sigma=float(d_tilt.std(ddof=1)),
        position_mean=float(d_pos.mean()),
        tilt_mean=float(d_tilt.mean()),
        samples=samples,
    )


# --- allocation -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Allocation:
    tolerances: dict[str, float]  # +-t per source, m (the same in both chains)
    cost: float
    linear: Reliability


#: Design margin, in standard errors of the Monte Carlo check, added to each required reliability.
MC_MARGIN_SIGMAS = 3.0


def design_targets(settings: SynthesisSettings, samples: int) -> tuple[float, float]:
    """Required reliabilities raised by 3 standard errors of a ``samples``-sample Monte Carlo.

    The linearised optimum sits exactly on a constraint, where a Monte Carlo
    check would fail half of the time; the margin makes it pass.
    """
    def raised(p: float) -> float:
        return min(p + MC_MARGIN_SIGMAS * math.sqrt(p * (1 - p) / samples), 1 - 1e-9)
    return raised(settings.position_reliability), raised(settings.tilt_reliability)


def allocate(model: ErrorModel, *, samples: int | None = None) -> Allocation:
    """Cheapest tolerances meeting both reliability requirements, by IPOPT.

    Variables are the tolerances in ``cost_unit`` within the bounds; the
    linearised constraints erf(R / (sqrt 2 sigma)) >= p are smooth in them.
    The targets p carry the margin of :func:`design_targets` for a Monte
    Carlo check with ``samples`` samples (default: the settings').
    """
    st = model.settings
    p_pos, p_tilt = design_targets(st, st.samples if samples is None else samples)
    n, unit = len(model.sources), st.cost_unit
    lo, hi = st.tolerance_min / unit, st.tolerance_max / unit
    tightest = linear_reliability(model, dict.fromkeys(model.sources, st.tolerance_min))
    if tightest.position < p_pos or tightest.tilt < p_tilt:
        raise ValueError(
            f"no allocation within {st.tolerance_min * 1e3:g}-{st.tolerance_max * 1e3:g} mm meets "
            f"the requirements: even the tightest gives P(position) = {tightest.position:.4f}, "
            f"P(tilt) = {tightest.tilt:.4f}"
        )
    u = ca.SX.sym("u", n)
    k = [st.cost_link if kind == "link" else st.cost_position for kind in model.kinds]
    objective = sum(k[i] * u[i] ** (-st.cost_exponent) for i in range(n))
    s_pos, s_tilt = _linear_sigmas(model, [u[i] * unit for i in range(n)])
    g = ca.vertcat(ca.erf(st.position_limit / (math.sqrt(2) * s_pos)),
                   ca.erf(st.tilt_limit / (math.sqrt(2) * s_tilt)))
    solver = ca.nlpsol("allocation", "ipopt", {"x": u, "f": objective, "g": g},
                       {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes",
                        "ipopt.tol": 1e-10})
    with signals_survive():  # IPOPT would turn a Ctrl-C into a failed allocation
        sol = solver(x0=np.full(n, math.sqrt(lo * hi)), lbx=lo, ubx=hi,
                     lbg=[p_pos, p_tilt], ubg=[1.0, 1.0])
    if not solver.stats()["success"]:
        raise ValueError(f"tolerance allocation failed: {solver.stats()['return_status']}")
    t = np.clip(np.asarray(sol["x"]).ravel(), lo, hi) * unit
    tol = dict(zip(model.sources, (float(v) for v in t)))
    return Allocation(tol, cost(model, tol), linear_reliability(model, tol))


def with_settings(model: ErrorModel, **changes: Any) -> ErrorModel:
    """The same error model with some synthesis settings changed."""
    return replace(model, settings=replace(model.settings, **changes))
