"""Mechanism parameters: typed, immutable, SI units (m, rad).

Each half of the nine-link clamp carries its own dimensions, so a mechanical
error is just a different number in one half. Presets are TOML files shipped
in ``toggle/presets``; a user's own file loads the same way. The other sections (clamp,
sections, drive, dynamics) and ParameterError are :mod:`toggle.sections`'s, re-exported.
"""

from __future__ import annotations

import difflib
import math
import sys
from dataclasses import MISSING, dataclass, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

from toggle.files import InputError, read_toml

# the sections and the error are re-exported: callers take the whole model from here
from toggle.sections import (  # noqa: F401
    DYNAMICS_PARAMETERS,
    MAX_CURVE_POINTS,
    ClampData,
    DieHeight,
    Drive,
    Dynamics,
    LinkSection,
    LinkSections,
    MemberCounts,
    ParameterError,
    PinRadii,
    Sections,
    TieBars,
    UnknownPresetError,
    dynamics_fields,
    dynamics_parameters,
    torque_speed_points,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

HALVES = ("lower", "upper")

#: Field order of :class:`HalfDims` (seed 000's lower-half names).
DIMENSIONS = ("r1", "r2", "r3", "r4a", "r4b", "r4c", "r5", "e")

#: Seed 000's names of each half's dimensions (Figure 4): the upper half's link 3,
#: 4 and 5 are links 6, 7 and 8.
PAPER_NAMES = {
    "lower": dict(zip(DIMENSIONS, ("r1L", "r2L", "r3", "r4a", "r4b", "r4c", "r5", "eL"))),
    "upper": dict(zip(DIMENSIONS, ("r1U", "r2U", "r6", "r7a", "r7b", "r7c", "r8", "eU"))),
}


def paper_dimension(name: str) -> tuple[str, str]:
    """Map a paper name such as ``"r8"`` or ``"eL"`` to ``(half, field)``."""
    for half, names in PAPER_NAMES.items():
        for field, paper in names.items():
            if paper == name:
                return half, field
    known = ", ".join(n for names in PAPER_NAMES.values() for n in names.values())
    raise ParameterError(f"unknown dimension {name!r}; known: {known}")


#: Largest plausible clamp dimension, m: a preset written in mm exceeds it.
MAX_DIMENSION = 10.0


@dataclass(frozen=True)
class HalfDims:
    """Dimensions of one half (a Watt-II six-link chain), metres.

    r1, r2: vertical offsets of the link-4 fixed pivot and of the crosshead pin
    from the clamp axis; r3: crosshead link; r4a, r4b, r4c: sides of the
    triangular tailstock-side link (pivot to link-3 pin, pivot to link-5 pin,
    between the two pins); r5: platen-side link; e: vertical offset of the
    platen joint from the link-4 pivot.
    """

    r1: float
    r2: float
    r3: float
    r4a: float
    r4b: float
    r4c: float
    r5: float
    e: float

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ParameterError(f"{f.name} must be a finite number, got {value!r}")
        for name in ("r3", "r4a", "r4b", "r4c", "r5"):
            if getattr(self, name) <= 0:
                value = getattr(self, name)
                raise ParameterError(f"link length {name} must be positive, got {value}")
        for f in fields(self):
            if abs(getattr(self, f.name)) > MAX_DIMENSION:
                raise ParameterError(
                    f"{f.name} = {getattr(self, f.name):g} m is beyond {MAX_DIMENSION:g} m: "
                    "dimensions are in metres (was it written in mm?)")
        a, b, c = self.r4a, self.r4b, self.r4c
        if not (abs(a - b) < c < a + b):
            raise ParameterError(
                f"triangular link 4 cannot close: r4a={a}, r4b={b}, r4c={c} m "
                "violate the triangle inequality"
            )

    @property
    def alpha4(self) -> float:
        """Angle of the triangular link at its fixed pivot, rad (Eq 6)."""
        a, b, c = self.r4a, self.r4b, self.r4c
        return math.acos((a * a + b * b - c * c) / (2 * a * b))

    @property
    def d(self) -> float:
        """Vertical distance from the link-4 pivot to the crosshead pin line, m."""
        return self.r1 - self.r2

    def replace(self, **changes: float) -> HalfDims:
        """A copy with some dimensions changed."""
        return replace(self, **changes)

    def as_tuple(self) -> tuple[float, ...]:
        return tuple(getattr(self, n) for n in DIMENSIONS)


@dataclass(frozen=True)
class Mechanism:
    """A double-toggle clamp: a named pair of halves."""

    name: str
    lower: HalfDims
    upper: HalfDims
    description: str = ""
    #: Pins, sections, tie bars and clamping data (seed 001); None if the file has no [clamp].
    clamp: ClampData | None = None
    #: Ball-screw/belt drive (seed 001 Eqs 31-32); None if the file has no [drive].
    drive: Drive | None = None
    #: Masses and guide damping of the dynamic plant; None if the file has no [dynamics].
    dynamics: Dynamics | None = None
    #: Link sections and materials (toggle design's structural checks); None without [sections].
    sections: Sections | None = None

    def half(self, half: str) -> HalfDims:
        if half not in HALVES:
            raise ParameterError(f"half must be 'lower' or 'upper', got {half!r}")
        return getattr(self, half)

    def with_error(self, half: str, dim: str, delta: float) -> Mechanism:
        """The mechanism with ``dim`` of one half changed by ``delta`` (m)."""
        if dim not in DIMENSIONS:
            raise ParameterError(f"unknown dimension {dim!r}; known: {', '.join(DIMENSIONS)}")
        h = self.half(half)
        return replace(self, **{half: h.replace(**{dim: getattr(h, dim) + delta})})

    @property
    def symmetric(self) -> bool:
        return self.lower == self.upper


# --- Real-mold clamping data (seed 001, Lin & Hsiao 2003), all SI ---------------------------


def _sections_from_table(table: Any, origin: str) -> Sections:
    if not isinstance(table, dict):
        raise ParameterError(f"{origin}: [sections] must be a table")
    names = [f.name for f in fields(Sections)]
    unknown, missing = set(table) - set(names), set(names) - set(table)
    if unknown or missing:
        raise ParameterError(f"{origin}: [sections]: unknown {sorted(unknown)}, "
                             f"missing {sorted(missing)}")
    return Sections(**{n: _section(LinkSection, table[n], origin, f"sections.{n}")
                       for n in names})


def symbolic_copy(obj: Any, **values: Any) -> Any:
    """A copy of a frozen dataclass with some fields set to CasADi symbols, its numeric
    checks skipped: how the native FMU and the planner keep values as inputs or parameters
    of generated functions."""
    copy = object.__new__(type(obj))
    for f in fields(obj):
        object.__setattr__(copy, f.name, values.get(f.name, getattr(obj, f.name)))
    return copy


def _section(cls: type, table: Any, origin: str, where: str) -> Any:
    """Build one dataclass section from a TOML table, naming unknown/missing keys."""
    if not isinstance(table, dict):
        raise ParameterError(f"{origin}: [{where}] must be a table")
    _unknown(table, [f.name for f in fields(cls)], f"{origin}: [{where}]", "key")
    missing = [f.name for f in fields(cls) if f.default is MISSING and f.name not in table]
    if missing:
        raise ParameterError(f"{origin}: [{where}] has no {', '.join(missing)}")
    try:
        return cls(**table)
    except (TypeError, ParameterError) as exc:
        raise ParameterError(f"{origin}: [{where}]: {exc}") from exc


def _clamp_from_table(table: Any, origin: str) -> ClampData:
    """[clamp] with sub-tables pins, counts, links, tiebars (and die_height, optional)."""
    if not isinstance(table, dict):
        raise ParameterError(f"{origin}: [clamp] must be a table")
    parts = {"pins": PinRadii, "counts": MemberCounts, "links": LinkSections, "tiebars": TieBars,
             "die_height": DieHeight}
    values = {k: v for k, v in table.items() if k not in parts}
    for key, cls in parts.items():
        if key not in table:
            if key == "die_height":
                continue
            raise ParameterError(f"{origin}: [clamp.{key}] is missing")
        values[key] = _section(cls, table[key], origin, f"clamp.{key}")
    return _section(ClampData, values, origin, "clamp")


#: The tables and keys of a clamp preset (a family adds ``groups`` and ``default_group``).
SECTIONS = ("name", "description", "half", "lower", "upper", "clamp", "drive", "dynamics",
            "sections")


def _unknown(names: Any, known: Any, where: str, kind: str) -> None:
    """Refuse the first of ``names`` not in ``known``, by name, with the nearest known one."""
    for name in names:
        if name not in known:
            near = difflib.get_close_matches(str(name), list(known), n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise ParameterError(f"{where}: unknown {kind} {name!r}{hint}; "
                                 f"known: {', '.join(known)}")


def _halves_from_table(table: dict[str, Any], origin: str) -> tuple[HalfDims, HalfDims]:
    for name in ("half", *HALVES):  # each table's own keys, named where they are
        if name in table:
            if not isinstance(table[name], dict):
                raise ParameterError(f"{origin}: [{name}] must be a table of dimensions (m)")
            _unknown(table[name], DIMENSIONS, f"{origin}: [{name}]", "dimension")
    common = table.get("half", {})
    out = []
    for half in HALVES:
        values = {**common, **table.get(half, {})}
        missing = [k for k in DIMENSIONS if k not in values]
        if missing:
            raise ParameterError(
                f"{origin}: the {half} half has no {', '.join(missing)} "
                f"(give it in [half], or in [{half}] for this half only)")
        for key, value in values.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ParameterError(f"{origin}: [{half}] {key} = {value!r} is not a number (m)")
        try:
            out.append(HalfDims(**{k: float(v) for k, v in values.items()}))
        except ParameterError as exc:
            raise ParameterError(f"{origin}: [{half}] {exc}") from exc
    return out[0], out[1]


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``over`` laid on top, sub-tables merged key by key."""
    out = dict(base)
    for key, value in over.items():
        both = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = _merge(out[key], value) if both else value
    return out


def group_names(table: dict[str, Any]) -> list[str]:
    """Names of the groups of a preset family (``[groups.<name>]`` tables); [] for one mechanism."""
    return list(table.get("groups", {}))


def select_group(table: dict[str, Any], group: str | int | None, origin: str) -> dict[str, Any]:
    """The table of one group of a preset family, merged over the family's shared tables.

    A family holds several variants of one mechanism in one file: shared tables
    at the top, and each group's differences in ``[groups.<name>]`` (with
    sub-tables such as ``[groups.<name>.half]``). Without ``group`` a family
    gives its ``default_group``; a file without groups is returned unchanged.
    """
    names = group_names(table)
    if not names:
        if group is not None:
            raise ParameterError(f"{origin} has no groups; cannot select group {group!r}")
        return table
    key = str(group if group is not None else table.get("default_group", ""))
    if key not in names:
        raise ParameterError(
            f"{origin}: unknown or missing group {key!r}; groups: {', '.join(names)}"
        )
    shared = {k: v for k, v in table.items() if k not in ("groups", "default_group")}
    chosen = table["groups"][key]
    merged = _merge(shared, {k: v for k, v in chosen.items() if k != "description"})
    merged["name"] = f"{table.get('name', origin)}/{key}"
    if "description" in chosen:
        family = table.get("description", "")
        merged["description"] = f"{family}, group {key}: {chosen['description']}"
    return merged


def mechanism_from_dict(
    table: dict[str, Any], origin: str = "<dict>", group: str | int | None = None
) -> Mechanism:
    """Build a :class:`Mechanism` from a parsed TOML table (SI units).

    For a preset family, ``group`` names the group (see :func:`select_group`).
    """
    table = select_group(table, group, origin)
    if not {"half", "lower", "upper"} & set(table):
        what = table.get("description", "")
        raise ParameterError(f"{origin} has no clamp link dimensions ([half], [lower], [upper])"
                             + (f": it is the {what}" if what else ""))
    _unknown(table, SECTIONS, origin, "section or key")
    lower, upper = _halves_from_table(table, origin)
    return Mechanism(
        name=str(table.get("name", origin)),
        lower=lower,
        upper=upper,
        description=str(table.get("description", "")),
        clamp=_clamp_from_table(table["clamp"], origin) if "clamp" in table else None,
        drive=_section(Drive, table["drive"], origin, "drive") if "drive" in table else None,
        dynamics=(_section(Dynamics, table["dynamics"], origin, "dynamics")
                  if "dynamics" in table else None),
        sections=(_sections_from_table(table["sections"], origin)
                  if "sections" in table else None),
    )


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        return read_toml(path, "preset")
    except InputError as exc:
        raise ParameterError(str(exc)) from None


def load_mechanism(path: str | Path, group: str | int | None = None) -> Mechanism:
    """Load a mechanism (or one ``group`` of a family) from a TOML file (preset format, SI).

    Args:
        path: The TOML file (see ``toggle/presets/chang2021.toml`` for the format).
        group: One group of a preset family; default the family's default group.

    Returns:
        The mechanism, checked (a dimension beyond 10 m is refused as written in mm).

    Raises:
        ParameterError: A missing, unreadable or invalid file, naming the key.
    """
    return mechanism_from_dict(_read_toml(Path(path)), str(path), group)


def preset_names() -> list[str]:
    """Names of the presets shipped with the package.

    Returns:
        The names `load_preset` takes, sorted.
    """
    folder = resources.files(__package__) / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def _split_group(name: str, group: str | int | None) -> tuple[str, str | int | None]:
    """``"family/g"`` -> ``("family", "g")``; an existing file or a ``.toml`` name stays whole."""
    if group is None and "/" in name and preset_file(name) is None and not Path(name).exists():
        base, _, part = name.rpartition("/")
        if base and (base in preset_names() or Path(base).is_file()):
            return base, part
    return name, group


def split_group(name: str) -> tuple[str, str | None]:
    """``"li_micro/6"`` -> ``("li_micro", "6")``; a name without a group -> ``(name, None)``."""
    base, group = _split_group(name, None)
    return base, None if group is None else str(group)


def preset_file(name: str) -> Path | None:
    """The file of a preset given as a path (a name ending in .toml, or an existing file);
    None for a shipped preset's name."""
    return Path(name) if name.endswith(".toml") or Path(name).is_file() else None


def preset_table(name: str) -> tuple[dict[str, Any], str]:
    """Parsed TOML of a shipped preset or of a file, and the origin used in messages."""
    if not name.strip():
        raise UnknownPresetError(f"an empty preset name; shipped: {', '.join(preset_names())}"
                                 " or a TOML file")
    if Path(name).is_dir():
        raise ParameterError(f"{name} is a directory, not a preset TOML file")
    if (path := preset_file(name)) is not None:
        return _read_toml(path), name
    resource = resources.files(__package__) / "presets" / f"{name}.toml"
    if not resource.is_file():
        raise UnknownPresetError(f"unknown preset {name!r}; shipped: {', '.join(preset_names())}")
    return tomllib.loads(resource.read_text(encoding="utf-8")), f"preset {name}"


def load_preset(name: str, group: str | int | None = None) -> Mechanism:
    """Load a shipped preset by name, or a TOML file if ``name`` is a path.

    A preset family takes ``group`` or the name ``family/group``
    (``load_preset("li_micro", group=6)`` is ``load_preset("li_micro/6")``);
    without either it gives the family's default group.

    Args:
        name: A shipped preset's name (`preset_names`) or a TOML file's path.
        group: One group of a preset family.

    Returns:
        The mechanism.

    Raises:
        ParameterError: An unknown preset or an invalid file (``UnknownPresetError`` for
            an unknown name).
    """
    name, group = _split_group(name, group)
    table, origin = preset_table(name)
    return mechanism_from_dict(table, origin, group)


def preset_groups(name: str) -> list[str]:
    """Group names of a preset family (shipped name or file); [] for a single mechanism."""
    return group_names(preset_table(name)[0])
