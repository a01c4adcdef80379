"""The sections of a preset besides the link dimensions, typed and checked (SI): the
clamp's pins, member counts, link sections, tie bars and die height, the link cross
sections, the drive and the [dynamics] masses and friction; and the error a preset that
does not describe a valid mechanism raises. :mod:`toggle.params` holds the mechanism
(the halves' dimensions) and reads the preset files into these.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any


class ParameterError(ValueError):
    """A parameter file or value that does not describe a valid mechanism."""


class UnknownPresetError(ParameterError):
    """No shipped preset and no file of that name."""


def _check_positive(obj: Any, optional: tuple[str, ...] = (), skip: tuple[str, ...] = ()
                    ) -> None:
    """Every field of a section but ``skip`` must be a finite positive number (optional ones
    may be None)."""
    for f in fields(obj):
        if f.name in skip:
            continue
        value = getattr(obj, f.name)
        if value is None and f.name in optional:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value > 0
        ):
            raise ParameterError(
                f"{type(obj).__name__}.{f.name} must be a finite positive number, got {value!r}"
            )


@dataclass(frozen=True)
class PinRadii:
    """Pin-joint radii, m (seed 001: joint A as B, joint E as D).

    B joins link 5 (seed 001's link 1) to the triangular link, C is the
    triangular link's pivot on the tailstock platen, D joins the crosshead link.
    """

    B: float
    C: float
    D: float

    def __post_init__(self) -> None:
        _check_positive(self)


@dataclass(frozen=True)
class MemberCounts:
    """Members of the whole clamp (both halves): seed 001's n1..n4."""

    n1: int  # platen-side links (seed 000's links 5 and 8)
    n2: int  # triangular tailstock-side links (4 and 7)
    n3: int  # crosshead links (3 and 6)
    n4: int = 1  # crossheads

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ParameterError(
                    f"member count {f.name} must be a positive integer, got {value!r}"
                )


@dataclass(frozen=True)
class LinkSections:
    """Cross-section areas (m^2) and Young's moduli (Pa) of the platen-side link (1)
    and the triangular link (2), for their axial shortening (Eqs 22-23)."""

    area1: float
    modulus1: float
    area2: float
    modulus2: float

    def __post_init__(self) -> None:
        _check_positive(self)


@dataclass(frozen=True)
class TieBars:
    """The tie bars: count, free length (m), section (m^2), Young's modulus (Pa) (Eq 24)."""

    count: int
    length: float
    area: float
    modulus: float
    #: centre distance of the (square) tie-bar pattern, m; optional (toggle design's
    #: tie-bar clearance and radial envelope use it)
    spacing: float | None = None

    def __post_init__(self) -> None:
        _check_positive(self, optional=("spacing",))

    @property
    def stiffness(self) -> float:
        """Total axial stiffness of all tie bars, N/m."""
        return self.count * self.area * self.modulus / self.length


@dataclass(frozen=True)
class DieHeight:
    """The tailstock's die-height (mold thickness) adjustment, m: the thinnest and thickest
    mold the machine takes, and the mold height at which the tie bars' free length
    ([clamp.tiebars] length) holds. The tailstock moves along the bars with the mold, so
    the bars' span between their nuts grows with it mm for mm."""

    min: float
    max: float
    reference: float

    def __post_init__(self) -> None:
        _check_positive(self)
        if not self.min < self.max:
            raise ParameterError(f"die height min {self.min!r} m must be below max {self.max!r} m")


@dataclass(frozen=True)
class ClampData:
    """What the real-mold clamping model needs beyond the link lengths.

    final_tiebar_force: total tie-bar force at the final (toggle) position, N;
    mu: kinetic friction coefficient at the pins; static_factor: mu_s / mu_d,
    used once the final position is reached (the paper's 1.25); x_open:
    crosshead position with the clamp open, m, for clamps whose crosshead link
    never becomes horizontal (then the kinematic open position does not exist);
    die_height: the tailstock's adjustment range ([clamp.die_height], optional).
    """

    pins: PinRadii
    counts: MemberCounts
    links: LinkSections
    tiebars: TieBars
    final_tiebar_force: float
    mu: float = 0.0
    static_factor: float = 1.25
    x_open: float | None = None
    die_height: DieHeight | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.final_tiebar_force) and self.final_tiebar_force > 0):
            raise ParameterError(
                f"final_tiebar_force must be positive, got {self.final_tiebar_force!r} N"
            )
        if not (math.isfinite(self.mu) and self.mu >= 0):
            raise ParameterError(f"friction coefficient mu must be >= 0, got {self.mu!r}")
        if not (math.isfinite(self.static_factor) and self.static_factor >= 1):
            raise ParameterError(
                f"static_factor (mu_s / mu_d) must be >= 1, got {self.static_factor!r}"
            )


@dataclass(frozen=True)
class LinkSection:
    """One member's rectangular section and material (SI): depth in the plane of motion and
    thickness along its pins (m), Young's modulus and yield strength (Pa), density (kg/m^3).
    Read from ``[sections.<link>]`` for toggle design's strength, buckling, pin-pressure and
    mass checks (docs/design.md)."""

    depth: float
    thickness: float
    modulus: float
    yield_strength: float
    density: float

    def __post_init__(self) -> None:
        _check_positive(self)

    @property
    def area(self) -> float:
        return self.depth * self.thickness


@dataclass(frozen=True)
class Sections:
    """Sections of the three kinds of link (one member each; [clamp.counts] gives how many):
    crosshead_link (link 3, r3), triangle (link 4, its arms r4a, r4b, r4c), platen_link
    (link 5, r5)."""

    crosshead_link: LinkSection
    triangle: LinkSection
    platen_link: LinkSection


#: Most points of a drive's torque-speed curve (the planner keeps them as parameters of its
#: compiled problem, padded to this many).
MAX_CURVE_POINTS = 8


@dataclass(frozen=True)
class Drive:
    """Servo motor, belt and ball screw driving the crosshead (Eqs 31-32).

    ratio: R, the velocity ratio of driven to driver gear (motor turns x R =
    screw turns); lead: ball-screw lead, m; efficiency: eta of belt and screw;
    pulses_per_rev: encoder pulses per motor turn (N_s); rated_torque (N m) and
    rated_speed (rad/s) of the motor, when known. rotor_inertia: J_m of the
    motor's rotor (with its pulley), kg m^2; screw_inertia: J_s of the ball
    screw (with its pulley and coupling), kg m^2 (:func:`toggle.drive.reflected_mass`).
    torque_speed: the motor's usable torque against speed, ((speed rad/s, torque N m),
    ...) from speed 0, speeds increasing, torques not increasing, interpolated linearly
    and constant beyond the last point (:func:`toggle.drive.torque_speed_limit`); None:
    the planner's flat default (:mod:`controllers.limits`).

    The motor and its drive as physics (:mod:`controllers.duty`), each optional (None:
    unknown, the figures that need it are not given): back_efficiency: eta' of belt and
    screw while the load back-drives the motor (None: 2 - 1/eta, the ball-screw relation
    of THK's and NSK's catalogues, :func:`toggle.drive.back_efficiency`);
    torque_constant: k_t, N m per A (rms phase current); winding_resistance: R of one
    phase, ohm; phases: the motor's phases (3: AC servo, 2: stepper), copper losses
    phases R (T / k_t)^2; thermal_time_constant: the winding's, s; rated_temperature_rise:
    the winding's rise above ambient at the rated torque, K (its thermal resistance follows
    from the rated torque's copper losses); bus_voltage: the drive's DC bus, V;
    brake_voltage: the bus voltage where its brake chopper (or overvoltage limit) acts, V.
    """

    ratio: float
    lead: float
    efficiency: float
    pulses_per_rev: int
    rated_torque: float | None = None
    rated_speed: float | None = None
    rotor_inertia: float = 0.0
    screw_inertia: float = 0.0
    torque_speed: tuple[tuple[float, float], ...] | None = None
    back_efficiency: float | None = None
    torque_constant: float | None = None
    winding_resistance: float | None = None
    phases: int = 3
    thermal_time_constant: float | None = None
    rated_temperature_rise: float | None = None
    bus_voltage: float | None = None
    brake_voltage: float | None = None

    def __post_init__(self) -> None:
        _check_positive(self, optional=("rated_torque", "rated_speed", "back_efficiency",
                                        "torque_constant", "winding_resistance",
                                        "thermal_time_constant", "rated_temperature_rise",
                                        "bus_voltage", "brake_voltage"),
                        skip=("rotor_inertia", "screw_inertia", "torque_speed"))
        if self.efficiency > 1:
            raise ParameterError(f"drive efficiency must be in (0, 1], got {self.efficiency}")
        if self.back_efficiency is not None and self.back_efficiency > self.efficiency:
            raise ParameterError("drive back_efficiency must be in (0, efficiency]: back-"
                                 f"driving loses at least as much, got {self.back_efficiency}")
        if not (isinstance(self.phases, int) and not isinstance(self.phases, bool)
                and 1 <= self.phases <= 6):
            raise ParameterError(f"drive phases must be an integer 1 to 6, got {self.phases!r}")
        if None not in (self.bus_voltage, self.brake_voltage) and not (
                self.brake_voltage > self.bus_voltage):
            raise ParameterError(f"drive brake_voltage ({self.brake_voltage} V) must be above "
                                 f"bus_voltage ({self.bus_voltage} V)")
        for name in ("rotor_inertia", "screw_inertia"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and value >= 0):
                raise ParameterError(f"{name} must be a finite number >= 0 (kg m^2), "
                                     f"got {value!r}")
        if self.torque_speed is not None:
            object.__setattr__(self, "torque_speed", torque_speed_points(self.torque_speed))


def torque_speed_points(points: Any) -> tuple[tuple[float, float], ...]:
    """A torque-speed curve checked and as a tuple of (speed rad/s, torque N m) pairs: 1 to
    :data:`MAX_CURVE_POINTS` points, the first at speed 0, speeds increasing, torques
    positive and not increasing; otherwise :class:`ParameterError` naming the fault."""
    what = "torque_speed must be a list of [speed rad/s, torque N m] pairs"
    if not isinstance(points, (list, tuple)) or not 1 <= len(points) <= MAX_CURVE_POINTS:
        raise ParameterError(f"{what}, 1 to {MAX_CURVE_POINTS} of them, got {points!r}")
    out = []
    for point in points:
        if not (isinstance(point, (list, tuple)) and len(point) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                for v in point)):
            raise ParameterError(f"{what}; {point!r} is not a pair of finite numbers")
        out.append((float(point[0]), float(point[1])))
    speeds, torques = zip(*out)
    if speeds[0] != 0.0:
        raise ParameterError(f"torque_speed must start at speed 0, got {speeds[0]!r} rad/s")
    if any(b <= a for a, b in zip(speeds, speeds[1:])):
        raise ParameterError(f"torque_speed speeds must increase, got {list(speeds)} rad/s")
    if min(torques) <= 0:
        raise ParameterError(f"torque_speed torques must be > 0, got {list(torques)} N m")
    if any(b > a for a, b in zip(torques, torques[1:])):
        raise ParameterError("torque_speed torques must not rise with speed (a motor's "
                             f"usable torque falls), got {list(torques)} N m")
    return tuple(out)


@dataclass(frozen=True)
class Dynamics:
    """Inertia and guide friction of the dynamic plant (:mod:`toggle.plant`).

    crosshead: the input link with what moves rigidly with it (kg); links:
    all toggle links together, lumped half at the crosshead and half at the
    platen (kg); platen: the moving platen with its mold half (kg);
    guide_damping: viscous friction of the crosshead and platen guides,
    referred to the input link (N s/m); guide_friction: their Coulomb friction
    (and the ball screw's), referred to the input link (N); platen_friction: the
    moving platen's Coulomb friction on its tie-bars, at the platen (N), referred to
    the input by the velocity ratio dL/dx, so it fades to nothing at the toggle;
    platen_rate: its rate strengthening, the friction being platen_friction times
    1 + platen_rate ln(1 + |platen speed| / 1 mm/s) (1).
    """

    crosshead: float
    links: float
    platen: float
    guide_damping: float = 0.0
    guide_friction: float = 0.0
    platen_friction: float = 0.0
    platen_rate: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ParameterError(f"dynamics.{f.name} must be finite and >= 0, got {value!r}")


#: The FMUs' parameter name of each [dynamics] field, with its unit and description: one
#: table for the Python and the native FMU (their parameters, in this order) and the CLI.
DYNAMICS_PARAMETERS: dict[str, tuple[str, str, str]] = {
    "m_crosshead": ("crosshead", "kg", "Crosshead mass"),
    "m_links": ("links", "kg", "Links mass"),
    "m_platen": ("platen", "kg", "Platen mass"),
    "guide_damping": ("guide_damping", "N.s/m",
                      "Viscous guide friction referred to the input link"),
    "guide_friction": ("guide_friction", "N",
                       "Coulomb friction of the crosshead guide and ball screw, at the input"),
    "platen_friction": ("platen_friction", "N",
                        "Coulomb friction of the moving platen on the tie-bars, at the platen"),
    "platen_rate": ("platen_rate", "1", "Rate strengthening of the platen friction: "
                    "x (1 + platen_rate ln(1 + platen speed / 1 mm/s))"),
}


def dynamics_fields(parameters: Mapping[str, Any]) -> dict[str, Any]:
    """[dynamics] fields from values named as the FMUs name their parameters (the names
    :data:`DYNAMICS_PARAMETERS` does not list are ignored)."""
    return {field: parameters[name] for name, (field, _, _) in DYNAMICS_PARAMETERS.items()
            if name in parameters}


def dynamics_parameters(dynamics: Mapping[str, Any]) -> dict[str, Any]:
    """The FMUs' parameters from [dynamics] fields: the inverse of :func:`dynamics_fields`."""
    return {name: dynamics[field] for name, (field, _, _) in DYNAMICS_PARAMETERS.items()
            if field in dynamics}
