"""modelDescription.xml from a slave's :class:`~fmu_src.variables.Var` table: units, display
units, limits and ModelStructure, which pythonfmu 0.7 does not write (fmpy's validator
rejects its FMUs without them).

:func:`extend_model_description` is called at build time from
:meth:`fmu_src.slave.DeclaredSlave.to_xml`; the native build
(:mod:`fmu_src.native_build`) writes its description with the same helpers. Apart from
:mod:`fmu_src.build` (which bundles and validates) so that the slave and the builder do not
import each other.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from importlib.metadata import PackageNotFoundError, version
from xml.etree.ElementTree import Element, SubElement

from fmu_src.variables import Var, hidden_names

# SI units: exponents of the FMI base units, and display units as (name, factor)
# with display value = factor * value.
UNITS: dict[str, dict[str, int]] = {
    "1": {},
    "s": {"s": 1},
    "Hz": {"s": -1},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "kg": {"kg": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N/m": {"kg": 1, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "Pa": {"kg": 1, "m": -1, "s": -2},
    "1/s": {"s": -1},
}
#: The physical quantity of each unit's variables (FMI ``quantity``).
QUANTITIES = {"s": "Time", "Hz": "Frequency", "m": "Length", "m/s": "Velocity",
              "m/s2": "Acceleration", "rad": "Angle", "kg": "Mass", "kg.m2": "MomentOfInertia",
              "N": "Force", "N.s/m": "TranslationalDampingConstant", "N.m": "Torque",
              "1/s": "Rate"}
#: The display unit a tool shows by default (FMI ``displayUnit``); one of DISPLAY_UNITS.
DEFAULT_DISPLAY = {"m": "mm", "m/s": "mm/s", "N": "kN", "rad": "deg"}
DISPLAY_UNITS: dict[str, tuple[tuple[str, float], ...]] = {
    "m": (("mm", 1e3),),
    "m/s": (("mm/s", 1e3),),
    "rad": (("deg", 180.0 / math.pi),),
    "N": (("kN", 1e-3), ("kgf", 1.0 / 9.80665)),
}


def number_text(value: float) -> str:
    """A float as modelDescription.xml writes it (repr: round-trips exactly)."""
    return repr(float(value))


def project_version() -> str:
    """The installed project's version (the FMU's modelDescription ``version``)."""
    try:
        return version("toggle-clamp")
    except PackageNotFoundError:
        return "unknown"


def unit_definitions(units: Iterable[str]) -> Element:
    """UnitDefinitions with BaseUnit and display units of each unit used."""
    node = Element("UnitDefinitions")
    for name in sorted(units):
        unit = SubElement(node, "Unit", name=name)  # "1": a BaseUnit with no exponents
        SubElement(unit, "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})
        for display, factor in DISPLAY_UNITS.get(name, ()):
            SubElement(unit, "DisplayUnit", name=display, factor=number_text(factor))
    return node


def real_attributes(unit: str, nominal: float | None = None) -> dict[str, str]:
    """quantity, displayUnit and nominal of a Real variable of ``unit`` (where it has them)."""
    out = {}
    if unit in QUANTITIES:
        out["quantity"] = QUANTITIES[unit]
    if unit in DEFAULT_DISPLAY:
        out["displayUnit"] = DEFAULT_DISPLAY[unit]
    if nominal is not None:
        out["nominal"] = number_text(nominal)
    return out


def model_structure(variables: Sequence[Var],
                    initial: Mapping[str, Sequence[str]] | None = None) -> Element:
    """Outputs with their direct input dependencies; InitialUnknowns = all outputs, with
    the inputs and parameters each depends on in ``initial`` (none given: every known)."""
    index = {v.name: i + 1 for i, v in enumerate(variables)}  # 1-based ModelVariables order
    node = Element("ModelStructure")
    outputs = [v for v in variables if v.causality == "output"]
    if not outputs:
        return node
    out_node = SubElement(node, "Outputs")
    for var in outputs:
        attrib = {"index": str(index[var.name])}
        if var.depends_on is not None:
            attrib["dependencies"] = " ".join(str(index[n]) for n in var.depends_on)
        SubElement(out_node, "Unknown", attrib)
    init_node = SubElement(node, "InitialUnknowns")
    for var in outputs:  # no dependencies attribute: may depend on every known at init
        attrib = {"index": str(index[var.name])}
        if initial is not None:
            attrib["dependencies"] = " ".join(str(index[n]) for n in initial[var.name])
        SubElement(init_node, "Unknown", attrib)
    return node


def check_variables(variables: Sequence[Var]) -> None:
    """Reject a table that would give an invalid model description."""
    names = [v.name for v in variables]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"duplicate variable names: {duplicates}")
    inputs = {v.name for v in variables if v.causality == "input"}
    for var in variables:
        if not var.is_string and var.unit not in UNITS:
            raise ValueError(f"{var.name}: unit {var.unit!r} is not in fmu_src.description.UNITS")
        unknown = set(var.depends_on or ()) - inputs
        if unknown:
            raise ValueError(f"{var.name}: depends_on names non-inputs {sorted(unknown)}")


def extend_model_description(root: Element, variables: Sequence[Var],
                             initial: Mapping[str, Sequence[str]] | None = None) -> None:
    """Complete pythonfmu's modelDescription tree in place from the variable table
    (``initial``: the initial unknowns' dependencies, see :func:`model_structure`)."""
    check_variables(variables)
    root.set("version", project_version())
    root.set("copyright", "Copyright (c) the toggle-clamp authors")
    root.set("license", "MIT")
    scalars = root.find("ModelVariables")
    hidden = hidden_names(variables)  # registered after the table; the guard sets them
    for sv in list(scalars)[len(variables):]:
        if sv.get("name") in hidden:
            scalars.remove(sv)
    names = [sv.get("name") for sv in scalars]
    if names != [v.name for v in variables]:
        raise ValueError(f"registered variables {names} differ from the table")
    for sv, var in zip(scalars, variables, strict=True):
        if var.is_string:
            continue
        real = sv.find("Real")
        real.set("unit", var.unit)
        for attr, value in real_attributes(var.unit, var.nominal).items():
            real.set(attr, value)
        for attr in ("min", "max"):
            if getattr(var, attr) is not None:
                real.set(attr, number_text(getattr(var, attr)))

    experiment = root.find("DefaultExperiment")
    if experiment is None or experiment.get("stepSize") is None:
        raise ValueError("the slave must set default_experiment with a step_size")

    cosim = root.find("CoSimulation")
    cosim.set("canGetAndSetFMUstate", "true")
    cosim.set("canSerializeFMUstate", "true")
    # the guard passes fmi2SetRealInputDerivatives on (fmu_src.slave, hidden variables)
    cosim.set("canInterpolateInputs", "true")
    cosim.set("maxOutputDerivativeOrder", "0")
    units = {v.unit for v in variables if not v.is_string}
    root.insert(list(root).index(cosim) + 1, unit_definitions(units))

    root.remove(root.find("ModelStructure"))
    root.append(model_structure(variables, initial))
