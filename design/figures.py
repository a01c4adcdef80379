"""Figures a designer reads: the front in every pair of objectives with the reference
designs marked, and parallel coordinates of the front (PNG, axes ``quantity (unit)``)."""

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


def _values(evaluations: Sequence[Evaluation], key: str) -> np.ndarray:
    return np.array([e.metrics.get(key, math.nan) for e in evaluations], dtype=float)


def front_figure(path: Path, keys: Sequence[str], feasible: Sequence[Evaluation],
                 front: Sequence[Evaluation], placements: Sequence[Placement] = ()) -> Path:
    """Scatter of feasible designs and the front in pairs of objectives, references marked
    (a line from a dominated reference to the design that dominates it)."""
    pairs = list(itertools.combinations(keys, 2))[:MAX_PAIRS]
    cols = min(3, len(pairs))
    rows = math.ceil(len(pairs) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.6 * rows), squeeze=False)
    for ax, (a, b) in zip(axes.flat, pairs):
        ax.scatter(_values(feasible, a), _values(feasible, b), s=6, c="0.75",
                   label="feasible designs")
        ax.scatter(_values(front, a), _values(front, b), s=14, c="tab:blue", label="Pareto set")
        for i, p in enumerate(placements):  # one marker and colour per reference throughout
            ra, rb = p.reference.metrics.get(a, math.nan), p.reference.metrics.get(b, math.nan)
            ax.scatter([ra], [rb], marker=_MARKERS[i % len(_MARKERS)], color=f"C{i % 10}",
                       s=50, edgecolors="k", label=p.name, zorder=3)
            if p.dominated_by is not None:
                ax.annotate("", (p.dominated_by.metrics[a], p.dominated_by.metrics[b]),
                            (ra, rb), arrowprops={"arrowstyle": "->", "color": "0.3"})
        ax.set_xlabel(OBJECTIVES[a].header)
        ax.set_ylabel(OBJECTIVES[b].header)
    for ax in list(axes.flat)[len(pairs):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=6)
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
        ax.plot(xs, row, lw=2.2, color=f"C{i % 10}", marker=_MARKERS[i % len(_MARKERS)],
                label=p.name)
    ax.set_xticks(xs)
    ax.set_xticklabels([f"{OBJECTIVES[k].header}\n{'higher' if s > 0 else 'lower'} up"
                        f"\n[{a:.4g}, {b:.4g}]" for k, s, a, b in zip(keys, sense, lo, hi)],
                       fontsize=7)
    ax.set_ylabel("objective, scaled: better upwards (1)")
    if placements:
        ax.legend(fontsize=6)
    return save_figure(fig, path)
