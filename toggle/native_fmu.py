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

from toggle.fmu_build import (
    DEFAULT_SLAVE,
    check_variables,
    model_structure,
    unit_definitions,
)
from toggle.fmu_build import number_text as _number
from toggle.fmu_slave import Var
from toggle.kinematics import half_pose
from toggle.params import (
    DIMENSIONS,
    DYNAMICS_PARAMETERS,
    HALVES,
    PAPER_NAMES,
    load_preset,
    symbolic_copy,
)
from toggle.plant import (
    NO_MOLD_TOLERANCE,
    PlantConfig,
    PlantOutputs,
    configure,
    plant_outputs,
)

MODEL = "ToggleClampNative"
C_DIR = Path(__file__).resolve().parent.parent / "fmu_src" / "native"
WRAPPER = C_DIR / "fmi2_clamp.c"
GENERATED = "clamp_model"  # clamp_model.c / clamp_model.h
#: The [dynamics] fields by FMU parameter name, first in the generated functions' ``masses``.
MASS_FIELDS = {name: field for name, (field, _, _) in DYNAMICS_PARAMETERS.items()}
#: The drive's inertias, after the masses in the generated functions' ``masses`` input.
DRIVE_FIELDS = ("rotor_inertia", "screw_inertia")
N_MASSES = len(MASS_FIELDS) + len(DRIVE_FIELDS)
#: Names of the generated functions, indexed by (mold, unequal halves) in the C wrapper.
VARIANTS = ("tgc_free_equal", "tgc_free_unequal", "tgc_mold_equal", "tgc_mold_unequal")
CFLAGS = ("-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-fvisibility=hidden")
#: CasADi's generated functions all take (arg, res, iw, w, mem), used or not.
GENERATED_CFLAGS = ("-Wno-unused-parameter",)


class _SymbolicHalf(NamedTuple):
    """Eight symbolic dimensions of one half, in :data:`toggle.params.DIMENSIONS` order.

    Two halves are equal only if they are the same object, so the plant's
    ``Mechanism.symmetric`` decides between the generated variants.
    """

    r1: Any
    r2: Any
    r3: Any
    r4a: Any
    r4b: Any
    r4c: Any
    r5: Any
    e: Any

    def as_tuple(self) -> tuple[Any, ...]:
        return tuple(self)

    def __eq__(self, other: object) -> bool:
        return self is other

    def __hash__(self) -> int:
        return id(self)


def plant_functions(cfg: PlantConfig) -> list[ca.Function]:
    """The plant as CasADi functions (xvaz[4], lower[8], upper[8], mu, masses, x_contact);
    xvaz: position, velocity, acceleration and the pin friction's slip state; masses: the
    fields of :data:`MASS_FIELDS`, then the drive's inertias (:data:`DRIVE_FIELDS`)."""
    xva = ca.SX.sym("xvaz", 4)
    p_lower, p_upper = (ca.SX.sym(h, len(DIMENSIONS)) for h in HALVES)
    mu, masses, x_contact = (ca.SX.sym("mu"), ca.SX.sym("masses", N_MASSES),
                             ca.SX.sym("x_contact"))
    lower = _SymbolicHalf(*ca.vertsplit(p_lower))
    values = ca.vertsplit(masses)
    dynamics = symbolic_copy(cfg.dynamics, **dict(zip(MASS_FIELDS.values(), values)))
    drive = symbolic_copy(cfg.mechanism.drive, **dict(zip(DRIVE_FIELDS,
                                                         values[len(MASS_FIELDS):])))
    functions = []
    for name in VARIANTS:
        upper = lower if name.endswith("_equal") else _SymbolicHalf(*ca.vertsplit(p_upper))
        mech = dataclasses.replace(cfg.mechanism, lower=lower, upper=upper, dynamics=dynamics,
                                   drive=drive)
        mold = "_mold" in name  # the no-mold variant ignores its x_contact input
        sym_cfg = symbolic_copy(cfg, mechanism=mech, mu=mu, x_contact=None)
        outs = plant_outputs(xva[0], xva[1], xva[2], sym_cfg, x_contact if mold else None,
                             slip_state=xva[3])
        functions.append(ca.Function(
            name, [xva, p_lower, p_upper, mu, masses, x_contact],
            [ca.vertcat(*[ca.SX(o) for o in outs])],
            ["xvaz", "lower", "upper", "mu", "masses", "x_contact"], ["y"], {"cse": True}))
    return functions


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


def c_string(text: str) -> str:
    """A C string literal of ``text``."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def model_header(cfg: PlantConfig, preset: str, variables: Sequence[Var], guid: str,
                 functions: Sequence[ca.Function]) -> str:
    """clamp_model_data.h: the preset's constants, the variable table and work sizes."""
    mech = cfg.mechanism
    reals = real_variables(variables)
    roles = _roles(variables)
    sizes = {k: max(getattr(f, k)() for f in functions) for k in ("sz_arg", "sz_res", "sz_iw",
                                                                   "sz_w")}
    lines = [
        "/* Generated by toggle.native_fmu: the preset's constants and the variable table. */",
        "#ifndef CLAMP_MODEL_DATA_H", "#define CLAMP_MODEL_DATA_H",
        f"#define CLAMP_GUID {c_string(guid)}",
        f"#define CLAMP_PRESET {c_string(preset)}",
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
        "static const char *const CLAMP_NAMES[CLAMP_N_REAL] = {"
        + ", ".join(c_string(v.name) for v in reals) + "};",
        "#endif", "",
    ]
    return "\n".join(lines)


def model_description(variables: Sequence[Var], guid: str, sources: Sequence[str],
                      description: str, step_size: float, stop_time: float) -> bytes:
    """modelDescription.xml of the native FMU (the same variables as the pythonfmu FMU)."""
    check_variables(variables)
    root = Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": MODEL, "guid": guid, "description": description,
        "generationTool": "toggle-clamp native_fmu (CasADi codegen)",
        "variableNamingConvention": "structured", "numberOfEventIndicators": "0"})
    cosim = SubElement(root, "CoSimulation", {
        "modelIdentifier": MODEL, "needsExecutionTool": "false",
        "canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions":
        "true", "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "false"})
    files = SubElement(cosim, "SourceFiles")
    for name in sources:
        SubElement(files, "File", name=name)
    root.append(unit_definitions({v.unit for v in variables if not v.is_string}))
    cats = SubElement(root, "LogCategories")
    SubElement(cats, "Category", name="logStatusError", description="Errors and rejected input")
    SubElement(root, "DefaultExperiment", startTime="0.0", stopTime=_number(stop_time),
               stepSize=_number(step_size))
    scalars = SubElement(root, "ModelVariables")
    real_vr = 0
    for var in variables:
        attrib = {"name": var.name, "causality": var.causality,
                  "variability": var.variability or ("fixed" if var.causality == "parameter"
                                                     else "continuous"),
                  "description": var.description}
        if var.is_string:
            attrib["valueReference"] = "0"
            node = SubElement(scalars, "ScalarVariable", attrib)
            SubElement(node, "String", start=var.start)
            continue
        attrib["valueReference"] = str(real_vr)
        real_vr += 1
        if var.causality == "output":
            attrib["initial"] = "calculated"
        node = SubElement(scalars, "ScalarVariable", attrib)
        real = {"unit": var.unit}
        for attr in ("min", "max"):
            if getattr(var, attr) is not None:
                real[attr] = _number(getattr(var, attr))
        if var.start is not None:
            real["start"] = _number(var.start)
        SubElement(node, "Real", real)
    root.append(model_structure(variables))
    indent(root, "  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8") + b"\n"


def build_description(sources: Sequence[str]) -> bytes:
    """sources/buildDescription.xml: what an importing tool compiles, and how."""
    root = Element("fmiBuildDescription", fmiVersion="3.0")
    config = SubElement(root, "BuildConfiguration", modelIdentifier=MODEL,
                        description="C99; link with libm")
    files = SubElement(config, "SourceFileSet", language="C99")
    for name in sources:
        SubElement(files, "SourceFile", name=name)
    SubElement(config, "Library", name="m")
    indent(root, "  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8") + b"\n"


def fmi2_headers() -> Path:
    """The folder of the FMI 2.0 headers shipped inside the installed fmpy."""
    import fmpy

    folder = Path(fmpy.__file__).resolve().parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise FileNotFoundError(f"no fmi2Functions.h in {folder}: fmpy installation incomplete")
    return folder


def slave_variables(preset: str = "chang2021") -> tuple[tuple[Var, ...], str, Any]:
    """Variables (for ``preset``), description and default experiment of the pythonfmu
    ToggleClamp slave: both FMUs of a preset have the same variables."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("toggle_native_slave_table", DEFAULT_SLAVE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    slave = module.ToggleClamp
    return module.variables(load_preset(preset)), slave.description, slave.default_experiment


def generate_sources(folder: Path, preset: str) -> tuple[list[str], str]:
    """Write the C sources (generated model, data header, wrapper) into ``folder``.

    Returns the names of the files to compile and the model's GUID.
    """
    variables, _, _ = slave_variables(preset)
    cfg = configure(preset)
    functions = plant_functions(cfg)
    gen = ca.CodeGenerator(f"{GENERATED}.c", {"with_header": True, "with_export": False,
                                              "casadi_real": "double", "casadi_int": "long"})
    for f in (*functions, geometry_function()):
        gen.add(f)
    gen.generate(str(folder) + "/")
    guid = str(uuid.uuid5(uuid.NAMESPACE_URL, f"toggle-clamp/{MODEL}/{preset}/{variables!r}/"
                          + (folder / f"{GENERATED}.c").read_text()))  # same model, same GUID
    (folder / "clamp_model_data.h").write_text(
        model_header(cfg, preset, variables, guid, functions))
    shutil.copy2(WRAPPER, folder / WRAPPER.name)
    return [WRAPPER.name, f"{GENERATED}.c"], guid


def _run(cmd: list[str]) -> None:
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode:
        raise RuntimeError(f"gcc failed:\n{' '.join(cmd)}\n{result.stderr}")


def compile_library(src: Path, sources: Sequence[str], out: Path) -> None:
    """gcc the sources into a shared library; any warning is an error."""
    objects = []
    for name in sources:
        extra = GENERATED_CFLAGS if name.startswith(GENERATED) else ()
        obj = out.parent / f"{Path(name).stem}.o"
        _run(["gcc", *CFLAGS, *extra, "-I", str(src), "-I", str(fmi2_headers()), "-c",
              str(src / name), "-o", str(obj)])
        objects.append(str(obj))
    _run(["gcc", "-shared", *objects, "-o", str(out), "-lm"])


def build_native_fmu(out_dir: Path, preset: str = "chang2021") -> Path:
    """Build ``<out_dir>/ToggleClampNative.fmu`` for ``preset``; return its path.

    Raises RuntimeError if gcc fails or fmpy's validator finds problems.
    """
    from fmpy.validation import validate_fmu

    variables, description, experiment = slave_variables(preset)  # a bad name fails here
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fmu = out_dir / f"{MODEL}.fmu"
    with tempfile.TemporaryDirectory(prefix="toggle_native_") as tmp:
        src = Path(tmp) / "sources"
        src.mkdir()
        sources, guid = generate_sources(src, preset)
        library = Path(tmp) / f"{MODEL}.so"
        compile_library(src, sources, library)
        stop = experiment.stop_time if math.isfinite(experiment.stop_time) else 10.0
        with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("modelDescription.xml", model_description(
                variables, guid, sources, description, experiment.step_size, stop))
            zf.write(library, f"binaries/linux64/{MODEL}.so")
            for path in sorted(src.iterdir()):
                zf.write(path, f"sources/{path.name}")
            zf.writestr("sources/buildDescription.xml", build_description(sources))
    problems = validate_fmu(str(fmu))
    if problems:
        raise RuntimeError(f"{fmu} is not a valid FMU:\n" + "\n".join(problems))
    return fmu
