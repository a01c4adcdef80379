"""The mechanism drawn to scale: both halves, the crosshead and the platen at a crosshead
position, and an animation over the stroke (GIF, through matplotlib's Pillow writer).

Joint positions come from :func:`toggle.kinematics.clamp_joints` (the angles of
:func:`toggle.kinematics.half_pose`); nothing here solves a loop. Labels follow seed 000
(Chang, Lee & Hsu 2021, Figures 3-5): links 1 (frame) to 9 (moving platen), link 2 the
crosshead, 3-5 the lower half and 6-8 the upper; joints A, B, C of the upper half and D, E,
F of the lower (pivot, elbow, platen joint: collinear at the toggle). Seed 001 names the
lower half's joints A (platen) to E (crosshead) instead: its A, B, C are seed 000's F, E, D.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib import animation

from toggle.elastics import clamp_stroke
from toggle.files import atomic_path
from toggle.kinematics import HalfJoints, clamp_joints, stroke_limits
from toggle.params import Mechanism
from toggle.plots import MM, plt, save_figure

#: Seed 000's letters of the pivot, elbow and platen joint of each half.
JOINT_LETTERS = {"upper": ("A", "B", "C"), "lower": ("D", "E", "F")}
#: Seed 000's numbers of each half's crosshead link, triangular link and platen-side link.
LINK_NUMBERS = {"lower": (3, 4, 5), "upper": (6, 7, 8)}
#: The joint markers' artist id (a test reads the drawn positions back by it).
JOINTS_GID = "joints"
_LINK = {"color": "tab:blue", "lw": 3.0, "solid_capstyle": "round", "zorder": 2}
_TRIANGLE = {"facecolor": "tab:orange", "edgecolor": "tab:red", "alpha": 0.6, "lw": 2.0,
             "zorder": 2}


def stroke_ends(mech: Mechanism) -> tuple[float, float]:
    """Crosshead positions of the open clamp and of the toggle, m (a preset's own
    ``[clamp] x_open`` where its crosshead link never becomes horizontal, as the SM-55)."""
    if mech.clamp is not None and mech.clamp.x_open is not None:
        return clamp_stroke(mech)
    return stroke_limits(mech.lower)


def _bounds(mech: Mechanism, xs: Sequence[float]) -> tuple[float, float, float, float]:
    """Limits (m) that hold the drawing at every position of ``xs``, with a margin."""
    px, py = [0.0], [0.0]
    for x in xs:
        for joints in clamp_joints(x, mech.lower, mech.upper).values():
            px += [float(p[0]) for p in joints]
            py += [float(p[1]) for p in joints]
    width = max(px) - min(px)
    pad = 0.12 * max(width, max(py) - min(py))
    return min(px) - pad, max(px) + pad, min(py) - pad, max(py) + pad


def draw_linkage(ax: plt.Axes, mech: Mechanism, x: float,
                 limits: tuple[float, float, float, float] | None = None) -> None:
    """Draw the clamp at crosshead position ``x`` (m) on ``ax`` in mm, to scale."""
    joints = clamp_joints(x, mech.lower, mech.upper)
    x0, x1, y0, y1 = limits or _bounds(mech, [x])
    low, up = joints["lower"], joints["upper"]
    # frame: the tailstock platen holding both pivots, and the clamp axis
    ax.axvline(0.0, color="0.35", lw=6, alpha=0.35, zorder=0)
    ax.axhline(0.0, color="0.5", lw=0.8, ls="-.", zorder=0)
    ax.text(-0.02 * (x1 - x0) * MM, y1 * MM * 0.95, "1", ha="right", va="top", fontsize=9,
            color="0.3")
    # crosshead (link 2) between the two crosshead pins, on the axis
    top, bottom = float(up.crosshead[1]), float(low.crosshead[1])
    half_height = max(0.5 * (top - bottom), 0.04 * (y1 - y0))
    mid = 0.5 * (top + bottom)
    ax.add_patch(plt.Rectangle(((x - 0.03 * (x1 - x0)) * MM, (mid - half_height) * MM),
                               0.06 * (x1 - x0) * MM, 2 * half_height * MM,
                               facecolor="0.8", edgecolor="0.3", zorder=1))
    ax.annotate("2", (x * MM, mid * MM), ha="center", va="center", fontsize=9, zorder=5)
    # moving platen (link 9) through both platen joints
    plx = [float(low.platen[0]), float(up.platen[0])]
    ply = [float(low.platen[1]), float(up.platen[1])]
    reach = 0.25 * (ply[1] - ply[0])
    direction = np.array([plx[1] - plx[0], ply[1] - ply[0]]) / (ply[1] - ply[0])
    ends = [np.array([plx[0], ply[0]]) - reach * direction,
            np.array([plx[1], ply[1]]) + reach * direction]
    ax.plot([e[0] * MM for e in ends], [e[1] * MM for e in ends], color="0.35", lw=8,
            alpha=0.5, solid_capstyle="butt", zorder=1)
    # its number where the bar crosses the clamp axis (the bar's ends may lie outside the
    # view, and an annotation outside it is not drawn)
    on_axis = plx[0] - ply[0] * direction[0]
    ax.annotate("9", (on_axis * MM, 0.0), xytext=(7, 5), textcoords="offset points",
                ha="left", va="bottom", fontsize=9, color="0.3", zorder=5)
    for half, j in joints.items():
        _draw_half(ax, half, j)
    points = [p for j in joints.values() for p in j]
    ax.plot([float(p[0]) * MM for p in points], [float(p[1]) * MM for p in points], "o",
            ms=7, mfc="white", mec="black", mew=1.5, zorder=4, gid=JOINTS_GID)
    ax.set_xlim(x0 * MM, x1 * MM)
    ax.set_ylim(y0 * MM, y1 * MM)
    ax.set_aspect("equal")
    ax.set_xlabel("horizontal position (mm)")
    ax.set_ylabel("vertical position (mm)")


#: A joint counts as across the clamp axis beyond this distance from it, m.
AXIS_TOLERANCE = 1e-5
#: The names of the joints that can cross the axis, by half: (corner, elbow).
_CROSSING_NAMES = {"lower": ("joint 3-4", "E"), "upper": ("joint 6-7", "B")}


def axis_crossings(mech: Mechanism, x: float) -> list[tuple[str, float]]:
    """The joints of either half that lie on the other half's side of the clamp axis at
    crosshead position ``x`` (m), with their height y (m): where the two halves' links pass
    each other (they must lie in different planes there), as the SM-55's open pose does."""
    found = []
    for half, j in clamp_joints(x, mech.lower, mech.upper).items():
        side = 1.0 if half == "upper" else -1.0
        for point, name in zip((j.corner, j.elbow), _CROSSING_NAMES[half]):
            if side * float(point[1]) < -AXIS_TOLERANCE:
                found.append((name, float(point[1])))
    return found


def crossing_note(crossings: list[tuple[str, float]]) -> str:
    """Two short lines naming the joints across the axis and how far (empty when none)."""
    if not crossings:
        return ""
    above = ", ".join(name for name, y in crossings if y > 0)
    below = ", ".join(name for name, y in crossings if y < 0)
    sides = "; ".join(part for part in (f"{above} above it" if above else "",
                                         f"{below} below" if below else "") if part)
    furthest = max(abs(y) for _, y in crossings) * MM
    return f"the halves cross the clamp axis (by {furthest:.1f} mm):\n{sides}"


def _draw_half(ax: plt.Axes, half: str, j: HalfJoints) -> None:
    """Links 3-5 (or 6-8) of one half, with seed 000's link numbers and joint letters."""
    def xy(p: tuple) -> tuple[float, float]:
        return float(p[0]) * MM, float(p[1]) * MM

    crank, triangle, rod = LINK_NUMBERS[half]
    ax.add_patch(plt.Polygon([xy(j.pivot), xy(j.corner), xy(j.elbow)], **_TRIANGLE))
    for (a, b), number in (((j.crosshead, j.corner), crank), ((j.elbow, j.platen), rod)):
        ax.plot(*zip(xy(a), xy(b)), **_LINK)
        _label(ax, np.mean([xy(a), xy(b)], axis=0), str(number), half, color="tab:blue")
    centre = np.mean([xy(j.pivot), xy(j.corner), xy(j.elbow)], axis=0)
    _label(ax, centre, str(triangle), half, color="tab:red", offset=0)
    for point, letter in zip((j.pivot, j.elbow, j.platen), JOINT_LETTERS[half]):
        _label(ax, xy(point), letter, half, weight="bold")


def _label(ax: plt.Axes, at: Sequence[float], text: str, half: str, offset: float = 9,
           **style: object) -> None:
    """A label beside a point, away from the clamp axis."""
    dy = offset if half == "upper" else -offset
    ax.annotate(text, tuple(at), xytext=(offset * 0.6, dy), textcoords="offset points",
                ha="center", va="center", fontsize=10, zorder=6, **style)


def _figure_size(limits: tuple[float, float, float, float], panels: int) -> tuple[float, float]:
    """Inches for ``panels`` drawings side by side at the drawing's own aspect ratio."""
    x0, x1, y0, y1 = limits
    width = 5.2
    return width * panels + 0.4, min(width * (y1 - y0) / (x1 - x0), 8.0) + 1.3


def plot_linkage(mech: Mechanism, path: Path, x: float | None = None) -> Path:
    """The clamp at crosshead position ``x`` (m); without it, open, mid-stroke and at the
    toggle side by side (seed 000, Figure 3). PNG."""
    x_open, x_tp = stroke_ends(mech)
    panels = ([("open: ", x_open), ("mid-stroke: ", 0.5 * (x_open + x_tp)), ("toggle: ", x_tp)]
              if x is None else [("", x)])
    limits = _bounds(mech, [*np.linspace(x_open, x_tp, 25), *(xi for _, xi in panels)])
    fig, axes = plt.subplots(1, len(panels), figsize=_figure_size(limits, len(panels)),
                             squeeze=False)
    for ax, (name, xi) in zip(axes[0], panels):
        draw_linkage(ax, mech, xi, limits)
        platen = clamp_joints(xi, mech.lower, mech.upper)["lower"].platen[0]
        note = crossing_note(axis_crossings(mech, xi))
        ax.set_title(f"{name}x = {xi * MM:.2f} mm, L = {float(platen) * MM:.2f} mm"
                     + (f"\n{note}" if note else ""), fontsize=10,
                     color="black" if not note else "darkred")
    fig.suptitle(f"{mech.name}: the double-toggle clamp to scale "
                 "(links 1-9, 9 the moving platen; joints A-F as seed 000)", fontsize=11)
    return save_figure(fig, path)


def animate_linkage(mech: Mechanism, path: Path, frames: int = 40, fps: int = 12) -> Path:
    """A GIF of one closing and opening over the stroke: ``frames`` frames, the crosshead
    moving as 1 - cos (slow at the open position and at the toggle)."""
    x_open, x_tp = stroke_ends(mech)
    phase = 2 * np.pi * np.arange(frames) / frames
    xs = x_open + (x_tp - x_open) * 0.5 * (1 - np.cos(phase))
    limits = _bounds(mech, list(np.linspace(x_open, x_tp, 25)))
    fig, ax = plt.subplots(figsize=_figure_size(limits, 1))

    def frame(i: int) -> list:
        ax.clear()
        draw_linkage(ax, mech, float(xs[i]), limits)
        note = crossing_note(axis_crossings(mech, float(xs[i])))
        ax.set_title(f"{mech.name}: x = {xs[i] * MM:6.2f} mm" + (f"\n{note}" if note else ""),
                     fontsize=10)
        return []

    frame(0)
    fig.tight_layout()
    try:
        movie = animation.FuncAnimation(fig, frame, frames=frames, blit=False)
        with atomic_path(path) as tmp:
            movie.save(tmp, writer=animation.PillowWriter(fps=fps), dpi=80)
    finally:
        plt.close(fig)
    return path
