"""Response surfaces of section 5.2 of Chang, Lee & Hsu 2021 (Eqs 44-47 and 52-55).

Each index y (stroke error, forward and backward RMS force, force at the toggle) is
modelled by the paper's "modified cubic" in the speed v and the link error D = delta_r8:

    y = c1 + c2 v + c3 D + c4 v D + c5 v^2 + c6 D^2 + c7 v^2 D + c8 v D^2

fitted by least squares to the mean of each run (or of each cell of Tables 3-8). The fit
is done in the paper's units (v in mm/s, D in mm, y in mm or N), which keeps the design
matrix well conditioned and gives coefficients comparable with the printed equations;
:class:`ResponseFit` carries both those and the SI coefficients (v in m/s, D in m, y in m
or N).

Reproduction (tests/test_rsm.py): fitted to the means of Tables 6-8, the coefficients of
Eqs 45-47 come out equal to every printed digit, once the minus signs lost in the
extracted text are restored (toggle/data/chang2021_tables.toml lists them); re-expressed in
the platen error at the toggle, dL_TP = D / cos(theta8(x_TP)) with theta8 from
toggle.kinematics, they also give Eqs 53-55 to every printed digit. Fitted to the means
of Tables 3-5, the stroke error model is close to Eq 44 but not identical: the two
predictions differ by at most 0.008 mm over 5-25 mm/s x 0-0.75 mm, and Eq 44's residual
norm at the twelve table means is 0.0801 mm against the least-squares optimum 0.0791 mm
(c1 0.3675 vs 0.3723, c2 0.00641 vs 0.0046, c5 -0.000143 vs -0.0000794, ...), so Eq 44
was presumably fitted to unrounded or slightly different data.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from toggle.calibration import PAPER_TABLES
from toggle.files import InputError, read_text
from toggle.kinematics import half_pose, toggle_position
from toggle.params import Mechanism, tomllib

#: Terms of the modified cubic model and their powers of (v, D).
TERMS = ("1", "v", "D", "v D", "v^2", "D^2", "v^2 D", "v D^2")
POWERS = ((0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (0, 2), (2, 1), (1, 2))

#: Modelled indices: summary key -> (paper equation, paper unit, SI-to-paper factor).
RESPONSES = {
    "stroke_error": ("Eq 44", "mm", 1e3),
    "force_forward_rms": ("Eq 45", "N", 1.0),
    "force_backward_rms": ("Eq 46", "N", 1.0),
    "force_toggle": ("Eq 47", "N", 1.0),
}
#: Paper units of the inputs: v in mm/s and D in mm are SI values times 1e3.
_INPUT_FACTOR = 1e3
#: The file name of a response's contour map (``str.format`` with the response's name).
RSM_FIGURE = "rsm_{}.png"


class RsmError(InputError):
    """Data that cannot give a response surface."""


def design_matrix(v: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Rows (1, v, D, vD, v^2, D^2, v^2 D, v D^2) for each point (any consistent units)."""
    v, d = np.broadcast_arrays(np.asarray(v, dtype=float), np.asarray(d, dtype=float))
    return np.stack([v**a * d**b for a, b in POWERS], axis=-1)


@dataclass(frozen=True)
class ResponseFit:
    """The fitted model of one index.

    paper_coefficients: y in mm or N from v in mm/s and D in mm (the printed form);
    coefficients: y in m or N from v in m/s and D in m. residual_norm is in SI.
    """

    name: str
    paper_coefficients: tuple[float, ...]
    coefficients: tuple[float, ...]
    residual_norm: float
    r_squared: float

    def predict(self, speed: Any, delta_r8: Any) -> np.ndarray:
        """The index (m or N) at speed (m/s) and delta_r8 (m)."""
        return design_matrix(speed, delta_r8) @ np.asarray(self.coefficients)

    def platen_error_coefficients(self, cos_theta8: float) -> tuple[float, ...]:
        """Paper-unit coefficients in dL_TP (mm) instead of D, as in Eqs 52-55.

        With D = dL_TP cos(theta8(x_TP)) (Eq 51) a term in D^k scales by cos^k.
        """
        return tuple(c * cos_theta8**b for c, (_, b) in zip(self.paper_coefficients, POWERS))


@dataclass(frozen=True)
class RsmFit:
    """Fitted models of every index that all points provide, with the design points (SI)."""

    speed: np.ndarray
    delta_r8: np.ndarray
    responses: dict[str, ResponseFit]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form: SI coefficients, paper-unit coefficients and fit quality."""
        return {
            "terms": list(TERMS),
            "points": [{"speed": float(v), "delta_r8": float(d)}
                       for v, d in zip(self.speed, self.delta_r8)],
            "responses": {
                name: {"equation": RESPONSES[name][0],
                       "coefficients_si": list(r.coefficients),
                       "coefficients_paper": list(r.paper_coefficients),
                       "paper_units": f"{RESPONSES[name][1]} from v in mm/s and delta_r8 in mm",
                       "residual_norm": r.residual_norm, "r_squared": r.r_squared}
                for name, r in self.responses.items()
            },
        }


@dataclass(frozen=True)
class PaperTables:
    """Tables 3-8 and Eqs 44-47/52-55 of the paper, in the paper's units.

    ``mean[name]`` and ``three_sigma[name]`` are (speed x delta_r8) arrays; the
    equations are the printed coefficient strings (lost signs restored).
    """

    speed_mm_s: np.ndarray
    delta_r8_mm: np.ndarray
    units: dict[str, str]
    mean: dict[str, np.ndarray]
    three_sigma: dict[str, np.ndarray]
    equations: dict[str, tuple[str, ...]]
    equations_platen_error: dict[str, tuple[str, ...]]

    def summaries(self) -> list[dict[str, Any]]:
        """One run summary per table cell, SI, shaped like ``hil.host.recording.summarize``'s."""
        out = []
        for i, v in enumerate(self.speed_mm_s):
            for j, d in enumerate(self.delta_r8_mm):
                entry: dict[str, Any] = {"meta": {"speed": v / _INPUT_FACTOR,
                                                  "delta_r8": d / _INPUT_FACTOR}}
                for name, table in self.mean.items():
                    scale = 1e-3 if self.units[name] == "mm" else 1.0
                    entry[name] = {"mean": float(table[i, j]) * scale,
                                   "three_sigma": float(self.three_sigma[name][i, j]) * scale}
                out.append(entry)
        return out


def load_paper_tables(path: str | Path = PAPER_TABLES) -> PaperTables:
    """Read the shipped Tables 3-8 (or a file of the same layout)."""
    try:
        raw = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        speed, delta = np.array(raw["speed"], float), np.array(raw["delta_r8"], float)
        shape = (speed.size, delta.size)
        mean = {k: np.array(t["mean"], float).reshape(shape) for k, t in raw["tables"].items()}
        sigma = {k: np.array(t["three_sigma"], float).reshape(shape)
                 for k, t in raw["tables"].items()}
        eqs = {key: {k: tuple(v) for k, v in raw[key].items() if k != "terms"}
               for key in ("equations", "equations_platen_error")}
        return PaperTables(speed, delta, dict(raw["units"]), mean, sigma, eqs["equations"],
                           eqs["equations_platen_error"])
    except (OSError, KeyError, ValueError, TypeError, tomllib.TOMLDecodeError) as exc:
        raise RsmError(f"cannot read paper tables {path}: {exc}") from exc


def _fit_one(name: str, v_mm: np.ndarray, d_mm: np.ndarray, y_si: np.ndarray) -> ResponseFit:
    factor = RESPONSES[name][2]
    y = y_si * factor
    X = design_matrix(v_mm, d_mm)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = X @ coef - y
    spread = float(np.sum((y - y.mean()) ** 2))
    # y_paper = factor y_si and v, D in paper units are 1e3 times SI: c_si = c 1e3^(a+b) / factor
    si = tuple(float(c * _INPUT_FACTOR ** (a + b) / factor) for c, (a, b) in zip(coef, POWERS))
    return ResponseFit(
        name=name,
        paper_coefficients=tuple(float(c) for c in coef),
        coefficients=si,
        residual_norm=float(np.linalg.norm(resid)) / factor,
        r_squared=1.0 - float(resid @ resid) / spread if spread > 0 else 1.0,
    )


def _mean(summary: Mapping[str, Any], name: str) -> float | None:
    stat = summary.get(name)
    value = stat.get("mean") if isinstance(stat, Mapping) else None
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def fit_rsm(source: PaperTables | Iterable[Mapping[str, Any]]) -> RsmFit:
    """Fit Eqs 44-47's model to run summaries (or to the paper's tables).

    Each summary needs ``meta.speed`` (m/s), ``meta.delta_r8`` (m) and the index
    means (as ``summary.json`` has them). An index is fitted when every summary has
    it. The eight terms need at least three speeds, three link errors and eight
    distinct points.
    """
    summaries = source.summaries() if isinstance(source, PaperTables) else list(source)
    try:
        v = np.array([float(s["meta"]["speed"]) for s in summaries], dtype=float)
        d = np.array([float(s["meta"]["delta_r8"]) for s in summaries], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise RsmError("every run needs numbers meta.speed and meta.delta_r8 (a "
                       "reciprocating run, hil run --speed, not a profile)") from None
    v_mm, d_mm = v * _INPUT_FACTOR, d * _INPUT_FACTOR
    points = {(round(float(a), 9), round(float(b), 9)) for a, b in zip(v_mm, d_mm)}
    if np.linalg.matrix_rank(design_matrix(v_mm, d_mm)) < len(TERMS):
        raise RsmError(
            f"the {len(TERMS)}-term model needs >= 3 speeds, >= 3 values of delta_r8 and "
            f">= {len(TERMS)} distinct points; got {len(points)} point(s): "
            + ", ".join(f"{a:g} mm/s at {b:g} mm" for a, b in sorted(points))
        )
    responses = {}
    for name in RESPONSES:
        values = [_mean(s, name) for s in summaries]
        if all(x is not None for x in values):
            responses[name] = _fit_one(name, v_mm, d_mm, np.array(values, dtype=float))
    if not responses:
        raise RsmError(f"no index is present in every run; need one of {list(RESPONSES)}")
    return RsmFit(v, d, responses)


def toggle_cos_theta8(mech: Mechanism) -> float:
    """cos(theta8) at the toggle of the (nominal) upper half: Eq 51's 0.998866 for chang2021."""
    theta8 = 2 * math.pi - float(half_pose(toggle_position(mech.upper), mech.upper).theta5)
    return math.cos(theta8)


def plot_rsm(fit: RsmFit, out_dir: str | Path, *, cos_theta8: float | None = None,
             levels: int = 15) -> list[Path]:
    """Contour maps of each fitted index over the design range (Figures 17-20).

    With ``cos_theta8`` the abscissa is the platen error at the toggle dL_TP (mm), as in
    the paper's figures; otherwise delta_r8 (mm). Returns the PNG paths.
    """
    from toggle.plots import plt, save_figure

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    v = np.linspace(fit.speed.min(), fit.speed.max(), 101)
    d = np.linspace(fit.delta_r8.min(), fit.delta_r8.max(), 101)
    V, D = np.meshgrid(v, d)
    scale_x = 1.0 / cos_theta8 if cos_theta8 else 1.0
    xlabel = "platen error at the toggle \u03b4L_TP (mm)" if cos_theta8 else "\u0394r8 (mm)"
    paths = []
    for name, r in fit.responses.items():
        eq, unit, factor = RESPONSES[name]
        fig, ax = plt.subplots(figsize=(6.5, 5))
        z = r.predict(V, D) * factor
        cs = ax.contourf(D * 1e3 * scale_x, V * 1e3, z, levels=levels, cmap="viridis")
        ax.contour(cs, colors="k", linewidths=0.4)
        ax.plot(fit.delta_r8 * 1e3 * scale_x, fit.speed * 1e3, "w+", ms=8, mew=1.5,
                clip_on=False, label="data points")
        fig.colorbar(cs, ax=ax, label=f"{name} ({unit})")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("input speed v (mm/s)")
        ax.set_title(f"Response surface of {name} ({eq} model)")
        ax.legend(loc="upper right", fontsize="small")
        paths.append(save_figure(fig, out / RSM_FIGURE.format(name)))
    return paths


def load_summaries(paths: Sequence[str | Path]) -> list[dict[str, Any]]:
    """Summaries from run directories or summary.json files; a file that cannot be read or
    is not a reciprocating run's summary is an :class:`RsmError` naming it."""
    out = []
    for p in map(Path, paths):
        file = p / "summary.json" if p.is_dir() else p
        try:
            summary = json.loads(read_text(file, "run summary"))
        except json.JSONDecodeError as exc:
            raise RsmError(f"run summary {file}: not JSON (line {exc.lineno}: "
                           f"{exc.msg.lower()})") from None
        except InputError as exc:
            raise RsmError(str(exc)) from None
        meta = summary.get("meta") if isinstance(summary, dict) else None
        if not isinstance(meta, dict):
            raise RsmError(f"run summary {file}: not a hil run's summary.json (no meta)")
        for key, what in (("speed", "m/s"), ("delta_r8", "m")):
            value = meta.get(key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise RsmError(f"run summary {file}: meta.{key} must be a number ({what}); "
                               "hil rsm fits reciprocating runs (hil run --speed), not "
                               "planned profiles")
        out.append(summary)
    return out
