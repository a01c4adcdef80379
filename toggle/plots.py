"""Figures of the plant model (PNG, SI values shown in mm and degrees, units labelled)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

#: The house style of every figure (all plotting imports ``plt`` from here).
plt.rcParams.update({"axes.grid": True, "grid.alpha": 0.3})
import numpy as np  # noqa: E402

from toggle.files import atomic_path  # noqa: E402
from toggle.kinematics import half_motion, sensitivities, stroke_limits  # noqa: E402
from toggle.params import DIMENSIONS, HALVES, PAPER_NAMES, Mechanism  # noqa: E402
from toggle.tolerance import asymmetry, it_tolerances  # noqa: E402

MM = 1e3


def save_figure(fig: plt.Figure, path: Path) -> Path:
    """Write a figure as PNG (120 dpi, folders created), close it, return the path.

    Written to a temporary file and renamed: a failed write leaves no half-written PNG.
    """
    try:
        fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    finally:
        plt.close(fig)
    return path


def plot_kinematics(mech: Mechanism, path: Path, points: int = 400) -> Path:
    """L(x) of both halves (seed 000, Figure 6), velocity ratio and mechanical advantage."""
    x_open, x_tp = stroke_limits(mech.lower)
    xs = np.linspace(x_open, x_tp, points)
    fig, axes = plt.subplots(3, 1, figsize=(7, 9), sharex=True)
    for h in HALVES:
        m = half_motion(xs, mech.half(h), label=f"{h} half")
        axes[0].plot(xs * MM, m.L * MM, label=f"{h} half")
        axes[1].plot(xs * MM, m.dL_dx, label=f"{h} half")
        axes[2].semilogy(xs[:-1] * MM, m.mechanical_advantage[:-1], label=f"{h} half")
    axes[0].set_ylabel("output position L (mm)")
    axes[1].set_ylabel("velocity ratio dL/dx (1)")
    axes[2].set_ylabel("ideal mechanical advantage (1)")
    axes[2].set_xlabel("input position x (mm)")
    for ax in axes:
        ax.legend()
    axes[0].set_title(f"{mech.name}: kinematics over the stroke")
    return save_figure(fig, path)


def plot_sensitivity(mech: Mechanism, grade: int, path: Path, points: int = 300) -> Path:
    """Output error curves of each half for IT deviations (seed 000, Figures 7 and 8).

    Lower half at its lower deviations (-IT), upper half at its upper ones (+IT).
    """
    x_open, x_tp = stroke_limits(mech.lower)
    xs = np.linspace(x_open, x_tp, points)
    tol = it_tolerances(mech, grade)
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), sharex=True)
    for col, (h, sign) in enumerate((("lower", -1.0), ("upper", 1.0))):
        sens = sensitivities(xs, mech.half(h), label=f"{h} half")
        contrib = {k: sens[k] * sign * tol[h][k] for k in DIMENSIONS}
        for k in DIMENSIONS:
            axes[0, col].plot(xs * MM, contrib[k] * MM, label=f"Δ{PAPER_NAMES[h][k]}")
        stack = np.array(list(contrib.values()))
        axes[1, col].plot(xs * MM, np.abs(stack).sum(axis=0) * MM, label="worst case (ΔL_wor)")
        axes[1, col].plot(xs * MM, np.sqrt((stack**2).sum(axis=0)) * MM, label="RSS (ΔL_rss)")
        axes[0, col].set_title(f"{h} half, IT{grade}, {'-' if sign < 0 else '+'}IT deviations")
        axes[0, col].set_ylabel("output error ΔL (mm)")
        axes[1, col].set_ylabel("deviation (mm)")
        axes[1, col].set_xlabel("input position x (mm)")
        for ax in axes[:, col]:
            ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_it_grades(mech: Mechanism, path: Path, grades: range = range(6, 13)) -> Path:
    """Asymmetry indices at the toggle against IT grade (seed 000, Figure 9)."""
    reports = [asymmetry(mech, it_tolerances(mech, g)) for g in grades]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(list(grades), [r.dL_wor * MM for r in reports], "o-", label="δL_wor (linearised)")
    ax.plot(list(grades), [r.dL_rss * MM for r in reports], "s-", label="δL_rss (linearised)")
    ax.plot(list(grades), [r.dL_exact * MM for r in reports], "x--", label="exact nonlinear")
    ax.set_xlabel("ISO tolerance grade IT (1)")
    ax.set_ylabel("asymmetry index at the toggle (mm)")
    ax.set_title(f"{mech.name}: asymmetry indices at the toggle position")
    ax.legend()
    return save_figure(fig, path)
