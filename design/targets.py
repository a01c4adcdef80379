"""What a designer asks for: the targets file of ``toggle design`` (TOML, SI units).

A targets file names a base preset (its clamp data, drive, motor and masses are kept; only
the linkage changes), the targets every design must meet (constraints), the objectives
to trade against each other, and the bounds of the design variables::

    preset = "lin2003_sm55"        # a shipped preset, or a TOML file (relative to this one)
    objectives = ["close_time", "thrust_peak", "installation_length"]

    [targets]
    clamp_force = 539365.75       # N, final tie-bar force (the machine's tonnage)
    mold_open_stroke = 0.132      # m, least platen stroke
    installation_length = 0.42    # m, most axial space of the linkage
    max_link_ratio = 4.0          # longest over shortest link

    [bounds]                      # [low, high], or one number to hold a variable fixed
    d = [0.10, 0.17]              # m ... angles in rad

Every bad key or value raises :class:`toggle.params.ParameterError` naming the file and
the key.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from toggle.files import InputError, read_text
from toggle.params import Mechanism, ParameterError, load_preset

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

#: The design variables of the symmetric double-toggle family, in vector order, with unit
#: and meaning. r2 is 0 (only d = r1 - r2 enters the kinematics); r4c follows from alpha4.
VARIABLES: dict[str, tuple[str, str]] = {
    "d": ("m", "height of the crosshead pin line above the triangular link's pivot (r1 - r2)"),
    "r3": ("m", "crosshead link"),
    "r4a": ("m", "triangular link, pivot to the crosshead link's pin"),
    "r4b": ("m", "triangular link, pivot to the platen-side link's pin"),
    "alpha4": ("rad", "angle of the triangular link at its pivot"),
    "r5": ("m", "platen-side link"),
    "e": ("m", "height of the platen joint above the triangular link's pivot"),
    "alpha_open": ("rad", "toggle angle of the open clamp (sets crosshead and platen travel)"),
}

#: Keys of [targets]: unit and meaning. All optional; a missing one constrains nothing.
TARGETS: dict[str, tuple[str, str]] = {
    "clamp_force": ("N", "final tie-bar force to reach at the toggle (needs [clamp])"),
    "mold_open_stroke": ("m", "least platen stroke from the open clamp to the toggle"),
    "installation_length": ("m", "most axial length of the linkage"),
    "max_link_ratio": ("1", "most ratio of the longest to the shortest link"),
}

@dataclass(frozen=True)
class Limit:
    """A designer's limit: ``most`` True for an upper bound; ``default`` (SI) and the
    source of that default; ``needs`` the preset data it takes (``sections``, ``spacing``,
    ``clamp``, ``die_height``)."""

    key: str
    unit: str
    most: bool
    default: float | None
    source: str
    needs: tuple[str, ...] = ()


#: The designer's limits: each a key of [targets] and a constraint of the same name.
DESIGN_LIMITS: dict[str, Limit] = {lim.key: lim for lim in (
    Limit("transmission_angle", "rad", False, math.radians(40.0),
          "40 deg, the least transmission angle for smooth running (Norton, Design of "
          "Machinery, on Alt's rule); at D (link 3 on the arm) and at A (link 5 on the "
          "platen's line: 90 deg less its inclination)"),
    Limit("radial_envelope", "m", True, None,
          "the reference machine's own (the base preset's, at its open position): a "
          "redesign fits the frame it replaces"),
    Limit("tiebar_clearance", "m", False, 0.010,
          "10 mm between the links' side faces and a tie bar (assumption: a running "
          "clearance; no standard names one)", ("sections", "spacing")),
    Limit("link_clearance", "m", False, None,
          "opt-in, no default: for a clamp whose two halves' links share one plane, so that "
          "their pins (D, B, A) must stay on their own sides of the clamp axis over the "
          "stroke (1 mm is play and tolerances); where the halves' link pairs interleave "
          "side by side (as the crosshead links pinned on the axis must), they may cross "
          "it. Seed 001 does not say which the SM-55's are", ("sections",)),
    Limit("clamp_force_sensitivity", "1/m", True, 3000.0,
          "at most 30 % clamp force change per 0.1 mm of mold height (a 300 mm steel mold "
          "grows 0.10 mm over 30 K at 11.5e-6/K); the SM-55 has 25.9 %", ("clamp",)),
    Limit("self_locking_travel", "m", False, 1.0e-3,
          "the clamp holds the mold shut without motor torque over at least the last 1 mm "
          "of crosshead travel (assumption: well above a servo's stopping error)",
          ("clamp",)),
    Limit("link_utilisation", "1", True, 1.0,
          "axial plus bending stress of each link within yield / 2 (assumption: a safety "
          "factor of 2 on EN 1563's Rp0.2 for cyclically loaded ductile iron)",
          ("sections", "clamp")),
    Limit("buckling_utilisation", "1", True, 1.0,
          "compression of the two-force links within the Johnson-Euler load / 3 "
          "(Shigley's column formulas, pinned ends; design factor 3, assumption)",
          ("sections", "clamp")),
    Limit("pin_pressure", "Pa", True, 100.0e6,
          "100 MPa, hardened steel pin in a hardened, greased steel bush under slow oscillating "
          "load (assumption: the top of the 25-100 MPa range bush makers rate; bronze bushes "
          "take about 60 MPa)",
          ("sections", "clamp")),
    Limit("die_height_range", "1", True, 1.0,
          "the clamp serves the tailstock's whole die-height range ([clamp.die_height] of the "
          "preset: the tie bars' span grows with the mold, so the clamp is stiffest at the "
          "thinnest mold and softest at the thickest): at both ends, the tailstock set for "
          "the target clamp force, the peak crosshead thrust within the motor's force (the "
          "drive_thrust rule) and the clamp force's sensitivity to mold height within "
          "clamp_force_sensitivity's limit; 1 is the worse of the two at its limit",
          ("clamp", "die_height")),
    Limit("platen_side_load", "1", True, math.tan(math.radians(50.0)),
          "transverse over axial force at the platen joint, tan 50 deg: link 5 within 50 "
          "deg of the platen's line (the 40 deg transmission rule at A)"),
)}

TARGETS.update({k: (lim.unit, ("most " if lim.most else "least ") + lim.key.replace("_", " ")
                     + f" (default: {lim.source})") for k, lim in DESIGN_LIMITS.items()})

#: Keys of [settings] with their defaults: the toggle angle where force amplification is
#: read (seed 004's "near lock-up"), points on the opening; lockup_angle > 0 holds the
#: angle of links 4b and 5 at lock-up (seed 004's gamma0): e = (r4b + r5) sin(lockup_angle)
#: follows the links instead of bounds.e; the molding cycle's hold (mold locked: injection
#: and cooling) and ejection dwells, s, of the cycle duty (assumption: 8 s and 1.5 s, a thin-
#: walled part on a 55 t machine; the seeds give no cycle).
SETTINGS: dict[str, float] = {"alpha_lock": math.radians(1.0), "points": 60,
                              "lockup_angle": 0.0, "hold": 8.0, "eject": 1.5}

_TOP = {"preset", "objectives", "targets", "bounds", "settings", "description"}


@dataclass(frozen=True)
class Targets:
    """A parsed targets file (SI): what a design search looks for.

    Attributes:
        preset: The base preset whose clamp data, motor, drive and masses are kept.
        objectives: The objectives to trade (names of ``OBJECTIVES``).
        targets: What every design must meet (``clamp_force``, ``mold_open_stroke``, ...).
        bounds: Every variable of ``VARIABLES`` to (low, high); low == high holds it fixed.
        settings: The designer's limits and evaluation settings.
        origin: Where the targets came from (the file), for messages.
        description: The file's description.
    """

    preset: str
    objectives: tuple[str, ...]
    targets: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    settings: dict[str, float]
    origin: str = "<targets>"
    description: str = ""

    @property
    def free(self) -> tuple[str, ...]:
        """The variables the search varies (low < high), in vector order."""
        return tuple(v for v in VARIABLES if self.bounds[v][0] < self.bounds[v][1])

    @property
    def base(self) -> Mechanism:
        """The base preset (clamp data, drive and masses of every design)."""
        return load_preset(self.preset)

    def digest(self) -> str:
        """Hash of everything that changes an evaluation: a store keyed by it is only reused
        for the same problem."""
        limits = sorted((k, lim.default) for k, lim in DESIGN_LIMITS.items())
        payload = json.dumps([self.preset, sorted(self.targets.items()),
                              sorted(self.settings.items()), _preset_text(self.preset),
                              limits], sort_keys=True)
        return hashlib.sha256(payload.encode()).hexdigest()[:16]


def _preset_text(preset: str) -> str:
    from toggle.params import preset_table  # the parsed table: a comment change is no change
    return json.dumps(preset_table(preset)[0], sort_keys=True, default=str)


def _given(value: Any) -> str:
    """What the file gave for a key, in TOML's words (not Python's: no None, no quotes)."""
    if value is None:
        return "but it is missing"
    if isinstance(value, dict):
        return "got a table"
    try:
        return f"got {json.dumps(value)}"
    except (TypeError, ValueError):  # a TOML date or time
        return f"got {value}"


def _number(value: Any, where: str, unit: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value):
        raise ParameterError(f"{where} must be a finite number ({unit}), {_given(value)}")
    return float(value)


def _bounds(table: Any, origin: str) -> dict[str, tuple[float, float]]:
    if not isinstance(table, dict):
        raise ParameterError(f"{origin}: [bounds] must be a table of [low, high] per variable")
    unknown = set(table) - set(VARIABLES)
    missing = set(VARIABLES) - set(table)
    if unknown or missing:
        raise ParameterError(f"{origin}: [bounds]: unknown {sorted(unknown)}, "
                             f"missing {sorted(missing)} (variables: {', '.join(VARIABLES)})")
    out = {}
    for name in VARIABLES:
        unit, value, where = VARIABLES[name][0], table[name], f"{origin}: bounds.{name}"
        pair = value if isinstance(value, list) else [value, value]
        if len(pair) != 2:
            raise ParameterError(f"{where} must be [low, high] or one number ({unit}), "
                                 f"{_given(value)}")
        lo, hi = (_number(v, where, unit) for v in pair)
        if lo > hi:
            raise ParameterError(f"{where}: low {lo:g} is above high {hi:g} {unit}")
        if name not in ("d", "e", "alpha4", "alpha_open") and lo <= 0:
            raise ParameterError(f"{where}: a link length must be > 0 m, got {lo:g}")
        if name in ("alpha4", "alpha_open") and not 0 < lo <= hi < math.pi:
            raise ParameterError(f"{where} must lie in (0, pi) rad, got [{lo:g}, {hi:g}]")
        out[name] = (lo, hi)
    return out


@dataclass(frozen=True)
class Objective:
    """One objective: ``sense`` +1 to maximise, -1 to minimise; ``needs`` the preset's
    sections it takes."""

    key: str
    label: str
    unit: str
    sense: int
    needs: tuple[str, ...] = ()

    def check(self, base: Mechanism, origin: str) -> None:
        """Refuse an objective the base preset cannot evaluate, by name."""
        for section in self.needs:
            if getattr(base, section) is None:
                raise ParameterError(f"{origin}: objective {self.key} needs the [{section}] "
                                     f"section, which preset {base.name} does not have")

    @property
    def header(self) -> str:
        return f"{self.key} ({self.unit})"


#: Every objective a targets file may pick (``toggle design --help`` lists them).
OBJECTIVES: dict[str, Objective] = {o.key: o for o in (
    Objective("force_amplification", "seed 004's Mp (Eq 6): crosshead over platen stroke "
              "from lock-up to alpha_lock", "1", 1),
    Objective("mechanical_advantage_lock", "frictionless platen over crosshead force at "
              "alpha_lock (1 / Mv, seed 004's Eq 5)", "1", 1),
    Objective("stroke_ratio", "platen over crosshead stroke, open clamp", "1", 1),
    Objective("velocity_ratio_peak", "peak platen over crosshead speed", "1", 1),
    Objective("coping_angle_min", "minimum coping angle (seed 004)", "rad", 1),
    Objective("velocity_ratio_close", "platen over crosshead speed entering mold protection",
              "1", -1),
    Objective("close_time", "closing time bound under the motor's limits", "s", -1,
              ("clamp", "drive", "dynamics")),
    Objective("close_rms_torque", "motor RMS torque over the minimum-time plan of the "
              "closing stroke (the planner: any duty objective plans both strokes, about "
              "1.4 s a candidate)", "N m", -1,
              ("clamp", "drive", "dynamics")),
    Objective("close_energy", "motor shaft energy (no regeneration) over the same plan",
              "J", -1, ("clamp", "drive", "dynamics")),
    Objective("cycle_rms_torque", "motor RMS torque over the molding cycle: that plan, the "
              "hold, the minimum-time opening, the ejection (settings.hold, eject)", "N m", -1,
              ("clamp", "drive", "dynamics")),
    Objective("cycle_energy", "motor shaft energy (no regeneration) over the same cycle",
              "J", -1, ("clamp", "drive", "dynamics")),
    Objective("thrust_peak", "peak crosshead thrust clamping to the force", "N", -1,
              ("clamp",)),
    Objective("link_stress", "peak axial link stress, clamped", "Pa", -1, ("clamp",)),
    Objective("tiebar_stress", "tie-bar stress, clamped", "Pa", -1, ("clamp",)),
    Objective("tolerance_cost", "cost of tolerances at seed 003's reliabilities", "1", -1),
    Objective("tolerance_sensitivity", "RSS of platen-position sensitivities at the toggle",
              "1", -1),
    Objective("installation_length", "axial length of the linkage", "m", -1),
    Objective("transmission_angle", "least transmission angle over the stroke (D and A)",
              "rad", 1),
    Objective("radial_envelope", "radial height the pins sweep", "m", -1),
    Objective("link_mass", "mass of the links (scaled from the preset's by their sizes)",
              "kg", -1, ("clamp", "dynamics", "sections")),
    Objective("breakaway_force", "crosshead pull that opens the clamped mold", "N", -1,
              ("clamp",)),
)}


def targets_from_dict(table: dict[str, Any], origin: str = "<targets>") -> Targets:
    """A :class:`Targets` from a parsed TOML table; every fault names its key."""
    unknown = set(table) - _TOP
    if unknown:
        raise ParameterError(f"{origin}: unknown key(s) {sorted(unknown)}; "
                             f"known: {', '.join(sorted(_TOP))}")
    preset = table.get("preset")
    if not isinstance(preset, str):
        raise ParameterError(f"{origin}: preset must be a preset name or TOML path, "
                             f"{_given(preset)}")
    base = load_preset(preset)
    objectives = table.get("objectives")
    if not (isinstance(objectives, list) and len(objectives) >= 2
            and all(isinstance(o, str) for o in objectives)):
        raise ParameterError(f"{origin}: objectives must be a list of at least two names "
                             f"from {', '.join(OBJECTIVES)}, {_given(objectives)}")
    for name in objectives:
        if name not in OBJECTIVES:
            raise ParameterError(f"{origin}: objectives: unknown {name!r}; "
                                 f"known: {', '.join(OBJECTIVES)}")
        OBJECTIVES[name].check(base, origin)
    if len(set(objectives)) != len(objectives):
        raise ParameterError(f"{origin}: objectives: {objectives!r} names one twice")
    raw = table.get("targets", {})
    if not isinstance(raw, dict):
        raise ParameterError(f"{origin}: [targets] must be a table")
    targets = {}
    for key, value in raw.items():
        if key not in TARGETS:
            raise ParameterError(f"{origin}: targets.{key} is unknown; "
                                 f"known: {', '.join(TARGETS)}")
        targets[key] = _number(value, f"{origin}: targets.{key}", TARGETS[key][0])
        if targets[key] <= 0:
            raise ParameterError(f"{origin}: targets.{key} must be > 0 {TARGETS[key][0]}, "
                                 f"{_given(value)}")
    if "clamp_force" in targets and base.clamp is None:
        raise ParameterError(f"{origin}: targets.clamp_force needs a preset with [clamp] "
                             f"data; {preset} has none")
    settings = dict(SETTINGS)
    for key, value in table.get("settings", {}).items():
        if key not in SETTINGS:
            raise ParameterError(f"{origin}: settings.{key} is unknown; "
                                 f"known: {', '.join(SETTINGS)}")
        settings[key] = _number(value, f"{origin}: settings.{key}", "")
    if not (0 < settings["alpha_lock"] < 0.5 and 2 <= settings["points"] <= 1000
            and 0 <= settings["lockup_angle"] < 0.5
            and 0 <= settings["hold"] <= 3600 and 0 <= settings["eject"] <= 3600):
        raise ParameterError(f"{origin}: settings need 0 < alpha_lock < 0.5 rad, "
                             f"2 <= points <= 1000, 0 <= lockup_angle < 0.5 rad and "
                             f"hold and eject of 0 to 3600 s, got {settings}")
    bounds = _bounds(table.get("bounds"), origin)
    if bounds["alpha_open"][0] <= settings["alpha_lock"]:
        raise ParameterError(f"{origin}: bounds.alpha_open must stay above settings.alpha_lock "
                             f"= {settings['alpha_lock']:g} rad, got {bounds['alpha_open'][0]:g}")
    return Targets(preset=preset, objectives=tuple(objectives), targets=targets,
                   bounds=bounds, settings=settings,
                   origin=origin, description=str(table.get("description", "")))


def load_targets(path: str | Path) -> Targets:
    """Read a targets file (:func:`targets_from_dict`)."""
    try:
        text = read_text(path, "targets file")  # no such file, a folder, not UTF-8: in words
    except InputError as exc:
        raise ParameterError(str(exc)) from None
    if not text.strip():
        raise ParameterError(f"targets file {path}: is empty; it needs preset = \"...\", "
                             "objectives, [targets] and [bounds] (see design/examples/sm55.toml)")
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"targets file {path}: {exc}") from exc
    preset = table.get("preset")
    if isinstance(preset, str) and preset.endswith(".toml") and not Path(preset).is_absolute():
        beside = Path(path).parent / preset  # a preset file named relative to the targets
        if beside.is_file():
            table["preset"] = str(beside)
    return targets_from_dict(table, str(path))
