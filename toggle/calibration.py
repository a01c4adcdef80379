"""Fit the unequal-halves model (toggle.asymmetry) to measured toggle forces.

Data: a table like Chang et al. 2021's Tables 6-8 (F_TP mean and three-sigma band
per speed and link-8 error; ``toggle/data/chang2021_tables.toml``) or run summaries
in the same shape. At most three parameters are fitted, by weighted least squares
(residual / three-sigma band) in log coordinates, so every fitted value stays
positive; the rest keep their physical defaults. The rows of one speed fix the
stiffness and free play; the speed dependence of the friction (the Hersey transition)
needs rows at two speeds (docs/unequal-halves.md, section 5).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from toggle.asymmetry import AsymmetryError, AsymmetryParams, toggle_force
from toggle.files import read_toml
from toggle.params import Mechanism

#: The paper's tables, shared with the HIL response surfaces (units as printed: mm/s, mm, N).
PAPER_TABLES = Path(__file__).with_name("data") / "chang2021_tables.toml"
#: Parameters a calibration may fit (all positive scalars of AsymmetryParams).
FITTABLE = ("free_play", "contact_stiffness", "series_stiffness", "drive_stiffness", "mu",
            "rate_strengthening", "hersey_transition")
MAX_FITTED = 3
#: Starts for parameters whose value may be infinite (boundary friction only), SI.
_FINITE_START = {"hersey_transition": 3e-6}


@dataclass(frozen=True)
class ForceTable:
    """Measured toggle forces: ``mean[i, j]`` and ``three_sigma[i, j]`` (N) at speed i, error j."""

    speeds: np.ndarray  # m/s
    errors: np.ndarray  # link-8 length error delta_r8, m
    mean: np.ndarray
    three_sigma: np.ndarray

    def __post_init__(self) -> None:
        shape = (len(self.speeds), len(self.errors))
        if np.shape(self.mean) != shape or np.shape(self.three_sigma) != shape:
            raise ValueError(f"force table must be {shape} (speeds x errors)")
        if np.any(np.asarray(self.three_sigma) <= 0):
            raise ValueError("three-sigma bands must be positive")

    def speed_index(self, speed: float) -> int:
        hits = np.flatnonzero(np.isclose(self.speeds, speed, rtol=1e-6))
        if not len(hits):
            raise ValueError(f"no data at {speed!r} m/s; speeds: {self.speeds.tolist()}")
        return int(hits[0])


def load_force_table(path: str | Path = PAPER_TABLES, key: str = "force_toggle") -> ForceTable:
    """Read a paper-style table (mm/s, mm, N as printed) and convert to SI."""
    data = read_toml(path, "force table")  # InputError: missing, unreadable, not TOML
    try:
        table = data["tables"][key]
        return ForceTable(np.asarray(data["speed"], float) * 1e-3,
                          np.asarray(data["delta_r8"], float) * 1e-3,
                          np.asarray(table["mean"], float), np.asarray(table["three_sigma"], float))
    except KeyError as exc:  # str(KeyError) is the bare key: say what is missing
        missing = f"[tables.{key}]" if exc.args[0] in (key, "tables") else repr(exc.args[0])
        raise ValueError(f"cannot read force table {key!r} from {path}: it has no {missing} "
                         f"(see toggle/data/chang2021_tables.toml)") from exc
    except (TypeError, ValueError) as exc:
        raise ValueError(f"cannot read force table {key!r} from {path}: {exc}") from exc


def table_mechanism(path: str | Path) -> str | None:
    """The preset a table was measured on (its ``mechanism`` key), or None if it names none."""
    name = read_toml(path, "force table").get("mechanism")
    return name if isinstance(name, str) else None


def predict(table: ForceTable, mech: Mechanism, params: AsymmetryParams) -> np.ndarray:
    """Model F_TP (N) at every (speed, error) of the table; errors go to the upper r5 (link 8)."""
    return np.array([[toggle_force(mech.with_error("upper", "r5", err), speed, params)
                      for err in table.errors] for speed in table.speeds])


class Calibration(NamedTuple):
    params: AsymmetryParams
    fitted: tuple[str, ...]
    speeds: tuple[float, ...]  # m/s, the table rows used
    normalised_residuals: np.ndarray  # (model - mean) / three_sigma, speeds x errors


def calibrate(
    table: ForceTable, mech: Mechanism, speeds: float | Sequence[float],
    fit: tuple[str, ...] = ("free_play", "contact_stiffness"),
    start: AsymmetryParams | None = None,
) -> Calibration:
    """Fit at most three parameters to the table's rows at ``speeds`` (m/s), from ``start``
    (default: the model's defaults)."""
    start = start or AsymmetryParams()
    if not 0 < len(fit) <= MAX_FITTED or len(set(fit)) != len(fit):
        raise ValueError(f"fit 1 to {MAX_FITTED} distinct parameters, got {fit}")
    unknown = set(fit) - set(FITTABLE)
    if unknown:
        raise ValueError(f"cannot fit {sorted(unknown)}; fittable: {', '.join(FITTABLE)}")
    rows = [table.speed_index(s) for s in np.atleast_1d(np.asarray(speeds, dtype=float))]
    used = ForceTable(table.speeds[rows], table.errors, table.mean[rows],
                      table.three_sigma[rows])

    def params_at(z: np.ndarray) -> AsymmetryParams:
        return start.replace(**{name: float(math.exp(zi)) for name, zi in zip(fit, z, strict=True)})

    def residuals(z: np.ndarray) -> np.ndarray:
        try:
            model = predict(used, mech, params_at(z))
        except AsymmetryError:
            return np.full(used.mean.size, 1e6)
        return ((model - used.mean) / used.three_sigma).ravel()

    result = least_squares(residuals, np.log([_start_value(start, name) for name in fit]),
                           x_scale=1.0, diff_step=1e-6)
    return Calibration(params_at(result.x), tuple(fit), tuple(map(float, used.speeds)),
                       residuals(result.x).reshape(used.mean.shape))


def _start_value(start: AsymmetryParams, name: str) -> float:
    """A positive, finite start for a log-coordinate fit (free play may be 0, the Hersey
    transition infinite: then a finite start)."""
    value = getattr(start, name)
    return max(value if math.isfinite(value) else _FINITE_START.get(name, 1.0), 1e-9)


class Comparison(NamedTuple):
    """One row of the side-by-side table: model against a measured F_TP."""

    speed: float  # m/s
    error: float  # delta_r8, m
    measured: float  # N
    three_sigma: float  # N
    model: float  # N
    #: (model - measured) / measured; NaN where the measured mean is within its 3-sigma band
    #: of zero (the delta_r8 = 0 rows, 1-3 N +- 3-4 N): a relative error there means nothing
    #: (it read -100 % beside "in band: yes")
    relative_error: float

    @property
    def within_band(self) -> bool:
        return abs(self.model - self.measured) <= self.three_sigma


def compare(table: ForceTable, mech: Mechanism, params: AsymmetryParams) -> list[Comparison]:
    """Side-by-side rows for every (speed, error) of the table."""
    model = predict(table, mech, params)
    mean, band = table.mean, table.three_sigma
    def relative(i: int, j: int) -> float:
        if abs(mean[i, j]) <= band[i, j]:
            return math.nan
        return float((model[i, j] - mean[i, j]) / mean[i, j])
    return [Comparison(float(s), float(e), float(mean[i, j]), float(band[i, j]),
                       float(model[i, j]), relative(i, j))
            for i, s in enumerate(table.speeds) for j, e in enumerate(table.errors)]
