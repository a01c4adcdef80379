"""The reciprocating experiment of Chang, Lee & Hsu 2021, section 5, and its cycle segmentation.

The input link is driven forward from the open position x_open (link 3 horizontal)
to the toggle x_TP and back, N times, at a speed v. Each stroke is the planner's
jerk-limited S-curve (:func:`controllers.profiles.stroke_at_speed`) cruising at v,
sampled every period, with the acceleration and jerk limits of the preset's drive
(:func:`controllers.limits.drive_limits`, the limits the planner and its baselines obey).
The strokes join at rest, without dwell.

A recorded stream is cut into cycles by the commanded position alone, so the same
segmentation serves every back-end and a re-read CSV.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.limits import DriveLimits, drive_limits
from controllers.profiles import ProfileError, stroke_at_speed
from hil.host.samples import Trajectory, TrajectoryError
from toggle.elastics import clamp_stroke
from toggle.params import Mechanism

DEFAULT_PERIOD = 1e-3  # s
#: Band around x_open / x_TP (m) within which the commanded position counts as "at the end".
DEFAULT_END_TOL = 1e-6


def stroke_positions(start: float, end: float, speed: float, period: float,
                     limits: DriveLimits, jerk: float | None = None) -> np.ndarray:
    """Positions of one S-curve move from ``start`` to ``end`` every ``period`` s, cruising
    at ``speed`` under the acceleration and jerk of ``limits`` (``jerk`` overrides the
    latter; inf gives the trapezoidal velocity profile).

    The first sample is ``start``; the last is exactly ``end`` (the move's duration
    is rounded up to a whole number of periods).
    """
    if not (math.isfinite(period) and period > 0):
        raise TrajectoryError(f"period must be positive, got {period!r}")
    try:
        move = stroke_at_speed(start, end, speed, limits.acceleration,
                               limits.jerk if jerk is None else jerk)
    except ProfileError as exc:
        raise TrajectoryError(str(exc)) from exc
    t = np.arange(math.ceil(move.duration / period - 1e-9) + 1) * period
    x = move.sample(t)[0]
    x[-1] = end  # the move is over by then; avoid start + (end - start) roundoff
    return x


def _repeat_cycles(forward: np.ndarray, backward: np.ndarray, cycles: int,
                   period: float) -> Trajectory:
    """forward, backward, forward, ... sharing their end samples, as one trajectory."""
    if not (isinstance(cycles, int) and cycles >= 1):
        raise TrajectoryError(f"cycles must be a positive integer, got {cycles!r}")
    one = np.concatenate([forward[:-1], backward[:-1]])
    x = np.concatenate([np.tile(one, cycles), backward[-1:]])
    return Trajectory.from_positions(x, period)


def reciprocating_trajectory(
    mech: Mechanism, speed: float, cycles: int, period: float = DEFAULT_PERIOD, *,
    limits: DriveLimits | None = None, jerk: float | None = None,
) -> Trajectory:
    """Seed 000's experiment: x_open -> x_TP -> x_open, ``cycles`` times, at ``speed`` m/s,
    under ``limits`` (default: the preset's drive, :func:`controllers.limits.drive_limits`).

    The end positions come from ``mech``'s lower half (and the preset's open position,
    :func:`toggle.elastics.clamp_stroke`), so pass the nominal mechanism (the paper drives
    every Delta r8 between the nominal -3.439 and 51.566 mm).
    """
    x_open, x_tp = clamp_stroke(mech)
    forward = stroke_positions(x_open, x_tp, speed, period,
                               drive_limits(mech) if limits is None else limits, jerk)
    return _repeat_cycles(forward, forward[::-1], cycles, period)


def profile_cycles(forward: Trajectory, cycles: int) -> Trajectory:
    """A planned forward stroke, replayed ``cycles`` times with its time-mirror as the return;
    a whole cycle (``toggle plan --cycle-out``: it ends where it starts, its own opening
    stroke and dwells included) replayed ``cycles`` times as it is."""
    x = forward.x_cmd
    if abs(x[-1] - x[0]) <= DEFAULT_END_TOL < np.ptp(x):
        if not (isinstance(cycles, int) and cycles >= 1):
            raise TrajectoryError(f"cycles must be a positive integer, got {cycles!r}")
        return Trajectory.from_positions(np.concatenate([np.tile(x[:-1], cycles), x[-1:]]),
                                         forward.period)
    return _repeat_cycles(x, x[::-1], cycles, forward.period)


def planned_trajectory(preset: str, period: float = DEFAULT_PERIOD, *,
                       mu: float | None = None, x_contact: float | None = None,
                       errors: dict[str, float] | None = None,
                       masses: dict[str, float] | None = None) -> Trajectory:
    """The default plan for the clamp a run drives: the planner's best minimum-peak stroke
    of the default duration (:meth:`controllers.planner.ClampPlanner.best`) for the preset
    with its friction ``mu``, mold ``x_contact``, dimensional ``errors`` and [dynamics]
    fields ``masses`` (the simulated rig's as built), sampled every ``period`` s."""
    from controllers.planner import default_duration, planner_for
    from controllers.plans import plan_config

    cfg = plan_config(preset, mu=mu, x_contact=x_contact, errors=errors, masses=masses)
    planner = planner_for(cfg, drive_limits(cfg.mechanism))
    plan = planner.best(default_duration(planner))
    t = np.arange(0.0, plan.duration + period / 2, period)
    return Trajectory.from_positions(plan.profile.sample(t)[0], period)


@dataclass(frozen=True)
class Cycle:
    """Sample indices of one complete cycle (all inclusive).

    start: at x_open where the forward stroke begins; toggle: first sample at the
    toggle (the cycle's largest command); reverse: last sample at the toggle, where
    the backward stroke begins; end: first sample back at x_open.
    """

    start: int
    toggle: int
    reverse: int
    end: int

    @property
    def forward(self) -> slice:
        return slice(self.start, self.toggle + 1)

    @property
    def backward(self) -> slice:
        return slice(self.reverse, self.end + 1)


def _end_runs(zone: np.ndarray) -> list[tuple[int, int, int]]:
    """Maximal runs (zone, first, last) of the non-zero zones, merging repeats of one zone."""
    idx = np.flatnonzero(zone)
    runs: list[tuple[int, int, int]] = []
    if idx.size == 0:
        return runs
    z = zone[idx]
    breaks = np.flatnonzero(z[1:] != z[:-1]) + 1
    for lo, hi in zip(np.r_[0, breaks], np.r_[breaks, idx.size]):
        runs.append((int(z[lo]), int(idx[lo]), int(idx[hi - 1])))
    return runs


def segment_cycles(
    x_cmd: np.ndarray, x_open: float, x_toggle: float, tol: float = DEFAULT_END_TOL
) -> list[Cycle]:
    """Complete cycles of a stream, found from its commanded positions.

    A sample is "open" within ``tol`` of x_open (or below) and "toggle" within ``tol``
    of x_toggle (or above); a cycle is an open run, a toggle run and the next open
    run. An unfinished last cycle (an aborted run) is left out.
    """
    x = np.asarray(x_cmd, dtype=float)
    if not x_toggle - x_open > 2 * tol:
        raise ValueError(f"x_toggle {x_toggle} m must exceed x_open {x_open} m by more than 2 tol")
    zone = np.where(x <= x_open + tol, -1, np.where(x >= x_toggle - tol, 1, 0))
    runs = _end_runs(zone)
    cycles = []
    for (za, a0, a1), (zb, b0, b1), (zc, c0, c1) in zip(runs, runs[1:], runs[2:]):
        if (za, zb, zc) != (-1, 1, -1):
            continue
        a, b, c = x[a0:a1 + 1], x[b0:b1 + 1], x[c0:c1 + 1]
        cycles.append(Cycle(
            start=a0 + int(np.flatnonzero(a == a.min())[-1]),
            toggle=b0 + int(np.argmax(b)),
            reverse=b0 + int(np.flatnonzero(b == b.max())[-1]),
            end=c0 + int(np.argmin(c)),
        ))
    return cycles


class CycleCounter:
    """Counts completed cycles while samples arrive (for a progress bar)."""

    def __init__(self, x_open: float, x_toggle: float, tol: float = DEFAULT_END_TOL) -> None:
        self._open, self._toggle, self._tol = x_open + tol, x_toggle - tol, tol
        self._reached_toggle = False
        self.completed = 0

    def update(self, x_cmd: float) -> bool:
        """Feed one commanded position; True when it completes a cycle."""
        if x_cmd >= self._toggle:
            self._reached_toggle = True
        elif x_cmd <= self._open and self._reached_toggle:
            self._reached_toggle = False
            self.completed += 1
            return True
        return False
