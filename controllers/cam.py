"""Cam tables of a plan, as a servo drive or motion controller loads them, and their check
at the drive's interpolation cycle.

A drive runs a cam as a table of points that it interpolates at every cycle of its
position loop (125 us on a typical servo drive). The master is time (s) or a virtual
master axis turning once per profile (degrees, 0 to 360 at constant speed: the PLCopen
MC_CamIn master); the slave is the crosshead's travel from the open position in SI (m),
in motor revolutions (R lead per turn, :mod:`toggle.drive`) or in encoder counts
(``pulses_per_rev`` per turn). Each point carries the slave's position, velocity and
acceleration over the master (per s or per degree), as the formats that take them need.

How the drive interpolates is the format's (:data:`INTERPOLATIONS`): ``linear`` and
``cubic`` (a spline through the positions) for plain position tables, ``pv-cubic``
(cubic Hermite through position and velocity: a PVT table) and ``pva-quintic`` (the
fifth-order polynomial through position, velocity and acceleration at both ends of each
segment: CODESYS SoftMotion's XYVA cams). :func:`drive_samples` interpolates a table so
and samples it every drive cycle; :func:`check_table` runs the samples through the plant
(:func:`toggle.plant.plant_outputs`, the planner's and the FMU's model) and gives
velocity, acceleration, motor torque and input force against the plan's limits: what
the drive will really command. A table is checked at the drive cycle it is made for and
at the two common position-loop cycles, 100 us and 125 us (:data:`CHECKED_CYCLES`): a
linear table made for one of them alone does not hold at the other (the 125 us table at
100 us reached 1.26 times the acceleration limit, the 100 us table at 125 us 1.10 times),
and a PLC user moving a drive between them should not need another table.
:func:`points_needed` finds the fewest points that keep them within 1 % at every one of
those cycles. The files are :mod:`controllers.cam_formats`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from controllers.limits import DriveLimits
from controllers.profiles import Profile, sample_times
from toggle.params import Drive, ParameterError
from toggle.plant import PlantConfig, plant_outputs

MASTERS = ("time", "position")
UNITS = ("si", "motor", "counts")
INTERPOLATIONS = ("linear", "cubic", "pv-cubic", "pva-quintic")
#: The end conditions of the ``cubic`` spline through the positions: its first derivative
#: at both ends is the table's end velocity (the plan's: a stroke starts and ends at rest).
#: scipy's default, not-a-knot, puts the chang2021 table 4.5 % of the peak velocity off the
#: plan, clamped 0.83 %.
END_CONDITIONS = "clamped to the end velocities (first derivative given at both ends)"
#: The unit of the master and of the slave as written, by master / units.
MASTER_UNIT = {"time": "s", "position": "deg"}
SLAVE_UNIT = {"si": "m", "motor": "rev", "counts": "counts"}
#: The drive's interpolation cycle the tables are checked at by default, s.
DRIVE_CYCLE = 125e-6
#: The cycles every table is checked at besides its own, s: the common position loops.
CHECKED_CYCLES = (100e-6, 125e-6)
#: The fewest points are found by trying every count from 2 up to the first that passes
#: (exact: the check is not monotonic in the count) while the search's first bracket is
#: at most this; a larger table (linear ones need a point about every drive cycle) is found
#: by bisection of the bracket, the least passing count of it: one point fewer breaks.
SCAN_POINTS = 1000
#: The drive cycles accepted, s: position loops and fieldbus cycles of servo drives (the
#: check's cost grows as the stroke time over the cycle).
CYCLES = (50e-6, 10e-3)
#: A table keeps the plan when every ratio is at most this.
TOLERANCE = 1.01
MAX_POINTS = 100_000
#: A table follows the plan when its position and velocity errors are at most this.
FOLLOWING = 0.01
ERRORS = ("position_error", "velocity_error")
RATIOS = ("velocity", "acceleration", "motor_torque", "peak_force")


@dataclass(frozen=True)
class CamTable:
    """Master and slave positions with the slave's velocity and acceleration over the
    master (in ``kind``'s and ``units``' units: per s or per degree), the profile's
    duration (s), the crosshead's open position (m) and the drive that converts;
    ``whole`` when the slave and its velocity are whole numbers (encoder counts)."""

    master: np.ndarray
    slave: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    kind: str  # master: time or position
    units: str
    duration: float
    x_open: float
    drive: Drive = field(repr=False)
    whole: bool = False

    @property
    def per_second(self) -> float:
        """Master units per second (1 for time, 360 / duration for the virtual axis)."""
        return 360.0 / self.duration if self.kind == "position" else 1.0

    @property
    def per_metre(self) -> float:
        """Slave units per metre of crosshead travel."""
        return per_metre(self.units, self.drive)

    def knots_si(self) -> tuple[np.ndarray, ...]:
        """The points as time (s), crosshead position (m), velocity and acceleration (SI)."""
        k, s = self.per_second, self.per_metre
        return (self.master / k, self.x_open + self.slave / s, self.velocity * k / s,
                self.acceleration * k * k / s)


def per_metre(units: str, drive: Drive) -> float:
    """Slave units per metre of crosshead travel."""
    turn = drive.ratio * drive.lead  # crosshead travel per motor turn, m
    return {"si": 1.0, "motor": 1.0 / turn, "counts": drive.pulses_per_rev / turn}[units]


def choice(name: str, value: str, allowed: tuple[str, ...]) -> None:
    """Refuse ``value`` outside ``allowed`` in one line."""
    if value not in allowed:
        raise ParameterError(f"cam {name} must be one of {', '.join(allowed)}, got {value!r}")


def cam_table(profile: Profile, drive: Drive, points: int, *, master: str = "time",
              units: str = "si", whole: bool = False) -> CamTable:
    """The profile as a cam table of ``points`` equally spaced master positions, the
    slave's travel from the profile's start; ``whole`` rounds the slave and its velocity
    to whole units (a drive table in integer encoder counts)."""
    choice("master", master, MASTERS)
    choice("units", units, UNITS)
    if not (isinstance(points, int) and 2 <= points <= MAX_POINTS):
        raise ParameterError(f"cam points must be an integer 2 to {MAX_POINTS}, got {points!r}")
    t = np.linspace(0.0, profile.duration, points)
    x, v, a = profile.sample(t)
    k = 360.0 / profile.duration if master == "position" else 1.0
    s = per_metre(units, drive)
    slave, velocity = (x - x[0]) * s, v * s / k
    if whole:
        slave, velocity = np.rint(slave), np.rint(velocity)
    return CamTable(t * k, slave, velocity, a * s / k**2, master, units, profile.duration,
                    float(x[0]), drive, whole)


def drive_samples(table: CamTable, interpolation: str, cycle: float = DRIVE_CYCLE
                  ) -> tuple[np.ndarray, ...]:
    """The crosshead motion the drive commands from the table: interpolated as
    ``interpolation`` says and sampled every ``cycle`` s; velocity and acceleration as
    the drive's position setpoints give them (central first and second differences over
    the cycle: what its feed-forward and its following error see). Time, position,
    velocity, acceleration, SI."""
    # imported here: a tenth of a second of every `toggle plan`, needed only by an export
    from scipy.interpolate import BPoly, CubicHermiteSpline, CubicSpline, PPoly

    choice("interpolation", interpolation, INTERPOLATIONS)
    if not (math.isfinite(cycle) and CYCLES[0] <= cycle <= CYCLES[1]):
        raise ParameterError(f"drive cycle must be 50 us to 10 ms, got {cycle!r} s")
    t_k, x_k, v_k, a_k = table.knots_si()
    t = sample_times(table.duration, cycle)
    if interpolation == "linear":
        x = np.interp(t, t_k, x_k)
    elif interpolation == "cubic":  # clamped to the table's end velocities (END_CONDITIONS)
        x = CubicSpline(t_k, x_k, bc_type=((1, v_k[0]), (1, v_k[-1])))(t)
    elif interpolation == "pv-cubic":
        x = CubicHermiteSpline(t_k, x_k, v_k)(t)
    else:
        quintic = BPoly.from_derivatives(t_k, np.column_stack([x_k, v_k, a_k]))
        x = PPoly.from_bernstein_basis(quintic)(t)  # the same polynomials, 20x faster
    h = t[1] - t[0]
    v = np.gradient(x, h)
    a = np.empty_like(x)
    a[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / h**2
    a[0], a[-1] = a[1], a[-2]
    return t, x, v, a


def check_table(table: CamTable, interpolation: str, cfg: PlantConfig, limits: DriveLimits,
                planned_peak: float, cycle: float = DRIVE_CYCLE, *,
                profile: Profile | None = None, plant: bool = True) -> dict[str, float]:
    """The table as the drive interpolates it at ``cycle``, through the plant: the
    largest velocity, acceleration and motor torque over their limits and the peak input
    force over the plan's (each at most :data:`TOLERANCE` for a table that keeps the plan
    within 1 %); with the plan's ``profile``, how far the motion strays from it: the
    largest position error over the stroke and velocity error over the plan's peak
    velocity (each at most :data:`FOLLOWING`). ``plant=False``: no force nor torque."""
    t, x, v, a = drive_samples(table, interpolation, cycle)
    ratios = {"velocity": float(np.max(np.abs(v))) / limits.velocity,
              "acceleration": float(np.max(np.abs(a))) / limits.acceleration}
    if profile is not None:
        x_plan, v_plan, _ = profile.sample(t)
        ratios.update(
            position_error=float(np.max(np.abs(x - x_plan)) / abs(x_plan[-1] - x_plan[0])),
            velocity_error=float(np.max(np.abs(v - v_plan)) / np.max(np.abs(v_plan))))
    if plant:
        force = np.asarray(plant_outputs(x, v, a, cfg).input_force, float)
        peak = float(np.max(np.abs(force)))
        ratios.update(motor_torque=limits.torque_ratio(table.drive, v, a, force),
                      peak_force=peak / planned_peak, peak_force_newton=peak)
    return ratios


def checked_cycles(cycle: float) -> tuple[float, ...]:
    """The cycles a table made for ``cycle`` is checked at: it and :data:`CHECKED_CYCLES`."""
    return tuple(sorted({cycle, *CHECKED_CYCLES}))


def check_cycles(table: CamTable, interpolation: str, cfg: PlantConfig,
                 limits: DriveLimits, planned_peak: float, cycles: tuple[float, ...], *,
                 profile: Profile | None = None, plant: bool = True) -> dict[str, float]:
    """:func:`check_table` at each of ``cycles``, each figure the worst of them."""
    checks = [check_table(table, interpolation, cfg, limits, planned_peak, c,
                          profile=profile, plant=plant) for c in cycles]
    return {name: max(c[name] for c in checks) for name in checks[0]}


def keeps(check: dict[str, float]) -> bool:
    """Whether a check keeps every limit within 1 % and follows the plan within 1 % (of
    the ratios it has)."""
    return (all(check[name] <= TOLERANCE for name in RATIOS if name in check)
            and all(check[name] <= FOLLOWING for name in ERRORS if name in check))


def points_needed(build: Callable[[int], CamTable], interpolation: str, cfg: PlantConfig,
                  limits: DriveLimits, planned_peak: float, profile: Profile,
                  cycle: float = DRIVE_CYCLE) -> tuple[int, dict[str, float]] | None:
    """The fewest points, and their check (the worst over :func:`checked_cycles`), for
    which ``build(points)``'s table keeps the plan at ``cycle``, 100 us and 125 us and
    follows ``profile``; None if no count up to :data:`MAX_POINTS` does (a table in whole
    counts whose rounding alone breaks a limit). The kinematics decide first, the plant
    confirms. The check is not monotonic in the count (knots beat against the cycle, whole
    counts round), so the counts are grown by a quarter to a first bracket and, if it is
    at most :data:`SCAN_POINTS`, every count from 2 up is tried: the first that passes is
    the fewest. Above, the bracket is bisected: the least passing count found, one point
    fewer breaking the plan."""
    cycles = checked_cycles(cycle)
    checks: dict[int, dict[str, float]] = {}

    def kinematic(n: int) -> bool:
        return keeps(check_cycles(build(n), interpolation, cfg, limits, planned_peak, cycles,
                                  profile=profile, plant=False))

    def full(n: int) -> bool:
        if n not in checks:
            checks[n] = check_cycles(build(n), interpolation, cfg, limits, planned_peak,
                                     cycles, profile=profile)
        return keeps(checks[n])

    def grow(k: int) -> int:
        return max(k + 1, math.ceil(k * 1.25))

    def passes(n: int) -> bool:
        return kinematic(n) and full(n)

    below, n = _first_passing(kinematic, 1, 2, grow)
    if n is None:
        return None
    if n <= SCAN_POINTS:
        found = next((k for k in range(2, SCAN_POINTS + 1) if passes(k)), None)
        if found is not None:
            return found, checks[found]
        below, n = SCAN_POINTS, grow(SCAN_POINTS)  # none does: grow on with the plant
    else:
        n = _bisect(kinematic, below, n)
    if not full(n):
        below, n = _first_passing(full, n, grow(n), grow)
        if n is None:
            return None
        n = _bisect(full, below, n)
    return n, checks[n]  # full(n) passed: in the first test or the bisection


def _first_passing(ok: Callable[[int], bool], below: int, n: int,
                   grow: Callable[[int], int]) -> tuple[int, int | None]:
    """The first count from ``n`` on (grown by ``grow``) that passes, with the last that
    failed before it; (last, None) if none up to :data:`MAX_POINTS` does."""
    while not ok(n):
        if n >= MAX_POINTS:
            return n, None
        below, n = n, min(MAX_POINTS, grow(n))
    return below, n


def _bisect(ok: Callable[[int], bool], below: int, n: int) -> int:
    """The least passing count in (below, n], ``below`` failing and ``n`` passing."""
    while n - below > 1:
        middle = (below + n) // 2
        below, n = (below, middle) if ok(middle) else (middle, n)
    return n


_SECONDS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}


def parse_cycle(text: str) -> float:
    """A drive cycle such as ``125us``, ``0.5ms`` or ``1e-4`` (s), in s (:data:`CYCLES`)."""
    number = text.strip().lower()
    unit = next((u for u in ("ms", "us", "µs", "s") if number.endswith(u)), "s")
    try:
        value = float(number.removesuffix(unit)) * _SECONDS[unit]
    except ValueError:
        raise ParameterError(f"drive cycle must be a time such as 125us, 1ms or 1e-4 "
                             f"(s), got {text!r}") from None
    if not (math.isfinite(value) and CYCLES[0] <= value <= CYCLES[1]):
        raise ParameterError(f"drive cycle must be 50 us to 10 ms, got {text!r}")
    return value


def over_limits(check: dict[str, float]) -> list[str]:
    """What a table that keeps the plan still puts above a limit (a ratio over 1, within
    :data:`TOLERANCE`), each in % of it: a drive that enforces that limit exactly trips."""
    return [f"{name.replace('_', ' ')} {100 * check[name]:.2f} %"
            for name in RATIOS if name in check and 1.0 < check[name] <= TOLERANCE]


def breaches(check: dict[str, float]) -> list[str]:
    """What a check breaks, each with its figure in % (of its limit, of the plan's peak
    force, of the stroke, of the plan's peak velocity); empty: it keeps the plan."""
    return ([f"{name.replace('_', ' ')} {100 * check[name]:.1f} %"
             for name in RATIOS if name in check and check[name] > TOLERANCE]
            + [f"{name.replace('_', ' ')} {100 * check[name]:.2f} %"
               for name in ERRORS if name in check and check[name] > FOLLOWING])
