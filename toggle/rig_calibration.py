"""Fit the rig model to any chosen statistics and speeds of seed 000's Tables 3-8.

The force statistics (Tables 6-8) are fitted with a handful of plant parameters and
as-built errors of the rig (:data:`FORCE_FITTABLE`) by weighted least squares in
transformed coordinates (log for positive values, logit for the returned take-up share,
linear for the signed errors and the latency), from one or several starts (the lowest
cost is kept); the stroke (Tables 3-5) with the three parameters of the encoder reading
(:class:`toggle.rig_tables.RigReading`), which no force statistic depends on, by linear
least squares. Each residual is measured in units of the printed 3 sigma; the
parameter uncertainty is the Gauss-Newton covariance (J^T J)^-1 scaled by the residual
variance (the model's misfit, not the scatter of the data, dominates); a parameter that
ends where the model refuses to go further (the friction at rest, a range, an assembly) is
reported as held at that limit, without one, the others' conditional on it. Rows are
reported with their residual in units of the printed 3 sigma.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from toggle.asymmetry import AsymmetryError, AsymmetryParams
from toggle.calibration import PAPER_TABLES
from toggle.kinematics import AssemblyError
from toggle.params import PAPER_NAMES, Mechanism, PinRadii, tomllib
from toggle.rig_tables import (
    CHANG2021_AS_BUILT,
    CHANG2021_DYNAMICS,
    CHANG2021_READING,
    FORCE_STATISTICS,
    RigReading,
    RigStatistics,
    rig_config,
    rig_statistics,
)

#: Frictions of the dynamics a fit may choose: the crosshead guide's (at the input, N), the
#: platen's on its tie-bars (at the platen, referred by dL/dx, N) and its rate strengthening.
DYNAMICS_FITTABLE = ("guide_friction", "platen_friction", "platen_rate")
#: Prefix of a fittable as-built error of the rig: ``as_built_r6`` is the prototype's own
#: error of link 6 (the upper half's r3, seed 000's names), m.
AS_BUILT = "as_built_"
#: Plant parameters a force fit may choose (AsymmetryParams fields, the pins' radius,
#: the guides' Coulomb friction, the reading's latency, the rig's as-built errors) and
#: their transform.
FORCE_FITTABLE = {
    "free_play": "log", "contact_stiffness": "log", "series_stiffness": "log",
    "drive_stiffness": "log", "mu": "log", "rate_strengthening": "log",
    "hersey_transition": "log", "slip_distance": "log", "pin_radius": "log",
    **dict.fromkeys(DYNAMICS_FITTABLE, "log"), "takeup_return": "logit",
    "toggle_latency": "time",
    **{f"{AS_BUILT}{n}": "length" for names in PAPER_NAMES.values() for n in names.values()},
}
MAX_FORCE_FITTED = 6
#: Where a fit starts a parameter whose model value is an end of its transform (a
#: log-scaled 0 or inf, a share of 0 or 1), SI: the defaults of the film law (h_s = inf),
#: the frictions the chang2021 preset does not have (0), no free play or rate law (0).
FIT_STARTS = {"free_play": 1e-5, "rate_strengthening": 0.01, "hersey_transition": 1e-5,
              "mu": 0.1, "guide_friction": 1.0, "platen_friction": 1.0, "platen_rate": 0.1,
              "takeup_return": 0.5}
STATISTICS = (*FORCE_STATISTICS, "stroke")
#: The paper's symbols of the statistics, for tables and figures.
STAT_LABELS = {"force_forward_max": "F_F(max)", "force_forward_rms": "F_F(rms)",
               "force_backward_min": "F_B(min)", "force_backward_rms": "F_B(rms)",
               "force_toggle": "F_TP", "stroke": "stroke S"}
#: Speeds (m/s) of the rows the shipped defaults were fitted on (Tables 3-4, 6-7).
SHIPPED_FIT_SPEEDS = (5e-3, 15e-3)
#: Relative acceptance of a prediction (issue 18); the weight scale of the fit.
RELATIVE = 0.25


class RigCalibrationError(ValueError):
    """A calibration request that cannot be met (unknown parameter, no data, ...)."""


@dataclass(frozen=True)
class PaperTables:
    """Seed 000's Tables 3-8 in SI: ``mean[stat]`` and ``three_sigma[stat]``, speed x error."""

    speeds: np.ndarray  # m/s
    errors: np.ndarray  # delta_r8, m
    mean: dict[str, np.ndarray]
    three_sigma: dict[str, np.ndarray]
    mechanism: str = "chang2021"  # the preset of the rig they were measured on

    def cell(self, preset: str, speed: float, delta_r8: float) -> tuple[int, int] | None:
        """(speed index, error index) of the condition a run of ``preset`` at ``speed``
        (m/s) with link 8 off by ``delta_r8`` (m) repeats, or None."""
        i = np.flatnonzero(np.isclose(self.speeds, speed, rtol=1e-6, atol=0))
        j = np.flatnonzero(np.isclose(self.errors, delta_r8, rtol=0, atol=1e-9))
        if preset != self.mechanism or not (len(i) and len(j)):
            return None
        return int(i[0]), int(j[0])

    def speed_index(self, speed: float) -> int:
        hits = np.flatnonzero(np.isclose(self.speeds, speed, rtol=1e-6))
        if not len(hits):
            raise RigCalibrationError(
                f"no table at {speed!r} m/s; speeds: {self.speeds.tolist()}")
        return int(hits[0])


def load_paper_tables(path: str | Path = PAPER_TABLES) -> PaperTables:
    """Tables 3-8 (printed in mm/s, mm, N) in SI."""
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        tables = data["tables"]
        scale = {k: (1e-3 if k == "stroke" else 1.0) for k in STATISTICS}
        return PaperTables(
            np.asarray(data["speed"], float) * 1e-3, np.asarray(data["delta_r8"], float) * 1e-3,
            {k: np.asarray(tables[k]["mean"], float) * scale[k] for k in STATISTICS},
            {k: np.asarray(tables[k]["three_sigma"], float) * scale[k] for k in STATISTICS},
            str(data["mechanism"]))
    except (OSError, KeyError, tomllib.TOMLDecodeError) as exc:
        raise RigCalibrationError(f"cannot read the paper's tables from {path}: {exc}") from exc


@dataclass(frozen=True)
class RigModel:
    """Everything the simulated rig's statistics depend on beyond the mechanism."""

    params: AsymmetryParams = AsymmetryParams()
    #: the rig's [dynamics] fields beyond its preset's (:func:`toggle.rig_tables.rig_dynamics`)
    dynamics: dict[str, float] = field(default_factory=lambda: dict(CHANG2021_DYNAMICS))
    reading: RigReading = CHANG2021_READING
    #: the rig's own dimensional errors besides the set link-8 error (seed 000's names, m)
    as_built: dict[str, float] = field(default_factory=lambda: dict(CHANG2021_AS_BUILT))

    def value(self, name: str) -> float:
        if name.startswith(AS_BUILT):
            return self.as_built.get(name.removeprefix(AS_BUILT), 0.0)
        if name == "toggle_latency":
            return self.reading.toggle_latency
        if name == "pin_radius":
            return self.params.pins.C
        if name in DYNAMICS_FITTABLE:
            return self.dynamics.get(name, 0.0)
        return getattr(self.params, name)

    def with_values(self, values: dict[str, float]) -> RigModel:
        changes = dict(values)
        as_built = {**self.as_built, **{n.removeprefix(AS_BUILT): changes.pop(n)
                                        for n in values if n.startswith(AS_BUILT)}}
        dynamics = {**self.dynamics, **{n: changes.pop(n) for n in values
                                        if n in DYNAMICS_FITTABLE}}
        reading = replace(self.reading, toggle_latency=changes.pop(
            "toggle_latency", self.reading.toggle_latency))
        if "pin_radius" in changes:
            r = changes.pop("pin_radius")
            changes["pins"] = PinRadii(B=r, C=r, D=r)
        return replace(self, params=self.params.replace(**changes), dynamics=dynamics,
                       reading=reading, as_built=as_built)

    def statistics(self, nominal: Mechanism, speed: float, delta_r8: float) -> RigStatistics:
        cfg = rig_config(nominal, delta_r8, self.params, self.dynamics, self.as_built)
        return rig_statistics(cfg, speed, self.reading)


def simulate_tables(tables: PaperTables, nominal: Mechanism, model: RigModel
                    ) -> dict[str, np.ndarray]:
    """Simulated statistics (SI) at every (speed, delta_r8) of the tables."""
    rows = [[model.statistics(nominal, v, d) for d in tables.errors] for v in tables.speeds]
    return {k: np.array([[getattr(s, k) for s in row] for row in rows]) for k in STATISTICS}


class Fit(NamedTuple):
    model: RigModel
    fitted: tuple[str, ...]
    values: dict[str, float]
    std_error: dict[str, float]  # one standard error, in the parameter's unit
    stroke_std_error: dict[str, float]
    speeds: tuple[float, ...]  # m/s of the rows fitted
    statistics: tuple[str, ...]
    cost: float  # mean squared residual (units of the printed 3 sigma)
    #: fitted parameters that ended where the model refuses to go further (a range, the
    #: friction at rest, an assembly): held there, their standard error is NaN and the
    #: others' is conditional on them
    at_limit: tuple[str, ...] = ()


#: The residual of every row where the model refuses the parameters (a large misfit the
#: least-squares steps turn back from).
REFUSED = 1e3
#: Step, in transformed coordinates, of the probe for a parameter at a limit.
_LIMIT_PROBE = 1e-3


#: Scales of the linear coordinates: a signed length (m), a time that may be 0 (s).
_LINEAR = {"length": 1e-4, "time": 0.1}


def _forward(kind: str, value: float) -> float:
    if kind in _LINEAR:
        return value / _LINEAR[kind]
    return math.log(value) if kind == "log" else math.log(value / (1 - value))


def _start(name: str, kind: str, value: float) -> float:
    """A fit's start in transformed coordinates: the model's value, or :data:`FIT_STARTS`
    where the transform cannot take it."""
    at_end = (kind == "log" and not 0 < value < math.inf) or (
        kind == "logit" and not 0 < value < 1)
    if at_end:
        if name not in FIT_STARTS:
            raise RigCalibrationError(f"cannot start a fit of {name} at {value!r}")
        value = FIT_STARTS[name]
    return _forward(kind, value)


def _inverse(kind: str, z: float) -> float:
    if kind in _LINEAR:
        return z * _LINEAR[kind]
    return math.exp(z) if kind == "log" else 1 / (1 + math.exp(-z))


def _slope(kind: str, value: float) -> float:
    """d value / d z of the transform at value."""
    if kind in _LINEAR:
        return _LINEAR[kind]
    return value if kind == "log" else value * (1 - value)


def _weights(tables: PaperTables, stat: str) -> np.ndarray:
    return tables.three_sigma[stat]


def calibrate_rig(
    tables: PaperTables, nominal: Mechanism, speeds: Sequence[float],
    fit: Sequence[str], statistics: Sequence[str] = STATISTICS,
    start: RigModel | None = None, starts: Sequence[dict[str, float]] = (),
) -> Fit:
    """Fit ``fit`` (at most :data:`MAX_FORCE_FITTED`) on the rows at ``speeds`` (m/s) and
    the chosen ``statistics``; the stroke reading is fitted when "stroke" is among them.

    The fit starts from ``start`` (default the shipped model) and from each of ``starts``
    (values of fitted parameters put into ``start``); the result of least cost is kept.
    """
    start = start or RigModel()
    fit = tuple(fit)
    unknown = [n for n in fit if n not in FORCE_FITTABLE]
    if unknown:
        raise RigCalibrationError(
            f"cannot fit {unknown}; fittable: {', '.join(FORCE_FITTABLE)}")
    if len(set(fit)) != len(fit) or len(fit) > MAX_FORCE_FITTED:
        raise RigCalibrationError(f"fit at most {MAX_FORCE_FITTED} distinct parameters: {fit}")
    bad = [s for s in statistics if s not in STATISTICS]
    if bad or not statistics:
        raise RigCalibrationError(f"statistics must be among {', '.join(STATISTICS)}: {bad}")
    rows = [tables.speed_index(s) for s in speeds]
    if not rows:
        raise RigCalibrationError("give at least one speed to fit")
    forces = [s for s in statistics if s != "stroke"]
    if forces and not fit:
        raise RigCalibrationError(
            "fitting force statistics needs at least one parameter (--fit PARAM ...); the "
            "statistic 'stroke' alone refits only the encoder's reading")
    if fit and not forces:
        raise RigCalibrationError(
            f"{', '.join(fit)} would be fitted on force statistics, and none is chosen "
            "('stroke' refits only the encoder's reading, which needs no --fit)")
    kinds = [FORCE_FITTABLE[n] for n in fit]

    def model_at(z: np.ndarray) -> RigModel:
        return start.with_values({n: _inverse(k, zi) for n, k, zi in zip(fit, kinds, z)})

    def residuals(z: np.ndarray) -> np.ndarray:
        try:
            model = model_at(z)
            out = []
            for i in rows:
                sims = [model.statistics(nominal, tables.speeds[i], d) for d in tables.errors]
                for stat in forces:
                    sim = np.array([getattr(s, stat) for s in sims])
                    out.append((sim - tables.mean[stat][i]) / _weights(tables, stat)[i])
            return np.concatenate(out)
        except (AsymmetryError, AssemblyError, ValueError):
            return np.full(len(rows) * len(forces) * len(tables.errors), REFUSED)

    def at_limit(z: np.ndarray, i: int) -> bool:
        """The model refuses a small step of parameter i one way or the other."""
        for sign in (-1.0, 1.0):
            probe = z.copy()
            probe[i] += sign * _LIMIT_PROBE * max(abs(z[i]), 1.0)
            if np.all(residuals(probe) == REFUSED):
                return True
        return False

    values: dict[str, float] = {}
    errors: dict[str, float] = {}
    model, cost, limits = start, 0.0, ()
    if forces:
        models = [start, *(start.with_values(values) for values in starts)]
        result = min((least_squares(residuals, np.array([_start(n, k, m.value(n))
                                                         for n, k in zip(fit, kinds)]),
                                    diff_step=1e-4) for m in models),
                     key=lambda r: r.cost)
        model = model_at(result.x)
        dof = max(result.fun.size - len(fit), 1)
        cost = float(np.mean(result.fun**2))
        limits = tuple(n for i, n in enumerate(fit) if at_limit(result.x, i))
        free = [i for i, n in enumerate(fit) if n not in limits]
        # a column whose difference step crossed the limit is meaningless: held parameters out
        cov = _covariance(result.jac[:, free], float(result.fun @ result.fun) / dof)
        var = dict(zip(free, np.diag(cov)))
        for i, (n, k, zi) in enumerate(zip(fit, kinds, result.x)):
            values[n] = _inverse(k, zi)
            errors[n] = (_slope(k, values[n]) * math.sqrt(max(var[i], 0.0)) if i in var
                         else math.nan)
    stroke_errors: dict[str, float] = {}
    if "stroke" in statistics:
        model, stroke_errors = _fit_stroke(tables, nominal, model, rows)
    return Fit(model, fit, values, errors, stroke_errors,
               tuple(float(tables.speeds[i]) for i in rows), tuple(statistics), cost, limits)


def _covariance(jac: np.ndarray, variance: float) -> np.ndarray:
    try:
        return np.linalg.inv(jac.T @ jac) * variance
    except np.linalg.LinAlgError:
        return np.full((jac.shape[1],) * 2, np.inf)


def _fit_stroke(tables: PaperTables, nominal: Mechanism, model: RigModel,
                rows: list[int]) -> tuple[RigModel, dict[str, float]]:
    """The stroke is linear in the reading's (datum, lever, compliance): weighted linear
    least squares (weights: the printed 3 sigma)."""
    names = ("datum", "lever", "compliance")
    latency = model.reading.toggle_latency
    units = [replace(model, reading=RigReading(toggle_latency=latency,
                                               **{n: 1.0 if n == m else 0.0 for n in names}))
             for m in names]
    base = replace(model, reading=RigReading(toggle_latency=latency))
    a, b = [], []
    for i in rows:
        for j, d in enumerate(tables.errors):
            s0 = base.statistics(nominal, tables.speeds[i], d).stroke
            weight = tables.three_sigma["stroke"][i, j]
            a.append([(u.statistics(nominal, tables.speeds[i], d).stroke - s0) / weight
                      for u in units])
            b.append((tables.mean["stroke"][i, j] - s0) / weight)
    A, y = np.array(a), np.array(b)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    cov = _covariance(A, float(res @ res) / max(len(y) - len(names), 1))
    reading = RigReading(toggle_latency=latency, **{n: float(c) for n, c in zip(names, coef)})
    return replace(model, reading=reading), {n: float(math.sqrt(max(cov[k, k], 0.0)))
                                             for k, n in enumerate(names)}


class Row(NamedTuple):
    """One measured statistic against the simulated rig (SI)."""

    statistic: str
    speed: float
    error: float
    measured: float
    three_sigma: float
    simulated: float

    @property
    def in_sigma(self) -> float:
        """Residual in units of the printed 3 sigma."""
        return (self.simulated - self.measured) / self.three_sigma

    @property
    def relative(self) -> float:
        return (self.simulated - self.measured) / abs(self.measured)

    def holds(self, stroke_tolerance: float = 0.05e-3) -> bool:
        """The issue's criterion: the stroke within 0.05 mm; forces within 25 % or 3 sigma
        (delta_r8 = 0: within 3 sigma only)."""
        if self.statistic == "stroke":
            return abs(self.simulated - self.measured) <= stroke_tolerance
        if abs(self.in_sigma) <= 1.0:
            return True
        return self.error > 0 and abs(self.relative) <= RELATIVE


def compare_tables(tables: PaperTables, simulated: dict[str, np.ndarray],
                   statistics: Sequence[str] = STATISTICS) -> list[Row]:
    """Every (statistic, speed, delta_r8) side by side."""
    return [Row(stat, float(v), float(d), float(tables.mean[stat][i, j]),
                float(tables.three_sigma[stat][i, j]), float(simulated[stat][i, j]))
            for stat in statistics for i, v in enumerate(tables.speeds)
            for j, d in enumerate(tables.errors)]


def plot_tables(tables: PaperTables, nominal: Mechanism, model: RigModel, folder: str | Path,
                fitted: set[tuple[str, float]] | None = None,
                statistics: Sequence[str] = STATISTICS, points: int = 31) -> list[Path]:
    """One PNG per statistic: measured mean +- 3 sigma (error bars) and the simulated rig
    (curves over ``points`` link-8 errors) against delta_r8, one colour per speed; the
    (statistic, speed) rows in ``fitted`` (default: the shipped calibration's, every
    statistic at :data:`SHIPPED_FIT_SPEEDS`) drawn solid, predicted ones dashed. The speeds'
    measured bars stand side by side around their delta_r8 (a few hundredths of a mm
    apart: on one abscissa they hid each other), the legend beside the axes. Written as
    ``tables_<stat>.png``."""
    from toggle.plots import plt, save_figure

    errors = np.linspace(tables.errors.min(), tables.errors.max(), points)
    curves = [[model.statistics(nominal, v, d) for d in errors] for v in tables.speeds]
    paths = []
    spread = 0.04 * float(np.ptp(tables.errors)) * 1e3  # mm between the speeds' bars
    for stat in statistics:
        scale, unit = (1e3, "mm") if stat == "stroke" else (1.0, "N")
        fig, ax = plt.subplots(figsize=(9, 4.5))
        for i, v in enumerate(tables.speeds):
            colour = f"C{i}"
            was_fitted = ((stat, float(v)) in fitted if fitted is not None else
                          any(math.isclose(v, f, rel_tol=1e-6) for f in SHIPPED_FIT_SPEEDS))
            shift = (i - (len(tables.speeds) - 1) / 2) * spread
            ax.errorbar(tables.errors * 1e3 + shift, tables.mean[stat][i] * scale,
                        yerr=tables.three_sigma[stat][i] * scale, fmt="o", ms=5,
                        color=colour, capsize=3, label=f"{v * 1e3:g} mm/s measured ± 3σ")
            ax.plot(errors * 1e3, [getattr(s, stat) * scale for s in curves[i]],
                    "-" if was_fitted else "--", color=colour,
                    label=f"{v * 1e3:g} mm/s simulated "
                          f"({'fitted' if was_fitted else 'predicted'})")
        ax.set_xlabel("link-8 error Δr8 (mm)")
        ax.set_ylabel(f"{STAT_LABELS[stat]} ({unit})")
        ax.set_title(f"Seed 000 Tables 3-8: {STAT_LABELS[stat]} (measured bars of the speeds "
                     "side by side at each Δr8)", fontsize=10)
        ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
        paths.append(save_figure(fig, Path(folder) / f"tables_{stat}.png"))
    return paths
