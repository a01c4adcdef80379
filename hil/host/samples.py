"""What every plant back-end exchanges with the host: trajectories in, samples out.

A back-end (the FMU or the rig) executes a :class:`Trajectory` -- commanded input-link
positions at a fixed period -- and streams one :class:`Sample` per period. Both are in SI
units (s, m, N), independent of the back-end.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import numpy as np

from controllers.profiles import CSV_COLUMNS, ProfileError, read_profile_columns

#: Columns a planned profile CSV must have (the planner writes velocity etc. too).
PROFILE_TIME, PROFILE_POSITION = CSV_COLUMNS[:2]
#: Relative tolerance on the spacing of a profile's time column.
_PERIOD_RTOL = 1e-6


class TrajectoryError(ValueError):
    """A trajectory or profile file that a back-end cannot execute."""


class Status(str, Enum):
    """State of the plant when a sample was taken."""

    OK = "ok"  # executing the trajectory normally
    STOPPING = "stopping"  # a controlled stop is decelerating the input link
    FAULT = "fault"  # a fault is active (force or travel limit, following error, ...)


@dataclass(frozen=True, slots=True)
class Sample:
    """One telemetry sample of a run.

    t: time since the start of the trajectory, s; x_cmd: commanded input-link
    (crosshead) position, m; platen: measured moving-platen position, m, in the
    back-end's frame (the encoder's zero); force: measured input force between
    the drive and the input link, N, positive when the drive pushes; status;
    index: the back-end's sample counter (the MCU's telemetry index on the rig, the
    step number on the FMU), so gaps and repeats are visible in the record.
    """

    t: float
    x_cmd: float
    platen: float
    force: float
    status: Status = Status.OK
    index: int = 0


@dataclass(frozen=True)
class Trajectory:
    """Commanded input positions ``x_cmd`` (m) at times ``time`` (s), spaced by ``period``."""

    time: np.ndarray
    x_cmd: np.ndarray
    period: float

    def __post_init__(self) -> None:
        time = np.asarray(self.time, dtype=float)
        x = np.asarray(self.x_cmd, dtype=float)
        if not (math.isfinite(self.period) and self.period > 0):
            raise TrajectoryError(f"period must be a positive time in s, got {self.period!r}")
        if time.ndim != 1 or time.shape != x.shape or time.size < 2:
            raise TrajectoryError(
                f"time and x_cmd must be 1-D arrays of equal length >= 2, got {time.shape} "
                f"and {x.shape}"
            )
        if not (np.all(np.isfinite(time)) and np.all(np.isfinite(x))):
            raise TrajectoryError("trajectory holds non-finite times or positions")
        if not np.allclose(np.diff(time), self.period, rtol=_PERIOD_RTOL, atol=0.0):
            raise TrajectoryError(f"time is not uniformly spaced at period {self.period} s")
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "x_cmd", x)

    @classmethod
    def from_positions(cls, x_cmd: Sequence[float] | np.ndarray, period: float) -> Trajectory:
        """Positions sampled every ``period`` seconds from t = 0."""
        x = np.asarray(x_cmd, dtype=float)
        return cls(np.arange(x.size) * period, x, period)

    @classmethod
    def from_csv(cls, path: str | Path, period: float | None = None) -> Trajectory:
        """Read a planned profile (:func:`controllers.profiles.read_profile_columns`:
        columns ``time [s]``, ``position [m]``, others ignored).

        Without ``period`` the file's own time step is used and must be uniform;
        with it the profile is linearly resampled at that period. Time is shifted
        to start at zero.
        """
        try:
            data = read_profile_columns(path, (PROFILE_TIME, PROFILE_POSITION))
        except ProfileError as exc:
            raise TrajectoryError(str(exc)) from exc
        t, x = data[:, 0] - data[0, 0], data[:, 1]
        if period is None:
            step = (t[-1] - t[0]) / (t.size - 1)
            # the file's times are printed with finite digits: allow 0.1 % jitter
            if not np.allclose(np.diff(t), step, rtol=1e-3, atol=0.0):
                raise TrajectoryError(
                    f"profile {path} has a non-uniform time step; give a period to resample it"
                )
            return cls.from_positions(x, step)
        n = int(math.floor(t[-1] / period + 1e-9)) + 1
        grid = np.arange(n) * period
        return cls(grid, np.interp(grid, t, x), period)

    def __len__(self) -> int:
        return int(self.time.size)

    @property
    def duration(self) -> float:
        """Time from the first to the last sample, s."""
        return float(self.time[-1] - self.time[0])
