"""Native FMI 2.0 Co-Simulation FMU: the plant generated to C, no Python at run time.

:func:`build_native_fmu` evaluates :func:`toggle.plant.plant_outputs` on
CasADi symbols, with the dimensions of both halves, the pin friction, the
masses, the drive's inertias and the mold-contact position as *inputs* of the
generated functions,
so one binary serves a preset and all its parameter variants. Four variants
are generated (with and without mold, equal and unequal halves: the plant's
own branches on ``x_contact`` and ``Mechanism.symmetric``) plus the geometry
of a half (theta3, theta4 minus its toggle value) from which the C wrapper
finds the toggle and the assemblable range at initialisation, as
:mod:`toggle.kinematics` does. The FMI layer is fmu_src/native/fmi2_clamp.c;
the preset's constants and the variable table go into a generated header.
The variable list is the pythonfmu slave's ``ToggleClamp.VARIABLES``.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import subprocess
import sys
import tempfile
import uuid
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple
from xml.etree.ElementTree import Element, SubElement, indent, tostring

import casadi as ca
import numpy as np

from fmu_src.build import DEFAULT_SLAVE
from fmu_src.c_code import c_string, fmi_headers
from fmu_src.description import (
    check_variables,
    real_attributes,
    unit_definitions,
)
from fmu_src.description import number_text as _number
from fmu_src.structure import (
    DRIVE_FIELDS,
    MASS_FIELDS,
    ME_STATES,
    N_MASSES,
    Dependencies,
    plant_functions,
    structure_dependencies,
)
from fmu_src.variables import Var
from toggle.kinematics import half_pose
from toggle.params import (
    DIMENSIONS,
    HALVES,
    PAPER_NAMES,
    load_preset,
)
from toggle.plant import (
    NO_MOLD_TOLERANCE,
    PlantConfig,
    PlantOutputs,
    configure,
)

MODEL = "ToggleClampNative"
C_DIR = Path(__file__).resolve().parent / "native"
#: The hand-written C files: the core (its files to compile, then its headers), the drive
#: lag, and one API file per FMI version.
CORE_SOURCES = ("clamp_core.c", "clamp_init.c", "clamp_motion.c", "clamp_state.c", "drive_lag.c")
CORE_FILES = (*CORE_SOURCES, "clamp_core.h", "clamp_core_internal.h", "drive_lag.h")
API_FILES = {2: "fmi2_clamp.c", 3: "fmi3_clamp.c"}
GENERATED = "clamp_model"  # clamp_model.c / clamp_model.h
#: A GNU ld / lld linker script ``INPUT(-lm)`` named as an object file: listed last among
#: the sources, it makes any build that links the listed files link libm, including fmpy's
#: CMake route (``fmpy compile``), which compiles the sources but ignores ``<Library>``.
LINK_LIBM = "link_libm.o"
FMI_VERSIONS = (2, 3)
INTERFACES = ("cs", "me", "both")
#: Value reference of the String ``preset``: FMI 2.0 numbers each type apart, FMI 3.0 needs
#: references unique across types (the Reals are 0 .. n-1); FMI 3.0's ``time`` is one more.
PRESET_VR = {2: 0, 3: 1000}
#: drive_bandwidth's start value in a Model Exchange build when the table's is 0, Hz
ME_BANDWIDTH = 20.0
TIME_VR = 1001
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-fvisibility=hidden")
#: CasADi's generated functions all take (arg, res, iw, w, mem), used or not.
GENERATED_CFLAGS = ("-Wno-unused-parameter",)


def geometry_function() -> ca.Function:
    """(x, dims[8]) -> (theta3, theta4 - asin(e / (r4b + r5))); NaN where a half cannot assemble."""
    x, p = ca.SX.sym("x"), ca.SX.sym("dims", len(DIMENSIONS))
    dims = ca.vertsplit(p)
    pose = half_pose(x, dims, check=False)
    r4b, r5, e = dims[4], dims[6], dims[7]
    return ca.Function("tgc_geometry", [x, p],
                       [ca.vertcat(pose.theta3, pose.theta4 - np.arcsin(e / (r4b + r5)))],
                       ["x", "dims"], ["g"], {"cse": True})


def real_variables(variables: Sequence[Var]) -> list[Var]:
    return [v for v in variables if not v.is_string]


def _roles(variables: Sequence[Var]) -> dict[str, int]:
    """C macro name -> value reference of every Real variable the wrapper must know."""
    reals = real_variables(variables)
    vr = {v.name: i for i, v in enumerate(reals)}
    # dims[8 * half + i] = nominal + delta of DIMENSIONS[i] of that half, in the wrapper
    errors = [f"delta_{PAPER_NAMES[half][dim]}" for half in HALVES for dim in DIMENSIONS]
    known = {"mu", "x_contact", *MASS_FIELDS, *DRIVE_FIELDS, "drive_bandwidth",
             "drive_damping", "x_cmd",
             *errors, *PlantOutputs._fields}
    unknown = sorted(set(vr) - known)
    missing = sorted(known - set(vr))
    if unknown or missing:
        raise ValueError(f"the native FMU does not know variables {unknown}; lacks {missing}")
    roles = {"VR_MU": vr["mu"], "VR_X_CONTACT": vr["x_contact"],
             "VR_BANDWIDTH": vr["drive_bandwidth"], "VR_DAMPING": vr["drive_damping"],
             "VR_X_CMD": vr["x_cmd"], "VR_MASS0": vr["m_crosshead"],
             "VR_DELTA0": vr[errors[0]], "VR_OUT0": vr[PlantOutputs._fields[0]]}
    # the wrapper indexes masses, errors and outputs from their first reference
    for first, names in (("VR_MASS0", [*MASS_FIELDS, *DRIVE_FIELDS]), ("VR_DELTA0", errors),
                         ("VR_OUT0", list(PlantOutputs._fields))):
        if [vr[n] - roles[first] for n in names] != list(range(len(names))):
            raise ValueError(f"variables {names} must be consecutive in the table")
    return roles


def _c_array(values: Sequence[float]) -> str:
    return "{" + ", ".join(repr(float(v)) for v in values) + "}"


def model_header(cfg: PlantConfig, preset: str, variables: Sequence[Var], guid: str,
                 functions: Sequence[ca.Function], fmi_version: int = 2,
                 interface: str = "cs") -> str:
    """clamp_model_data.h: the preset's constants, the variable table and work sizes."""
    mech = cfg.mechanism
    reals = real_variables(variables)
    roles = _roles(variables)
    sizes = {k: max(getattr(f, k)() for f in functions) for k in ("sz_arg", "sz_res", "sz_iw",
                                                                   "sz_w")}
    lines = [
        "/* Generated by fmu_src.native_build: the preset's constants and the variable table. */",
        "#ifndef CLAMP_MODEL_DATA_H", "#define CLAMP_MODEL_DATA_H",
        f"#define CLAMP_GUID {c_string(guid)}",
        f"#define CLAMP_PRESET {c_string(preset)}",
        f"#define CLAMP_VR_PRESET {PRESET_VR[fmi_version]}",
        f"#define CLAMP_HAS_CS {int(interface in ('cs', 'both'))}",
        f"#define CLAMP_HAS_ME {int(interface in ('me', 'both'))}",
        f"#define CLAMP_N_REAL {len(reals)}",
        f"#define CLAMP_N_OUT {len(PlantOutputs._fields)}",
        f"#define CLAMP_N_DIMS {len(DIMENSIONS)}",
        f"#define CLAMP_N_MASSES {N_MASSES}",
        f"#define CLAMP_SLIP_DISTANCE {cfg.asymmetry.slip_distance!r}",
        f"#define CLAMP_NO_MOLD_TOLERANCE {NO_MOLD_TOLERANCE!r}",
        *(f"#define {k} {v}" for k, v in roles.items()),
        *(f"#define CLAMP_{k.upper()} {v}" for k, v in sizes.items()),
        f"static const double CLAMP_NOMINAL[2 * CLAMP_N_DIMS] = "
        f"{_c_array(mech.lower.as_tuple() + mech.upper.as_tuple())};",
        "static const double CLAMP_MIN[CLAMP_N_REAL] = "
        f"{_c_array([-sys.float_info.max if v.min is None else v.min for v in reals])};",
        "static const double CLAMP_MAX[CLAMP_N_REAL] = "
        f"{_c_array([sys.float_info.max if v.max is None else v.max for v in reals])};",
        "static const double CLAMP_START[CLAMP_N_REAL] = "
        f"{_c_array([v.initial_value for v in reals])};",
        "static const double CLAMP_STATE_NOMINAL[3] = "
        f"{_c_array([_nominal(reals, state) for state, _, _ in ME_STATES])};",
        "static const char *const CLAMP_NAMES[CLAMP_N_REAL] = {"
        + ", ".join(c_string(v.name) for v in reals) + "};",
        "static const char *const CLAMP_UNITS[CLAMP_N_REAL] = {"
        + ", ".join(c_string(v.unit) for v in reals) + "};",
        "#endif", "",
    ]
    return "\n".join(lines)


def _nominal(reals: Sequence[Var], name: str) -> float:
    """A continuous state's nominal: its variable's, 1 for the slip state (a local)."""
    return next((v.nominal for v in reals if v.name == name and v.nominal is not None), 1.0)


def model_name(fmi_version: int = 2, interface: str = "cs") -> str:
    """Model identifier and file stem: ToggleClampNative[3][ME|CSME] (FMI 2.0 CS: plain)."""
    if fmi_version not in FMI_VERSIONS or interface not in INTERFACES:
        raise ValueError(f"FMI version {fmi_version!r} / interface {interface!r}: choose "
                         f"{FMI_VERSIONS} and {INTERFACES}")
    return MODEL + ("3" if fmi_version == 3 else "") + {"cs": "", "me": "ME",
                                                        "both": "CSME"}[interface]


class _Row(NamedTuple):
    """One Real or String variable of the description: the table's, or a Model Exchange
    local (the slip state, the derivatives)."""

    var: Var | None
    name: str
    vr: int
    causality: str
    unit: str | None
    derivative_of: str | None = None
    description: str = ""
    bounds: tuple[float, float, float] | None = None  # min, max, nominal of a local


def _rows(variables: Sequence[Var], fmi_version: int, me: bool) -> list[_Row]:
    rows, vr = [], 0
    for var in variables:
        if var.is_string:
            rows.append(_Row(var, var.name, PRESET_VR[fmi_version], var.causality, None))
        else:
            rows.append(_Row(var, var.name, vr, var.causality, var.unit))
            vr += 1
    if me:
        rows.append(_Row(None, "slip_state", vr, "local", "1", None,
                         "Slip state z of the pin friction (Dahl), in [-1, 1]", (-1.0, 1.0, 1.0)))
        for k, (state, der, unit) in enumerate(ME_STATES):
            rows.append(_Row(None, der, vr + 1 + k, "local", unit, state,
                             f"Time derivative of {state}"))
    return rows


def _description_root(fmi_version: int, name: str, guid: str, description: str) -> Element:
    from fmu_src.description import project_version

    attrib = {"fmiVersion": f"{fmi_version}.0", "modelName": name, "description": description,
              "generationTool": "toggle-clamp native_fmu (CasADi codegen)",
              "version": project_version(), "copyright": "Copyright (c) the toggle-clamp "
              "authors", "license": "MIT", "variableNamingConvention": "structured"}
    if fmi_version == 2:
        attrib |= {"guid": guid, "numberOfEventIndicators": "0"}
    else:
        attrib["instantiationToken"] = guid
    return Element("fmiModelDescription", attrib)


def _interfaces(root: Element, fmi_version: int, name: str, interface: str,
                sources: Sequence[str]) -> None:
    state = "FMUstate" if fmi_version == 2 else "FMUState"
    common = {"modelIdentifier": name, "needsExecutionTool": "false",
              "canBeInstantiatedOnlyOncePerProcess": "false",
              f"canGetAndSet{state}": "true", f"canSerialize{state}": "true",
              "providesDirectionalDerivative": "false"}
    if fmi_version == 2:
        common["canNotUseMemoryManagementFunctions"] = "true"
    else:
        common["providesDirectionalDerivatives"] = common.pop("providesDirectionalDerivative")
    if interface in ("me", "both"):  # the FMI 2.0 schema wants ModelExchange first
        me = SubElement(root, "ModelExchange", common | (
            {"completedIntegratorStepNotNeeded": "true"} if fmi_version == 2
            else {"needsCompletedIntegratorStep": "false"}))
        if fmi_version == 2:
            _source_files(me, sources)
    if interface in ("cs", "both"):
        cs = {"canHandleVariableCommunicationStepSize": "true"}
        if fmi_version == 2:
            cs |= {"canInterpolateInputs": "true", "maxOutputDerivativeOrder": "0"}
        else:
            cs |= {"hasEventMode": "false", "providesIntermediateUpdate": "false",
                   "canReturnEarlyAfterIntermediateUpdate": "false"}
        node = SubElement(root, "CoSimulation", common | cs)
        if fmi_version == 2:
            _source_files(node, sources)


def _source_files(node: Element, sources: Sequence[str]) -> None:
    files = SubElement(node, "SourceFiles")
    for source in sources:
        SubElement(files, "File", name=source)


def model_description(variables: Sequence[Var], guid: str, sources: Sequence[str],
                      description: str, step_size: float, stop_time: float,
                      fmi_version: int = 2, interface: str = "cs",
                      dependencies: Dependencies | None = None) -> bytes:
    """modelDescription.xml of the native FMU: the pythonfmu FMU's variables; with Model
    Exchange also the slip state and the derivatives of the three continuous states.
    ``dependencies``: ModelStructure's (default: :func:`structure_dependencies` of the
    chang2021 plant; the structure is that of every preset)."""
    if dependencies is None:
        dependencies = structure_dependencies(configure("chang2021"))
    check_variables(variables)
    name = model_name(fmi_version, interface)
    me = interface in ("me", "both")
    rows = _rows(variables, fmi_version, me)
    root = _description_root(fmi_version, name, guid, description)
    _interfaces(root, fmi_version, name, interface, sources)
    time_unit = {"s"} if fmi_version == 3 else set()  # FMI 3.0's independent variable
    root.append(unit_definitions({r.unit for r in rows if r.unit} | time_unit))
    cats = SubElement(root, "LogCategories")
    SubElement(cats, "Category", name="logStatusError", description="Errors and rejected input")
    SubElement(cats, "Category", name="logAll", description="Other messages")
    SubElement(root, "DefaultExperiment", startTime="0.0", stopTime=_number(stop_time),
               stepSize=_number(step_size))
    scalars = SubElement(root, "ModelVariables")
    by_name = {r.name: r for r in rows}
    if fmi_version == 3:
        SubElement(scalars, "Float64", name="time", valueReference=str(TIME_VR),
                   causality="independent", variability="continuous",
                   description="Simulation time", unit="s")
    for row in rows:
        (_fmi2_variable if fmi_version == 2 else _fmi3_variable)(scalars, row, by_name)
    root.append((_fmi2_structure if fmi_version == 2 else _fmi3_structure)(rows, me,
                                                                          dependencies))
    indent(root, "  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8") + b"\n"


def _variability(row: _Row) -> str:
    if row.var is not None and row.var.variability:
        return row.var.variability
    return "fixed" if row.causality == "parameter" else "continuous"


def _limits(row: _Row) -> dict[str, str]:
    """unit, quantity, displayUnit, min, max and nominal of a Real row."""
    out = {"unit": row.unit} if row.unit else {}
    var = row.var
    if var is not None:
        out |= {a: _number(getattr(var, a)) for a in ("min", "max") if getattr(var, a) is not None}
    elif row.bounds is not None:
        out |= {"min": _number(row.bounds[0]), "max": _number(row.bounds[1])}
    nominal = var.nominal if var is not None else row.bounds[2] if row.bounds else None
    return out | (real_attributes(row.unit, nominal) if row.unit else {})


def _fmi2_variable(scalars: Element, row: _Row, by_name: dict[str, _Row]) -> None:
    description = row.var.description if row.var else row.description
    attrib = {"name": row.name, "valueReference": str(row.vr), "causality": row.causality,
              "variability": _variability(row), "description": description}
    if row.causality in ("output", "local"):
        attrib["initial"] = "calculated"
    node = SubElement(scalars, "ScalarVariable", attrib)
    if row.var is not None and row.var.is_string:
        SubElement(node, "String", start=row.var.start)
        return
    real = _limits(row)
    if row.var is not None and row.var.start is not None:
        real["start"] = _number(row.var.start)
    if row.derivative_of:
        real["derivative"] = str(list(by_name).index(row.derivative_of) + 1)
    SubElement(node, "Real", real)


def _fmi3_variable(scalars: Element, row: _Row, by_name: dict[str, _Row]) -> None:
    description = row.var.description if row.var else row.description
    attrib = {"name": row.name, "valueReference": str(row.vr), "causality": row.causality,
              "variability": _variability(row), "description": description}
    if row.var is not None and row.var.is_string:
        node = SubElement(scalars, "String", attrib)
        SubElement(node, "Start", value=row.var.start)
        return
    if row.causality in ("output", "local"):
        attrib["initial"] = "calculated"
    attrib |= _limits(row)
    if row.var is not None and row.var.start is not None:
        attrib["start"] = _number(row.var.start)
    if row.derivative_of:
        attrib["derivative"] = str(by_name[row.derivative_of].vr)
    SubElement(scalars, "Float64", attrib)


def _unknowns(rows: Sequence[_Row], me: bool) -> tuple[list[_Row], list[_Row], list[_Row]]:
    """The outputs, the state derivatives (Model Exchange) and the initial unknowns."""
    outputs = [r for r in rows if r.causality == "output"]
    derivatives = [r for r in rows if r.derivative_of] if me else []
    initial = [r for r in rows if r.causality == "output" or (me and r.causality == "local")]
    return outputs, derivatives, initial


def _run_dependencies(row: _Row, me: bool, deps: Dependencies) -> tuple[str, ...]:
    """An output's or derivative's direct dependencies on states and input: in
    Co-Simulation none (the outputs are computed in doStep), with Model Exchange the
    sparsity's (the acceleration, forces and torque depend on x_cmd through the lag)."""
    return deps.run[row.name] if me else ()


def _fmi2_structure(rows: Sequence[_Row], me: bool, deps: Dependencies) -> Element:
    """Outputs, Derivatives and InitialUnknowns with their dependencies (indices)."""
    index = {r.name: i + 1 for i, r in enumerate(rows)}
    # a dependency on a state is one on the state variable (x, velocity, slip_state)
    outputs, derivatives, initial = _unknowns(rows, me)
    node = Element("ModelStructure")

    def unknown(parent: Element, row: _Row, names: Sequence[str]) -> None:
        SubElement(parent, "Unknown", index=str(index[row.name]),
                   dependencies=" ".join(str(index[n]) for n in names))

    out_node = SubElement(node, "Outputs")
    for row in outputs:
        unknown(out_node, row, _run_dependencies(row, me, deps))
    if me:
        der_node = SubElement(node, "Derivatives")
        for row in derivatives:
            unknown(der_node, row, deps.run[row.name])
    init_node = SubElement(node, "InitialUnknowns")
    for row in sorted(initial, key=lambda r: index[r.name]):
        unknown(init_node, row, deps.init[row.name])
    return node


def _fmi3_structure(rows: Sequence[_Row], me: bool, deps: Dependencies) -> Element:
    """Output, ContinuousStateDerivative and InitialUnknown with their dependencies
    (value references)."""
    vr = {r.name: r.vr for r in rows}
    outputs, derivatives, initial = _unknowns(rows, me)
    node = Element("ModelStructure")

    def unknown(tag: str, row: _Row, names: Sequence[str]) -> None:
        SubElement(node, tag, valueReference=str(row.vr),
                   dependencies=" ".join(str(vr[n]) for n in names))

    for row in outputs:
        unknown("Output", row, _run_dependencies(row, me, deps))
    for row in derivatives:
        unknown("ContinuousStateDerivative", row, deps.run[row.name])
    for row in initial:
        unknown("InitialUnknown", row, deps.init[row.name])
    return node


def build_description(name: str, sources: Sequence[str]) -> bytes:
    """sources/buildDescription.xml: what an importing tool compiles, and how."""
    root = Element("fmiBuildDescription", fmiVersion="3.0")
    config = SubElement(root, "BuildConfiguration", modelIdentifier=name,
                        description="C99; link with libm")
    files = SubElement(config, "SourceFileSet", language="C99")
    for source in sources:
        SubElement(files, "SourceFile", name=source)
    SubElement(config, "Library", name="m")
    indent(root, "  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8") + b"\n"


def slave_variables(preset: str = "chang2021") -> tuple[tuple[Var, ...], str, Any]:
    """Variables (for ``preset``), description and default experiment of the pythonfmu
    ToggleClamp slave: both FMUs of a preset have the same variables."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("toggle_native_slave_table", DEFAULT_SLAVE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    slave = module.ToggleClamp
    return module.variables(load_preset(preset)), slave.description, slave.default_experiment


def interface_variables(variables: Sequence[Var], interface: str) -> tuple[Var, ...]:
    """The table as an FMU with this interface declares it: with Model Exchange, whose
    continuous state is the drive lag, an ideal-drive default (drive_bandwidth start 0)
    becomes :data:`ME_BANDWIDTH`, so the FMU initialises with its start values (the
    Compliance Checker sets none)."""
    if interface == "cs":
        return tuple(variables)
    return tuple(dataclasses.replace(v, start=ME_BANDWIDTH)
                 if v.name == "drive_bandwidth" and v.start == 0 else v for v in variables)


def generate_sources(folder: Path, preset: str, fmi_version: int = 2,
                     interface: str = "cs") -> tuple[list[str], str]:
    """Write the C sources (generated model, data header, core, API) into ``folder``.

    Returns the names of the C files to compile and the model's GUID (the FMU lists
    :data:`LINK_LIBM` after them).
    """
    variables = interface_variables(slave_variables(preset)[0], interface)
    cfg = configure(preset)
    functions = plant_functions(cfg)
    gen = ca.CodeGenerator(f"{GENERATED}.c", {"with_header": True, "with_export": False,
                                              "casadi_real": "double", "casadi_int": "long"})
    for f in (*functions, geometry_function()):
        gen.add(f)
    gen.generate(str(folder) + "/")
    name = model_name(fmi_version, interface)
    guid = str(uuid.uuid5(uuid.NAMESPACE_URL, f"toggle-clamp/{name}/{preset}/{variables!r}/"
                          + (folder / f"{GENERATED}.c").read_text()))  # same model, same GUID
    (folder / "clamp_model_data.h").write_text(
        model_header(cfg, preset, variables, guid, functions, fmi_version, interface))
    api = API_FILES[fmi_version]
    for file in (*CORE_FILES, api):
        shutil.copy2(C_DIR / file, folder / file)
    return [api, *CORE_SOURCES, f"{GENERATED}.c"], guid


def _run(cmd: list[str]) -> None:
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode:
        raise RuntimeError(f"gcc failed:\n{' '.join(cmd)}\n{result.stderr}")


def compile_library(src: Path, sources: Sequence[str], out: Path, fmi_version: int = 2) -> None:
    """gcc the sources into a shared library; any warning is an error. The link line is
    the listed files only, as an importing tool's: libm comes from :data:`LINK_LIBM`."""
    objects = []
    for name in sources:
        if name.endswith(".o"):  # LINK_LIBM, in its place (last)
            objects.append(str(src / name))
            continue
        extra = GENERATED_CFLAGS if name.startswith(GENERATED) else ()
        obj = out.parent / f"{Path(name).stem}.o"
        _run(["gcc", *CFLAGS, *extra, "-I", str(src), "-I", str(fmi_headers(fmi_version)), "-c",
              str(src / name), "-o", str(obj)])
        objects.append(str(obj))
    _run(["gcc", "-shared", *objects, "-o", str(out)])  # libm through LINK_LIBM


def build_native_fmu(out_dir: Path, preset: str = "chang2021", fmi_version: int = 2,
                     interface: str = "cs") -> Path:
    """Build ``<out_dir>/<model_name(fmi_version, interface)>.fmu`` for ``preset``.

    Raises RuntimeError if gcc fails or fmpy's validator finds problems.
    """
    from fmpy.validation import validate_fmu

    name = model_name(fmi_version, interface)
    variables, description, experiment = slave_variables(preset)  # a bad name fails here
    variables = interface_variables(variables, interface)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fmu = out_dir / f"{name}.fmu"
    platform = "linux64" if fmi_version == 2 else "x86_64-linux"
    with tempfile.TemporaryDirectory(prefix="toggle_native_") as tmp:
        src = Path(tmp) / "sources"
        src.mkdir()
        sources, guid = generate_sources(src, preset, fmi_version, interface)
        shutil.copy2(C_DIR / LINK_LIBM, src / LINK_LIBM)
        sources.append(LINK_LIBM)
        library = Path(tmp) / f"{name}.so"
        compile_library(src, sources, library, fmi_version)
        stop = experiment.stop_time if math.isfinite(experiment.stop_time) else 10.0
        dependencies = structure_dependencies(configure(preset))
        with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("modelDescription.xml", model_description(
                variables, guid, sources, description, experiment.step_size, stop,
                fmi_version, interface, dependencies))
            zf.write(library, f"binaries/{platform}/{name}.so")
            for path in sorted(src.iterdir()):
                zf.write(path, f"sources/{path.name}")
            zf.writestr("sources/buildDescription.xml", build_description(name, sources))
    problems = validate_fmu(str(fmu))
    if problems:
        raise RuntimeError(f"{fmu} is not a valid FMU:\n" + "\n".join(problems))
    return fmu
