"""The files a cam table is written as (``toggle plan --export cam --format ...``).

* ``csv``: ``# key = value`` lines (what the table was made for, SI), then master,
  slave, slave velocity and slave acceleration with their units; the drive interpolates
  the positions ``linear`` or ``cubic`` (the user's choice: a plain position table).
* ``plcopen``: a PLCopen TC6 XML v2.01 project (namespace :data:`TC6`) for CODESYS
  SoftMotion: a global ``ClampCam_A : ARRAY [0..N-1] OF SMC_CAMXYVA`` (dX, dY, dV, dA:
  LREAL, the master and the slave's position, velocity and acceleration over the
  master), the ``ClampCam : MC_CAM_REF`` describing it (byType 3, XYVA: fifth-order
  polynomials between the points), and a program POU ``ClampCamIn`` whose ST body hands
  ``ClampCam`` to MC_CamTableSelect and couples the slave with MC_CamIn. The form is the
  IEC initialisation code CODESYS's cam editor generates ("Display Generated Code");
  its PLCopenXML import reads the project.
* ``pvt``: a drive's position-velocity-time table in whole encoder counts: one row per
  point at a fixed time step, position (counts) and velocity (counts/s) as integers;
  the drive interpolates each segment with the cubic through both ends' position and
  velocity (``pv-cubic``).

Each file's creation time is ``SOURCE_DATE_EPOCH`` when set (reproducible exports, the
reproducible-builds convention), else the time of the export, UTC.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from controllers import cam
from controllers.cam import DRIVE_CYCLE, MASTER_UNIT, SLAVE_UNIT, CamTable
from controllers.limits import DriveLimits
from controllers.profiles import Profile
from toggle.files import atomic_path
from toggle.params import ParameterError
from toggle.plant import PlantConfig

FORMATS = ("csv", "plcopen", "pvt")
#: How the drive interpolates each format's table; csv: the user's (linear or cubic).
INTERPOLATION = {"plcopen": "pva-quintic", "pvt": "pv-cubic"}
CSV_INTERPOLATIONS = ("linear", "cubic")
TC6 = "http://www.plcopen.org/xml/tc6_0201"
XHTML = "http://www.w3.org/1999/xhtml"
#: The program POU's ST body: select the cam, couple the slave to the master with it.
PROGRAM_BODY = """Select(Master := Master, Slave := Slave, CamTable := ClampCam, Execute := Start,
       Periodic := FALSE, MasterAbsolute := TRUE, SlaveAbsolute := FALSE);
Couple(Master := Master, Slave := Slave, Execute := Select.Done,
       CamTableID := Select.CamTableID);
InSync := Couple.InSync;
Error := Select.Error OR Couple.Error;
"""
#: The program's interface: section, name, type (derived type names are the libraries').
PROGRAM_VARS = (("inOutVars", "Master", "AXIS_REF"), ("inOutVars", "Slave", "AXIS_REF"),
                ("inputVars", "Start", "BOOL"), ("outputVars", "InSync", "BOOL"),
                ("outputVars", "Error", "BOOL"), ("externalVars", "ClampCam", "MC_CAM_REF"),
                ("localVars", "Select", "MC_CamTableSelect"),
                ("localVars", "Couple", "MC_CamIn"))
ELEMENTARY = ("BOOL", "LREAL", "INT", "BYTE")


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


def _header(table: CamTable, interpolation: str, settings: dict[str, object]) -> dict:
    return {**settings, "master": table.kind, "units": table.units,
            "interpolation": interpolation, "duration": table.duration,
            "x_open": table.x_open, "points": int(table.master.size),
            "created": creation_time().isoformat()}


def _comments(header: dict) -> str:
    return "".join(f"# {key} = {value!r}\n".replace("'", '"') if isinstance(value, str)
                   else f"# {key} = {value}\n" for key, value in header.items()
                   if value is not None)


def _units(table: CamTable) -> tuple[str, str, str, str]:
    m, s = MASTER_UNIT[table.kind], SLAVE_UNIT[table.units]
    return m, s, f"{s}/{m}", f"{s}/{m}^2"


def write_csv(path: str | Path, table: CamTable, interpolation: str,
              settings: dict[str, object]) -> None:
    """The table as CSV: ``# key = value`` lines, then the four columns with units."""
    buffer = io.StringIO()
    buffer.write(_comments(_header(table, interpolation, settings)))
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


def write_pvt(path: str | Path, table: CamTable, settings: dict[str, object]) -> None:
    """The table as a PVT drive table: time (s), position (counts) and velocity
    (counts/s), the last two whole numbers; refused unless master time and counts."""
    if table.kind != "time" or table.units != "counts" or not table.whole:
        raise ParameterError("a pvt table is in whole encoder counts over time: "
                             "--master time --units counts")
    buffer = io.StringIO()
    buffer.write(_comments({**_header(table, INTERPOLATION["pvt"], settings),
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


def plcopen_xml(table: CamTable, settings: dict[str, object], name: str = "ClampCam") -> str:
    """The table as a PLCopen TC6 XML v2.01 project (module docstring)."""
    ET.register_namespace("", TC6)
    ET.register_namespace("xhtml", XHTML)
    root = ET.Element(f"{{{TC6}}}project")
    created = creation_time().replace(tzinfo=None).isoformat()
    _sub(root, "fileHeader", companyName="toggle-clamp", productName="toggle plan",
         productVersion="1", creationDateTime=created,
         contentDescription="cam of a planned clamp stroke, CODESYS SoftMotion XYVA")
    content = _sub(root, "contentHeader", name=name, modificationDateTime=created)
    coordinates = _sub(content, "coordinateInfo")
    for language in ("fbd", "ld", "sfc"):
        _sub(_sub(coordinates, language), "scaling", x="1", y="1")
    types = _sub(root, "types")
    _sub(types, "dataTypes")
    pou = _sub(_sub(types, "pous"), "pou", name=f"{name}In", pouType="program")
    interface = _sub(pou, "interface")
    for section in dict.fromkeys(s for s, _, _ in PROGRAM_VARS):
        block = _sub(interface, section)
        for _, var, type_name in (v for v in PROGRAM_VARS if v[0] == section):
            _type(_sub(block, "variable", name=var), type_name)
    _text(_sub(_sub(pou, "body"), "ST"), PROGRAM_BODY)
    resource = _sub(_sub(_sub(_sub(root, "instances"), "configurations"), "configuration",
                         name="Clamp"), "resource", name="Drive")
    variables = _sub(resource, "globalVars", name=f"{name}Data")  # MC_CAM_REF: an FB
    points = _sub(variables, "variable", name=f"{name}_A")
    array = _sub(_sub(points, "type"), "array")
    _sub(array, "dimension", lower="0", upper=str(table.master.size - 1))
    _sub(_sub(array, "baseType"), "derived", name="SMC_CAMXYVA")
    values = _sub(_sub(points, "initialValue"), "arrayValue")
    for row in zip(*(c.tolist() for c in (table.master, table.slave, table.velocity,
                                           table.acceleration))):
        _struct_value(_sub(values, "value"), dict(zip(("dX", "dY", "dV", "dA"),
                                                      map(repr, row))))
    cam = _sub(variables, "variable", name=name)
    _type(cam, "MC_CAM_REF")
    _struct_value(_sub(cam, "initialValue"), {
        "nElements": str(table.master.size), "byType": "3",
        "xStart": repr(float(table.master[0])), "xEnd": repr(float(table.master[-1])),
        "nTappets": "0", "strCAMName": f"'{name}'", "pce": f"ADR({name}_A)"})
    m, s, v, a = _units(table)
    text = "; ".join(f"{k} = {value}" for k, value in
                     _header(table, INTERPOLATION["plcopen"], settings).items()
                     if value is not None)
    _text(_sub(points, "documentation"),
          f"dX [{m}], dY [{s}], dV [{v}], dA [{a}]; {text}")
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True)


def read_plcopen(text: str, name: str = "ClampCam") -> tuple[np.ndarray, ...]:
    """dX, dY, dV and dA of the points of a project written by :func:`plcopen_xml`."""
    root = ET.fromstring(text)
    ns = {"p": TC6}
    points = root.findall(f".//p:variable[@name='{name}_A']/p:initialValue/p:arrayValue/"
                          "p:value/p:structValue", ns)
    data = [[float(p.find(f"p:value[@member='{m}']/p:simpleValue", ns).get("value"))
             for m in ("dX", "dY", "dV", "dA")] for p in points]
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
            lines.append(f"  {var.get('name')} : {type_name};")
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
                                 f"plan at the {cycle * 1e6:g} us drive cycle")
        points, check = needed
    else:
        check = cam.check_table(build(points), interpolation, cfg, limits, planned_peak,
                                cycle, profile=profile)
    if not cam.keeps(check):
        needed = cam.points_needed(build, interpolation, cfg, limits, planned_peak, profile,
                                   cycle)
        raise ParameterError(
            f"the {points}-point {fmt} table ({interpolation}) breaks the plan at the "
            f"{cycle * 1e6:g} us drive cycle: {', '.join(cam.breaches(check))}; "
            + (f"it needs at least {needed[0]} points (--points {needed[0]}, or no --points)"
               if needed else "no number of points keeps it"))
    table = build(points)
    with atomic_path(path) as tmp:
        if fmt == "csv":
            write_csv(tmp, table, interpolation, settings)
        elif fmt == "pvt":
            write_pvt(tmp, table, settings)
        else:
            tmp.write_text(plcopen_xml(table, settings))
    return {"format": fmt, "points": points, "master": master, "units": units,
            "interpolation": interpolation, "drive_cycle": cycle,
            "points_found": found,
            "master_unit": MASTER_UNIT[master], "slave_unit": SLAVE_UNIT[units],
            "as_interpolated": check}
