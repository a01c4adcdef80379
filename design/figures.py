"""Figures a designer reads: the front in every pair of objectives with the reference
designs marked, and parallel coordinates of the front (PNG). Axes are named in words with
the unit a designer reads (mm, kN, MPa, deg: :func:`axis_label`), never the code's key and
an offset exponent; the legend sits below the plots, in a legible size."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from design.objectives import Evaluation
from design.placement import Placement
from design.targets import OBJECTIVES
from toggle.plots import plt, save_figure

#: Pairs of objectives drawn at most (the first objectives' pairs).
MAX_PAIRS = 6
_MARKERS = "os^Dvp*hX"


#: SI units as the figures print them: (display unit, factor from SI).
DISPLAY = {"m": ("mm", 1e3), "N": ("kN", 1e-3), "Pa": ("MPa", 1e-6),
           "rad": ("deg", 180.0 / math.pi), "N m": ("N m", 1.0), "J": ("J", 1.0),
           "s": ("s", 1.0), "kg": ("kg", 1.0), "1": ("1", 1.0)}
#: Each objective's name on an axis, in words (short: the objective's label is a sentence).
AXIS_NAMES = {
    "force_amplification": "force amplification Mp", "mechanical_advantage_lock":
    "mechanical advantage at lock", "stroke_ratio": "platen/crosshead stroke",
    "velocity_ratio_peak": "peak platen/crosshead speed", "coping_angle_min":
    "least coping angle", "velocity_ratio_close": "platen/crosshead speed at the mold",
    "close_time": "closing time", "close_rms_torque": "RMS motor torque, closing",
    "close_energy": "motor energy, closing", "cycle_rms_torque": "RMS motor torque, cycle",
    "cycle_energy": "motor energy, cycle", "thrust_peak": "peak crosshead thrust",
    "link_stress": "peak link stress", "tiebar_stress": "tie-bar stress",
    "tolerance_cost": "tolerance cost", "tolerance_sensitivity": "tolerance sensitivity",
    "installation_length": "installation length", "transmission_angle":
    "least transmission angle", "radial_envelope": "radial envelope",
    "link_mass": "link mass", "breakaway_force": "mold break-away force",
}


def axis_label(key: str) -> str:
    """``peak crosshead thrust (kN)``: the objective in words and its display unit."""
    return f"{AXIS_NAMES.get(key, key.replace('_', ' '))} ({_display(key)[0]})"


def _display(key: str) -> tuple[str, float]:
    unit = OBJECTIVES[key].unit
    return DISPLAY.get(unit, (unit, 1.0))


def _values(evaluations: Sequence[Evaluation], key: str) -> np.ndarray:
    """The objective's values in its display unit (mm, kN, MPa, deg)."""
    scale = _display(key)[1]
    return np.array([e.metrics.get(key, math.nan) for e in evaluations], dtype=float) * scale


def _point(metrics: dict, key: str) -> float:
    return metrics.get(key, math.nan) * _display(key)[1]


def front_figure(path: Path, keys: Sequence[str], feasible: Sequence[Evaluation],
                 front: Sequence[Evaluation], placements: Sequence[Placement] = ()) -> Path:
    """Scatter of feasible designs and the front in pairs of objectives, references marked
    (a line from a dominated reference to the design that dominates it)."""
    pairs = list(itertools.combinations(keys, 2))[:MAX_PAIRS]
    cols = min(3, len(pairs))
    rows = math.ceil(len(pairs) / cols)
    fig = plt.figure(figsize=(4.6 * cols, 4.0 * rows + 0.9))
    grid = fig.add_gridspec(rows + 1, cols, height_ratios=[1.0] * rows + [0.2])
    axes = np.array([[fig.add_subplot(grid[r, c]) for c in range(cols)] for r in range(rows)])
    key_ax = fig.add_subplot(grid[rows, :])  # the legend's row, below every plot
    key_ax.axis("off")
    for ax, (a, b) in zip(axes.flat, pairs):
        ax.scatter(_values(feasible, a), _values(feasible, b), s=6, c="0.75",
                   label="feasible designs")
        ax.scatter(_values(front, a), _values(front, b), s=14, c="tab:blue", label="Pareto set")
        for i, p in enumerate(placements):  # one marker and colour per reference throughout
            ra, rb = _point(p.reference.metrics, a), _point(p.reference.metrics, b)
            ax.scatter([ra], [rb], marker=_MARKERS[i % len(_MARKERS)],
                       color=f"C{(i + 1) % 10}", s=60, edgecolors="k", label=p.name, zorder=3)
            if p.dominated_by is not None:
                ax.annotate("", (_point(p.dominated_by.metrics, a),
                                 _point(p.dominated_by.metrics, b)),
                            (ra, rb), arrowprops={"arrowstyle": "->", "color": "0.3"})
        ax.set_xlabel(axis_label(a), fontsize=10)
        ax.set_ylabel(axis_label(b), fontsize=10)
        ax.ticklabel_format(axis="both", style="plain", useOffset=False)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(pairs):]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if placements:
        labels[2:] = [f"{name} (reference)" for name in labels[2:]]
    key_ax.legend(handles, labels, loc="center", ncol=min(len(labels), 4), fontsize=10,
                  frameon=False, markerscale=1.5)
    return save_figure(fig, path)


def parallel_figure(path: Path, keys: Sequence[str], front: Sequence[Evaluation],
                    placements: Sequence[Placement] = ()) -> Path:
    """Parallel coordinates of the front's objectives, each axis scaled to the range of
    the front and the references, better upwards; references drawn thick."""
    refs = [p.reference for p in placements]
    both = list(front) + refs
    data = np.array([[e.metrics.get(k, math.nan) for k in keys] for e in both], dtype=float)
    sense = np.array([OBJECTIVES[k].sense for k in keys], dtype=float)
    lo, hi = np.nanmin(data, axis=0), np.nanmax(data, axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    scaled = np.where(sense > 0, (data - lo) / span, (hi - data) / span)
    fig, ax = plt.subplots(figsize=(1.8 * len(keys) + 2, 4))
    xs = np.arange(len(keys))
    for row in scaled[:len(front)]:
        ax.plot(xs, row, c="tab:blue", alpha=0.35, lw=0.8)
    for i, (p, row) in enumerate(zip(placements, scaled[len(front):])):
        ax.plot(xs, row, lw=2.2, color=f"C{(i + 1) % 10}",
                marker=_MARKERS[i % len(_MARKERS)],
                label=p.name)
    ax.set_xticks(xs)
    scales = [_display(k)[1] for k in keys]
    ax.set_xticklabels([f"{axis_label(k)}\n{'higher' if s > 0 else 'lower'} up"
                        f"\n[{a * f:.4g}, {b * f:.4g}]"
                        for k, s, a, b, f in zip(keys, sense, lo, hi, scales)], fontsize=8)
    ax.set_ylabel("objective, scaled: better upwards (1)")
    if placements:
        ax.legend(fontsize=9)
    return save_figure(fig, path)
