"""Build this project's FMI 2.0 Co-Simulation FMUs with pythonfmu 0.7.

pythonfmu writes no units, no min/max, no output dependencies and no
InitialUnknowns, so fmpy's validator rejects its FMUs.
:func:`extend_model_description` (called from
:meth:`toggle.fmu_slave.DeclaredSlave.to_xml`) completes the description from
the slave's :class:`~toggle.fmu_slave.Var` table; :func:`build_fmu` bundles the
``toggle`` package, gives the slave module a project-unique name and refuses
to write an FMU that fmpy does not validate.
"""

from __future__ import annotations

import math
import shutil
import sys
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement

import toggle
from toggle.fmu_slave import Var

PACKAGE_DIR = Path(toggle.__file__).resolve().parent
DEFAULT_SLAVE = PACKAGE_DIR.parent / "fmu_src" / "toggle_clamp_fmu.py"
MODULE_PREFIX = "toggle_"

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
}
DISPLAY_UNITS: dict[str, tuple[tuple[str, float], ...]] = {
    "m": (("mm", 1e3),),
    "m/s": (("mm/s", 1e3),),
    "rad": (("deg", 180.0 / math.pi),),
    "N": (("kN", 1e-3), ("kgf", 1.0 / 9.80665)),
}


def number_text(value: float) -> str:
    """A float as modelDescription.xml writes it (repr: round-trips exactly)."""
    return repr(float(value))


def unit_definitions(units: Iterable[str]) -> Element:
    """UnitDefinitions with BaseUnit and display units of each unit used."""
    node = Element("UnitDefinitions")
    for name in sorted(units):
        unit = SubElement(node, "Unit", name=name)
        if UNITS[name]:
            SubElement(unit, "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})
        for display, factor in DISPLAY_UNITS.get(name, ()):
            SubElement(unit, "DisplayUnit", name=display, factor=number_text(factor))
    return node


def model_structure(variables: Sequence[Var]) -> Element:
    """Outputs with their direct input dependencies; InitialUnknowns = all outputs."""
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
        SubElement(init_node, "Unknown", index=str(index[var.name]))
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
            raise ValueError(f"{var.name}: unit {var.unit!r} is not in toggle.fmu_build.UNITS")
        unknown = set(var.depends_on or ()) - inputs
        if unknown:
            raise ValueError(f"{var.name}: depends_on names non-inputs {sorted(unknown)}")


def extend_model_description(root: Element, variables: Sequence[Var]) -> None:
    """Complete pythonfmu's modelDescription tree in place from the variable table."""
    check_variables(variables)
    scalars = root.find("ModelVariables")
    names = [sv.get("name") for sv in scalars]
    if names != [v.name for v in variables]:
        raise ValueError(f"registered variables {names} differ from the table")
    for sv, var in zip(scalars, variables, strict=True):
        if var.is_string:
            continue
        real = sv.find("Real")
        real.set("unit", var.unit)
        for attr in ("min", "max"):
            if getattr(var, attr) is not None:
                real.set(attr, number_text(getattr(var, attr)))

    experiment = root.find("DefaultExperiment")
    if experiment is None or experiment.get("stepSize") is None:
        raise ValueError("the slave must set default_experiment with a step_size")

    cosim = root.find("CoSimulation")
    cosim.set("canGetAndSetFMUstate", "true")
    cosim.set("canSerializeFMUstate", "true")
    units = {v.unit for v in variables if not v.is_string}
    root.insert(list(root).index(cosim) + 1, unit_definitions(units))

    root.remove(root.find("ModelStructure"))
    root.append(model_structure(variables))


def fmu_module_name(slave_file: Path) -> str:
    """Module name of the slave inside the FMU: prefixed so it is unique to this project.

    pythonfmu imports the slave by module name into the host's ``sys.modules``;
    two FMUs with the same module name in one process would share one module.
    """
    stem = slave_file.stem
    return stem if stem.startswith(MODULE_PREFIX) else f"{MODULE_PREFIX}fmu_{stem}"


def build_fmu(
    out_dir: Path,
    slave_file: Path = DEFAULT_SLAVE,
    project_files: Iterable[Path] = (PACKAGE_DIR,),
) -> Path:
    """Build ``<out_dir>/<ModelName>.fmu`` from a slave file; return its path.

    The ``toggle`` package is bundled in ``resources/`` so the FMU runs in a
    Python that has numpy and casadi but not this project. Raises RuntimeError
    if fmpy's validator finds problems in the result.
    """
    from fmpy.validation import validate_fmu
    from pythonfmu import FmuBuilder

    slave_file = Path(slave_file).resolve()
    if not slave_file.is_file():
        raise FileNotFoundError(f"no slave file {slave_file}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    module = fmu_module_name(slave_file)
    with tempfile.TemporaryDirectory(prefix="toggle_fmu_") as tmp:
        script = Path(tmp) / f"{module}.py"
        shutil.copy2(slave_file, script)
        try:
            fmu = FmuBuilder.build_FMU(
                script, dest=out_dir, project_files=[Path(p) for p in project_files]
            )
        finally:  # FmuBuilder imports the script and leaves it on sys.path/sys.modules
            sys.modules.pop(module, None)
            while tmp in sys.path:
                sys.path.remove(tmp)
    problems = validate_fmu(str(fmu))
    if problems:
        raise RuntimeError(f"{fmu} is not a valid FMU:\n" + "\n".join(problems))
    return Path(fmu)
