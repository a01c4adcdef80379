"""The files a cam table is written as (``toggle plan --export cam --format ...``).

* ``csv``: ``# key = value`` lines (what the table was made for, SI), then master,
  slave, slave velocity and slave acceleration with their units; the drive interpolates
  the positions ``linear`` or ``cubic`` (the user's choice: a plain position table).
* ``plcopen``: a PLCopen TC6 XML v2.01 project (namespace :data:`TC6`) for CODESYS
  SoftMotion: a global ``ClampCam_A : ARRAY [0..N-1] OF SMC_CAMXYVA`` (dX, dY, dV, dA:
  LREAL, the master and the slave's position, velocity and acceleration over the
  master), the ``ClampCam : MC_CAM_REF`` describing it (byType 3, XYVA: fifth-order
  polynomials between the points), and a program POU ``ClampCamIn`` whose ST body hands
  ``ClampCam`` to MC_CamTableSelect and couples the slave with MC_CamIn, run by a cyclic
  task at the drive cycle in the resource (``ClampCamTask``, instance ``ClampCamRun``).
  The form is the IEC initialisation code CODESYS's cam editor generates ("Display
  Generated Code").
* ``twincat``: the same project for TwinCAT's NC camming: ``ARRAY [1..N] OF
  MC_MotionFunctionPoint`` (MasterPos, SlavePos, SlaveVelo, SlaveAcc, each segment a
  MOTIONFUNCTYPE_POLYNOM5_MM quintic) and an MC_CAM_REF of table type
  MC_TABLETYPE_MOTIONFUNCTION (:data:`DIALECTS`).
* ``pvt``: a drive's position-velocity-time table in whole encoder counts: one row per
  point at a fixed time step, position (counts) and velocity (counts/s) as integers;
  the drive interpolates each segment with the cubic through both ends' position and
  velocity (``pv-cubic``).

Each file states the drive cycle it was checked for (``drive_cycle``, s) and every cycle
it was checked at (``checked_cycles``: it, 100 us and 125 us, :func:`cam.checked_cycles`);
a ``cubic`` CSV its spline's end conditions (:data:`cam.END_CONDITIONS`). Each file's
creation time is ``SOURCE_DATE_EPOCH`` when set (reproducible exports, the
reproducible-builds convention), else the time of the export, UTC.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import os
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controllers import cam
from controllers.cam import DRIVE_CYCLE, MASTER_UNIT, SLAVE_UNIT, CamTable
from controllers.limits import DriveLimits
from controllers.profiles import Profile
from toggle.files import atomic_path
from toggle.params import ParameterError
from toggle.plant import PlantConfig

FORMATS = ("csv", "plcopen", "twincat", "pvt")
#: How the drive interpolates each format's table; csv: the user's (linear or cubic).
INTERPOLATION = {"plcopen": "pva-quintic", "twincat": "pva-quintic", "pvt": "pv-cubic"}
CSV_INTERPOLATIONS = ("linear", "cubic")
TC6 = "http://www.plcopen.org/xml/tc6_0201"
XHTML = "http://www.w3.org/1999/xhtml"
@dataclass(frozen=True)
class Dialect:
    """A motion library's cam in a PLCopen project: the point type and its members (the
    master, the slave's position, velocity and acceleration among them), the cam
    reference MC_CamTableSelect takes, and the program that selects it and couples."""

    library: str
    point_type: str
    lower: int  # the points array's first index
    xyva: tuple[str, str, str, str]  # the members holding X, Y, V, A
    row: Callable[[int, int, tuple[float, ...]], dict[str, str]]  # index, count, XYVA
    cam_ref: Callable[[int, str], dict[str, str]]  # count, points variable
    program_vars: tuple[tuple[str, str, str, str | None], ...]  # section, name, type, init
    body: str


_AXES = (("inOutVars", "Master", "AXIS_REF", None), ("inOutVars", "Slave", "AXIS_REF", None),
         ("inputVars", "Start", "BOOL", None), ("outputVars", "InSync", "BOOL", None),
         ("outputVars", "Error", "BOOL", None),
         ("externalVars", "ClampCam", "MC_CAM_REF", None),
         ("localVars", "Select", "MC_CamTableSelect", None),
         ("localVars", "Couple", "MC_CamIn", None))
_OUTPUTS = """InSync := Couple.InSync;
Error := Select.Error OR Couple.Error;
"""
#: CODESYS SoftMotion (SM3_Basic): SMC_CAMXYVA points, MC_CAM_REF byType 3 (XYVA);
#: MC_CamTableSelect gives the CamTableID MC_CamIn couples with (PLCopen Part 1).
CODESYS = Dialect(
    "CODESYS SoftMotion SM3_Basic", "SMC_CAMXYVA", 0, ("dX", "dY", "dV", "dA"),
    lambda i, n, xyva: dict(zip(("dX", "dY", "dV", "dA"), map(repr, xyva))),
    lambda n, points: {"nElements": str(n), "byType": "3", "xStart": "{x0}",
                       "xEnd": "{x1}", "nTappets": "0", "strCAMName": "'ClampCam'",
                       "pce": f"ADR({points})"},
    _AXES, """Select(Master := Master, Slave := Slave, CamTable := ClampCam, Execute := Start,
       Periodic := FALSE, MasterAbsolute := TRUE, SlaveAbsolute := FALSE);
Couple(Master := Master, Slave := Slave, Execute := Select.Done,
       CamTableID := Select.CamTableID);
""" + _OUTPUTS)


def _motion_function_point(i: int, n: int, xyva: tuple[float, ...]) -> dict[str, str]:
    """Point ``i`` of ``n``: a motion point (Y, Y', Y'' as given) opening a quintic."""
    return {"PointIndex": str(i + 1), "FunctionType": "MOTIONFUNCTYPE_POLYNOM5_MM",
            "PointType": "MOTIONPOINTTYPE_MOTION", "RelIndexNextPoint": "1",
            **dict(zip(("MasterPos", "SlavePos", "SlaveVelo", "SlaveAcc"), map(repr, xyva))),
            "SlaveJerk": "0.0"}


#: TwinCAT NC camming (Tc2_MC2_Camming): MC_MotionFunctionPoint points joined by
#: fifth-order polynomials (MOTIONFUNCTYPE_POLYNOM5_MM: motion to motion, Y, Y', Y'' at
#: both ends), MC_CAM_REF of table type MC_TABLETYPE_MOTIONFUNCTION; its
#: MC_CamTableSelect and MC_CamIn both take the table's ID.
TWINCAT = Dialect(
    "TwinCAT Tc2_MC2_Camming", "MC_MotionFunctionPoint", 1,
    ("MasterPos", "SlavePos", "SlaveVelo", "SlaveAcc"), _motion_function_point,
    lambda n, points: {"pArray": f"ADR({points})", "ArraySize": f"SIZEOF({points})",
                       "TableType": "MC_TABLETYPE_MOTIONFUNCTION", "NoOfRows": str(n),
                       "NoOfColumns": "1"},
    (*_AXES, ("localVars", "CamId", "MC_CAM_ID", "1")),
    """Select(Master := Master, Slave := Slave, CamTable := ClampCam, Execute := Start,
       Periodic := FALSE, CamTableID := CamId);
Couple(Master := Master, Slave := Slave, Execute := Select.Done, CamTableID := CamId);
""" + _OUTPUTS)
DIALECTS = {"plcopen": CODESYS, "twincat": TWINCAT}

ELEMENTARY = ("BOOL", "LREAL", "INT", "BYTE")


def iec_time(seconds: float) -> str:
    """A duration as an IEC 61131-3 TIME literal in whole microseconds (``T#125us``)."""
    return f"T#{round(seconds * 1e6)}us"


def creation_time() -> dt.datetime:
    """``SOURCE_DATE_EPOCH`` (s since 1970, UTC) when set, else now (UTC, whole seconds)."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch is None:
        return dt.datetime.now(dt.timezone.utc).replace(microsecond=0)
    try:
        return dt.datetime.fromtimestamp(int(epoch), dt.timezone.utc)
    except (ValueError, OverflowError, OSError):
        raise ParameterError(f"SOURCE_DATE_EPOCH must be whole seconds since 1970, got "
                             f"{epoch!r}") from None


def _header(table: CamTable, interpolation: str, settings: dict[str, object],
            cycle: float) -> dict:
    """What the table was made for: the drive cycle it was checked for (s) and every cycle
    it was checked at, the cubic's end conditions."""
    return {**settings, "master": table.kind, "units": table.units,
            "interpolation": interpolation,
            "end_conditions": cam.END_CONDITIONS if interpolation == "cubic" else None,
            "drive_cycle": cycle, "checked_cycles": ", ".join(
                f"{c * 1e6:g} us" for c in cam.checked_cycles(cycle)),
            "duration": table.duration, "x_open": table.x_open,
            "points": int(table.master.size), "created": creation_time().isoformat()}


def _comments(header: dict) -> str:
    return "".join(f"# {key} = {value!r}\n".replace("'", '"') if isinstance(value, str)
                   else f"# {key} = {value}\n" for key, value in header.items()
                   if value is not None)


def _units(table: CamTable) -> tuple[str, str, str, str]:
    m, s = MASTER_UNIT[table.kind], SLAVE_UNIT[table.units]
    return m, s, f"{s}/{m}", f"{s}/{m}^2"


def write_csv(path: str | Path, table: CamTable, interpolation: str,
              settings: dict[str, object], cycle: float = DRIVE_CYCLE) -> None:
    """The table as CSV: ``# key = value`` lines (:func:`_header`), then the four columns
    with units."""
    buffer = io.StringIO()
    buffer.write(_comments(_header(table, interpolation, settings, cycle)))
    m, s, v, a = _units(table)
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow([f"master [{m}]", f"slave [{s}]", f"velocity [{v}]",
                     f"acceleration [{a}]"])
    writer.writerows(zip(*(map(repr, c.tolist()) for c in (
        table.master, table.slave, table.velocity, table.acceleration))))
    Path(path).write_text(buffer.getvalue())


def _columns(path: str | Path) -> tuple[np.ndarray, ...]:
    rows = [r for r in Path(path).read_text().splitlines() if r and not r.startswith("#")]
    return tuple(np.array([[float(v) for v in r.split(",")] for r in rows[1:]]).T)


def read_csv(path: str | Path) -> tuple[np.ndarray, ...]:
    """Master, slave, velocity and acceleration columns of a cam CSV."""
    return _columns(path)


def write_pvt(path: str | Path, table: CamTable, settings: dict[str, object],
              cycle: float = DRIVE_CYCLE) -> None:
    """The table as a PVT drive table: time (s), position (counts) and velocity
    (counts/s), the last two whole numbers; refused unless master time and counts."""
    if table.kind != "time" or table.units != "counts" or not table.whole:
        raise ParameterError("a pvt table is in whole encoder counts over time: "
                             "--master time --units counts")
    buffer = io.StringIO()
    buffer.write(_comments({**_header(table, INTERPOLATION["pvt"], settings, cycle),
                            "time_step": float(table.master[1] - table.master[0])}))
    buffer.write("time [s],position [counts],velocity [counts/s]\n")
    for t, p, v in zip(table.master.tolist(), table.slave.tolist(), table.velocity.tolist()):
        buffer.write(f"{t!r},{int(p)},{int(v)}\n")
    Path(path).write_text(buffer.getvalue())


def read_pvt(path: str | Path) -> tuple[np.ndarray, ...]:
    """Time, position and velocity columns of a PVT table."""
    return _columns(path)


def _sub(parent: ET.Element, tag: str, **attrs: str) -> ET.Element:
    return ET.SubElement(parent, f"{{{TC6}}}{tag}", attrs)


def _text(parent: ET.Element, text: str) -> None:
    """Formatted text (ST, documentation): one ``xhtml`` element in XHTML's namespace."""
    ET.SubElement(parent, f"{{{XHTML}}}xhtml").text = text


def _type(parent: ET.Element, name: str) -> None:
    holder = _sub(parent, "type")
    if name in ELEMENTARY:
        _sub(holder, name)
    else:
        _sub(holder, "derived", name=name)


def _struct_value(parent: ET.Element, members: dict[str, str]) -> None:
    struct = _sub(parent, "structValue")
    for member, value in members.items():
        _sub(_sub(struct, "value", member=member), "simpleValue", value=value)


def plcopen_xml(table: CamTable, settings: dict[str, object], fmt: str = "plcopen",
                name: str = "ClampCam", cycle: float = DRIVE_CYCLE) -> str:
    """The table as a PLCopen TC6 XML v2.01 project for ``fmt``'s motion library
    (:data:`DIALECTS`; module docstring); its resource runs the program in a cyclic task
    at the drive cycle ``cycle`` (s)."""
    dialect = DIALECTS[fmt]
    ET.register_namespace("", TC6)
    ET.register_namespace("xhtml", XHTML)
    root = ET.Element(f"{{{TC6}}}project")
    created = creation_time().replace(tzinfo=None).isoformat()
    _sub(root, "fileHeader", companyName="toggle-clamp", productName="toggle plan",
         productVersion="1", creationDateTime=created,
         contentDescription=f"cam of a planned clamp stroke, {dialect.library}")
    content = _sub(root, "contentHeader", name=name, modificationDateTime=created)
    coordinates = _sub(content, "coordinateInfo")
    for language in ("fbd", "ld", "sfc"):
        _sub(_sub(coordinates, language), "scaling", x="1", y="1")
    types = _sub(root, "types")
    _sub(types, "dataTypes")
    pou = _sub(_sub(types, "pous"), "pou", name=f"{name}In", pouType="program")
    interface = _sub(pou, "interface")
    for section in dict.fromkeys(v[0] for v in dialect.program_vars):
        block = _sub(interface, section)
        for _, var, type_name, initial in (v for v in dialect.program_vars
                                           if v[0] == section):
            variable = _sub(block, "variable", name=var)
            _type(variable, type_name)
            if initial is not None:
                _sub(_sub(variable, "initialValue"), "simpleValue", value=initial)
    _text(_sub(_sub(pou, "body"), "ST"), dialect.body)
    resource = _sub(_sub(_sub(_sub(root, "instances"), "configurations"), "configuration",
                         name="Clamp"), "resource", name="Drive")
    task = _sub(resource, "task", name=f"{name}Task", interval=iec_time(cycle), priority="1")
    _sub(task, "pouInstance", name=f"{name}Run", typeName=f"{name}In")
    variables = _sub(resource, "globalVars", name=f"{name}Data")  # MC_CAM_REF: an FB
    points = _sub(variables, "variable", name=f"{name}_A")
    array = _sub(_sub(points, "type"), "array")
    n = table.master.size
    _sub(array, "dimension", lower=str(dialect.lower), upper=str(dialect.lower + n - 1))
    _sub(_sub(array, "baseType"), "derived", name=dialect.point_type)
    values = _sub(_sub(points, "initialValue"), "arrayValue")
    for i, row in enumerate(zip(*(c.tolist() for c in (
            table.master, table.slave, table.velocity, table.acceleration)))):
        _struct_value(_sub(values, "value"), dialect.row(i, n, row))
    cam = _sub(variables, "variable", name=name)
    _type(cam, "MC_CAM_REF")
    _struct_value(_sub(cam, "initialValue"), {
        k: v.format(x0=repr(float(table.master[0])), x1=repr(float(table.master[-1])))
        for k, v in dialect.cam_ref(n, f"{name}_A").items()})
    m, s, v, a = _units(table)
    text = "; ".join(f"{k} = {value}" for k, value in
                     _header(table, INTERPOLATION[fmt], settings, cycle).items()
                     if value is not None)
    _text(_sub(points, "documentation"), "; ".join(
        f"{member} [{unit}]" for member, unit in zip(dialect.xyva, (m, s, v, a))) + f"; {text}")
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True)


def read_plcopen(text: str, fmt: str = "plcopen", name: str = "ClampCam"
                 ) -> tuple[np.ndarray, ...]:
    """X, Y, V and A of the points of a project written by :func:`plcopen_xml`."""
    root = ET.fromstring(text)
    ns = {"p": TC6}
    points = root.findall(f".//p:variable[@name='{name}_A']/p:initialValue/p:arrayValue/"
                          "p:value/p:structValue", ns)
    data = [[float(p.find(f"p:value[@member='{m}']/p:simpleValue", ns).get("value"))
             for m in DIALECTS[fmt].xyva] for p in points]
    return tuple(np.array(data).T)


def program_st(text: str) -> str:
    """The program POU of a PLCopen project as Structured Text (its interface's sections
    and its ST body), for an ST compiler to check."""
    root = ET.fromstring(text)
    ns = {"p": TC6, "x": XHTML}
    sections = {"inputVars": "VAR_INPUT", "outputVars": "VAR_OUTPUT",
                "inOutVars": "VAR_IN_OUT", "externalVars": "VAR_EXTERNAL",
                "localVars": "VAR"}
    pou = root.find(".//p:pou[@pouType='program']", ns)
    lines = [f"PROGRAM {pou.get('name')}"]
    for block in pou.find("p:interface", ns):
        lines.append(sections[block.tag.split("}")[1]])
        for var in block.findall("p:variable", ns):
            kind = var.find("p:type/*", ns)
            type_name = kind.get("name") or kind.tag.split("}")[1]
            initial = var.find("p:initialValue/p:simpleValue", ns)
            lines.append(f"  {var.get('name')} : {type_name}"
                         + (f" := {initial.get('value')};" if initial is not None else ";"))
        lines.append("END_VAR")
    lines.append(pou.find("p:body/p:ST/x:xhtml", ns).text.rstrip())
    lines.append("END_PROGRAM")
    return "\n".join(lines) + "\n"


def export(path: Path, profile: Profile, cfg: PlantConfig, limits: DriveLimits,
           planned_peak: float, fmt: str, settings: dict[str, object], *,
           points: int | None = None, master: str = "time", units: str | None = None,
           interpolation: str | None = None, cycle: float = DRIVE_CYCLE) -> dict[str, object]:
    """The plan's cam table in format ``fmt`` written to ``path`` (atomically), checked as
    the drive interpolates it at ``cycle``: ``points`` given and breaking the plan is
    refused with the points it needs; not given, the table has the fewest that keep it.
    Returns what was written and its check."""
    cam.choice("format", fmt, FORMATS)
    fixed = INTERPOLATION.get(fmt)
    if fixed and interpolation not in (None, fixed):
        raise ParameterError(f"a {fmt} table is interpolated {fixed} by the drive; "
                             "--interpolation linear|cubic is for csv")
    interpolation = fixed or interpolation or "cubic"
    cam.choice("interpolation", interpolation, fixed and (fixed,) or CSV_INTERPOLATIONS)
    whole = fmt == "pvt"
    units = units or ("counts" if whole else "si")
    if whole and (master, units) != ("time", "counts"):
        raise ParameterError("a pvt table is in whole encoder counts over time: "
                             "--master time --units counts")
    drive = cfg.mechanism.drive

    def build(n: int) -> cam.CamTable:
        return cam.cam_table(profile, drive, n, master=master, units=units, whole=whole)

    found = points is None
    if found:
        needed = cam.points_needed(build, interpolation, cfg, limits, planned_peak, profile,
                                   cycle)
        if needed is None:
            raise ParameterError(f"no {fmt} table of up to {cam.MAX_POINTS} points keeps the "
                                 f"plan at the {cycle * 1e6:g} us drive cycle and at 100 "
                                 "and 125 us")
        points, check = needed
    else:
        check = cam.check_cycles(build(points), interpolation, cfg, limits, planned_peak,
                                 cam.checked_cycles(cycle), profile=profile)
    if not cam.keeps(check):
        needed = cam.points_needed(build, interpolation, cfg, limits, planned_peak, profile,
                                   cycle)
        raise ParameterError(
            f"the {points}-point {fmt} table ({interpolation}) breaks the plan at the "
            f"{cycle * 1e6:g} us drive cycle or at 100 or 125 us (of the limits, the planned "
            f"peak force, stroke and peak velocity): {', '.join(cam.breaches(check))}; "
            + (f"it needs at least {needed[0]} points (--points {needed[0]}, or no --points)"
               if needed else "no number of points keeps it"))
    table = build(points)
    with atomic_path(path) as tmp:
        if fmt == "csv":
            write_csv(tmp, table, interpolation, settings, cycle)
        elif fmt == "pvt":
            write_pvt(tmp, table, settings, cycle)
        else:
            tmp.write_text(plcopen_xml(table, settings, fmt, cycle=cycle))
    return {"format": fmt, "points": points, "master": master, "units": units,
            "interpolation": interpolation, "drive_cycle": cycle,
            "checked_cycles": list(cam.checked_cycles(cycle)),
            "points_found": found,  # searched; the fewest when tried from 2 up
            "points_fewest": found and points <= cam.SCAN_POINTS,
            "master_unit": MASTER_UNIT[master], "slave_unit": SLAVE_UNIT[units],
            "as_interpolated": check}
