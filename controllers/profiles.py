"""Motion profiles of the crosshead: piecewise-constant jerk, baselines, CSV.

A :class:`Profile` is a chain of segments of constant jerk (the planner's
exact discretisation; an acceleration jump at a segment start also serves
the trapezoidal velocity profile). :func:`s_curve` gives the two baselines
the planner is measured against: the trapezoidal velocity profile (jerk
unlimited) and the jerk-limited S-curve, each stretched to a given duration;
:func:`stroke_at_speed` the same S-curve at a given cruise speed, the HIL
experiment's strokes (one S-curve generator for both).
:func:`predict` samples a profile through the plant (the FMU's model) and
:func:`write_profile_csv` writes what the HIL layer executes.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from toggle.params import tomllib
from toggle.plant import PlantConfig, plant_outputs
from toggle.roots import brentq

#: The CSV columns, units in the header (``hil run --profile`` reads time and position).
CSV_COLUMNS = ("time [s]", "position [m]", "velocity [m/s]", "acceleration [m/s^2]",
               "input_force [N]", "platen_position [m]")


class ProfileError(ValueError):
    """A profile that cannot be built or read (message names the reason)."""


@dataclass(frozen=True)
class Profile:
    """Piecewise-constant-jerk motion: segment k starts at ``knots[k]`` in state
    (x[k], v[k], a[k]) and runs with jerk ``jerk[k]`` until ``knots[k + 1]`` (SI)."""

    knots: np.ndarray
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    jerk: np.ndarray

    @classmethod
    def build(cls, x0: float, durations: np.ndarray, jerk: np.ndarray,
              accel: np.ndarray | None = None) -> Profile:
        """Integrate from rest at x0; ``accel`` sets each segment's starting
        acceleration (jumps), else the acceleration is continuous from zero."""
        d, j = np.asarray(durations, float), np.asarray(jerk, float)
        x, v, a = np.empty(d.size), np.empty(d.size), np.empty(d.size)
        state = (x0, 0.0, 0.0)
        for k in range(d.size):
            a0 = state[2] if accel is None else float(accel[k])
            x[k], v[k], a[k] = state[0], state[1], a0
            state = _advance(state[0], state[1], a0, j[k], d[k])
        return cls(np.concatenate(([0.0], np.cumsum(d))), x, v, a, j)

    @property
    def duration(self) -> float:
        return float(self.knots[-1])

    def reversed(self) -> Profile:
        """The same motion run backwards in time (x(T - t)): velocity and jerk change sign."""
        x, v, a = _advance(self.x, self.v, self.a, self.jerk, np.diff(self.knots))
        return Profile(self.duration - self.knots[::-1], x[::-1], -v[::-1], a[::-1],
                       -self.jerk[::-1])

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at times t (clipped to the profile)."""
        t = np.clip(np.asarray(t, float), 0.0, self.duration)
        k = np.clip(np.searchsorted(self.knots, t, side="right") - 1, 0, self.jerk.size - 1)
        return _advance(self.x[k], self.v[k], self.a[k], self.jerk[k], t - self.knots[k])


def _advance(x, v, a, j, dt):
    """Exact state after dt at constant jerk j."""
    return (x + dt * (v + dt * (a / 2 + dt * j / 6)), v + dt * (a + dt * j / 2), a + dt * j)


def ramp_time(v: float, a_max: float, j_max: float) -> float:
    """Time from rest to speed v (or from v to rest) at full acceleration and jerk, s."""
    if math.isinf(j_max):
        return v / a_max
    if v >= a_max * a_max / j_max:
        return v / a_max + a_max / j_max
    return 2.0 * math.sqrt(v / j_max)


def _accel_segments(v: float, a_max: float, j_max: float) -> tuple[list, list]:
    """(durations, jerks) of the ramp from rest to v (one segment if jerk is unlimited)."""
    if math.isinf(j_max):
        return [v / a_max], [0.0]
    t_j = min(a_max / j_max, math.sqrt(v / j_max))
    t_flat = max(v / (j_max * t_j) - t_j, 0.0)
    return [t_j, t_flat, t_j], [j_max, 0.0, -j_max]


def _top_speed(S: float, v_max: float, a_max: float, j_max: float) -> float:
    """Highest cruise speed a rest-to-rest stroke S can reach under the limits."""
    def cruise(v: float) -> float:  # distance left for cruising at speed v
        return S - v * ramp_time(v, a_max, j_max)

    return v_max if cruise(v_max) >= 0 else brentq(cruise, 1e-12 * v_max, v_max, xtol=1e-15)


def minimum_time(S: float, v_max: float, a_max: float, j_max: float = math.inf) -> float:
    """Shortest rest-to-rest time for stroke S under velocity, acceleration and jerk limits
    (the S-curve at full limits is time-optimal for the triple integrator)."""
    v = _top_speed(S, v_max, a_max, j_max)
    return S / v + ramp_time(v, a_max, j_max)


def _move(x_start: float, x_end: float, v: float, a_max: float, j_max: float) -> Profile:
    """Rest-to-rest move cruising at ``v`` (which the stroke can reach): full acceleration
    and jerk on the ramps, the mirrored ramp down, a zero-length rest segment at the end."""
    S, sign = abs(x_end - x_start), math.copysign(1.0, x_end - x_start)
    d, j = _accel_segments(v, a_max, j_max)
    durations = np.array([*d, max(S / v - ramp_time(v, a_max, j_max), 0.0), *d[::-1], 0.0])
    jerks = sign * np.array([*j, 0.0, *(-np.array(j)), 0.0])
    accel = sign * np.array([a_max, 0.0, -a_max, 0.0]) if math.isinf(j_max) else None
    return Profile.build(x_start, durations, jerks, accel)


def _check_limits(v_max: float, a_max: float, j_max: float) -> None:
    for name, value in (("speed", v_max), ("acceleration", a_max), ("jerk", j_max)):
        if not (value > 0 and not math.isnan(value)) or (name != "jerk" and math.isinf(value)):
            raise ProfileError(f"{name} limit must be a positive number, got {value!r}")


def s_curve(x_start: float, x_end: float, duration: float, v_max: float, a_max: float,
            j_max: float = math.inf) -> Profile:
    """Rest-to-rest S-curve (trapezoidal velocity if ``j_max`` is inf) taking
    exactly ``duration``: full acceleration and jerk, the cruise speed lowered
    until the stroke takes that long. Raises :class:`ProfileError` if the
    limits cannot cover the stroke in that time."""
    _check_limits(v_max, a_max, j_max)
    S = abs(x_end - x_start)
    if not (S > 0 and duration > 0):
        raise ProfileError(f"need a stroke and a positive duration, got {S!r} m in {duration!r} s")
    v_top = _top_speed(S, v_max, a_max, j_max)
    t_min = minimum_time(S, v_max, a_max, j_max)
    if duration < t_min * (1 - 1e-12):
        raise ProfileError(
            f"the stroke of {S * 1e3:.4g} mm needs at least {t_min:.4g} s with these limits "
            f"(v {v_max:.4g} m/s, a {a_max:.4g} m/s^2, j {j_max:.4g} m/s^3)"
        )
    v = v_top if duration <= t_min else brentq(
        lambda u: S / u + ramp_time(u, a_max, j_max) - duration, 0.5 * S / duration, v_top,
        xtol=1e-14)
    return _move(x_start, x_end, v, a_max, j_max)


def stroke_at_speed(x_start: float, x_end: float, speed: float, a_max: float,
                    j_max: float = math.inf) -> Profile:
    """The fastest rest-to-rest S-curve from ``x_start`` to ``x_end`` (either direction)
    cruising at ``speed`` m/s, or at the highest speed the stroke reaches under the
    acceleration and jerk limits when it is too short to cruise (seed 000's constant-speed
    strokes, the rig's moves to the start)."""
    _check_limits(speed, a_max, j_max)
    S = abs(x_end - x_start)
    if not S > 0:
        raise ProfileError("a stroke needs distinct start and end positions")
    return _move(x_start, x_end, _top_speed(S, speed, a_max, j_max), a_max, j_max)


class ProfileSamples(NamedTuple):
    """A profile sampled in time with the plant's prediction (SI; the CSV's columns)."""

    time: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    input_force: np.ndarray
    platen_position: np.ndarray

    @property
    def peak_force(self) -> float:
        return float(np.max(np.abs(self.input_force)))

    @property
    def rms_force(self) -> float:
        """Root mean square of the input force over the duration (trapezoidal rule), N."""
        t, f2 = self.time, self.input_force ** 2
        return float(math.sqrt(np.sum(np.diff(t) * (f2[1:] + f2[:-1]) / 2) / (t[-1] - t[0])))


def sample_times(duration: float, period: float) -> np.ndarray:
    """Uniform times from 0 to ``duration`` inclusive, spaced by at most ``period``."""
    return np.linspace(0.0, duration, max(1, math.ceil(duration / period - 1e-9)) + 1)


def predict(profile: Profile, cfg: PlantConfig, period: float = 1e-3) -> ProfileSamples:
    """Sample the profile every ``period`` and evaluate the plant on it."""
    t = sample_times(profile.duration, period)
    x, v, a = profile.sample(t)
    out = plant_outputs(x, v, a, cfg)
    return ProfileSamples(t, x, v, a, np.asarray(out.input_force, float),
                          np.asarray(out.platen_position, float) * np.ones_like(t))


def write_profile_csv(path: str | Path, samples: ProfileSamples,
                      settings: dict[str, str | float | None] | None = None) -> Path:
    """Write the samples with the units in the header (:data:`CSV_COLUMNS`).

    ``settings`` (SI) go first as ``# key = value`` lines (TOML values; None is left
    out): what the plan was made for, so a replay (``hil run --profile``) clamps the
    same mold with the same friction (:func:`read_profile_settings` reads them).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as fh:
        for key, value in (settings or {}).items():
            if value is not None:
                fh.write(f"# {key} = {json.dumps(value)}\n")
        writer = csv.writer(fh)
        writer.writerow(CSV_COLUMNS)
        writer.writerows([f"{value:.12g}" for value in row] for row in zip(*samples))
    return path


def _read(path: Path) -> str:
    """A profile's text; ProfileError in words (no such file, a folder, not UTF-8 with its
    line and column: :func:`toggle.files.read_text`)."""
    from toggle.files import InputError, read_text

    try:
        return read_text(path, "profile")
    except InputError as exc:
        raise ProfileError(str(exc)) from None


def read_profile_columns(path: str | Path, columns: tuple[str, ...] = CSV_COLUMNS
                         ) -> np.ndarray:
    """The named columns (header text with units, :data:`CSV_COLUMNS`) of a profile CSV as
    an array of rows; other columns and the leading ``# key = value`` lines are skipped.
    The time column (first of :data:`CSV_COLUMNS`) must increase over at least two rows."""
    path = Path(path)
    text = _read(path)
    numbered = [(number, ln) for number, ln in enumerate(text.splitlines(), 1)
                if ln.strip() and not ln.lstrip().startswith("#")]
    lines = [ln for _, ln in numbered]
    if not lines:
        raise ProfileError(f"profile {path} is empty")
    header = [h.strip() for h in next(csv.reader(lines[:1]))]
    missing = [c for c in columns if c not in header]
    if missing:
        raise ProfileError(f"profile {path} lacks the column(s) {', '.join(missing)}; its "
                           f"header is: {', '.join(header)}")
    data = np.empty((len(lines) - 1, len(columns)))
    at = [header.index(c) for c in columns]
    for row, fields in enumerate(csv.reader(lines[1:])):
        try:
            data[row] = [float(fields[i]) for i in at]
        except (ValueError, IndexError):
            raise ProfileError(f"profile {path}, line {numbered[row + 1][0]}: expected "
                               f"{len(header)} numbers ({', '.join(header)}), got "
                               f"{','.join(fields)!r}") from None
    if not np.all(np.isfinite(data)):
        raise ProfileError(f"profile {path} holds non-finite numbers")
    time = data[:, columns.index(CSV_COLUMNS[0])] if CSV_COLUMNS[0] in columns else None
    if data.shape[0] < 2 or (time is not None and np.any(np.diff(time) <= 0)):
        raise ProfileError(f"profile {path}: need >= 2 rows with increasing time")
    return data


#: How far before the time its header states a plan's samples may end, s (two periods of
#: the 1 ms sampling).
TRUNCATION_SLACK = 2e-3


def truncation(settings: dict[str, Any], end: float, slack: float = TRUNCATION_SLACK
               ) -> str | None:
    """Why samples ending at ``end`` (s) are a plan cut short, or None: its header's
    ``cycle_time`` (a molding cycle) or else ``duration`` (a stroke) says it lasts longer."""
    for key in ("cycle_time", "duration"):
        said = settings.get(key)
        if isinstance(said, (int, float)) and math.isfinite(said):
            if end < said - slack:
                return (f"truncated: its samples end at {end:.4g} s, its header says {key} = "
                        f"{said:.4g} s")
            return None
    return None


def read_profile_csv(path: str | Path) -> ProfileSamples:
    """Read a CSV written by :func:`write_profile_csv` (all columns required); a file that
    ends before its header's time is refused (:func:`truncation`)."""
    samples = ProfileSamples(*read_profile_columns(path).T)
    cut = truncation(read_profile_settings(path), float(samples.time[-1]))
    if cut is not None:
        raise ProfileError(f"profile {path}: {cut}")
    return samples


def read_profile_settings(path: str | Path) -> dict[str, Any]:
    """The settings a planned profile was made with: its leading ``# key = value`` lines
    (TOML values, SI units) as :func:`write_profile_csv` writes them; {} for a bare CSV."""
    path = Path(path)
    head = list(itertools.takewhile(lambda ln: ln.lstrip().startswith("#"),
                                    _read(path).splitlines()))
    text = "\n".join(ln.lstrip()[1:].strip() for ln in head)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"profile {path}: bad settings line ({exc})") from exc
