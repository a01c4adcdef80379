"""Cam tables of a plan, as a servo drive or motion controller loads them, and their check.

A drive runs a cam as a table of master to slave positions that it re-interpolates
(linearly, or with a cubic spline through the points) at every control cycle. The
master is time (s) or a virtual master axis turning once per profile (degrees,
0 to 360, at constant speed: the PLCopen MC_CamIn master); the slave is the
crosshead's travel from the open position in SI (m), in motor revolutions (through
the belt and screw: R lead per turn, :mod:`toggle.drive`) or in encoder counts
(``pulses_per_rev`` per turn; written with decimals, as drives that take LREAL
tables read them, so that rounding to whole counts does not become acceleration noise).

:func:`drive_samples` re-interpolates a table as the drive does and samples it every
control cycle (1 ms); :func:`check_table` runs those samples through the plant
(:func:`toggle.plant.plant_outputs`, the planner's and the FMU's model) and gives the
velocity, acceleration, motor torque and input force against the plan's limits: what
the drive will really command, not what the plan meant.

Formats: CSV (``# key = value`` lines, then ``master [unit],slave [unit]``) and PLCopen
XML (TC6 XML v2.01, namespace ``http://www.plcopen.org/xml/tc6_0201``): a project with a
``CamPoint`` structure (MasterPosition, SlavePosition: LREAL) and a constant global
``CamTable : ARRAY [0..N-1] OF CamPoint`` initialised with the table, which IEC 61131-3
tools import and pass to their MC_CamTableSelect (:func:`read_plcopen` reads it back).
"""

from __future__ import annotations

import csv
import io
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from controllers.limits import DriveLimits
from controllers.profiles import Profile, sample_times
from toggle.params import Drive, ParameterError
from toggle.plant import PlantConfig, plant_outputs

MASTERS = ("time", "position")
UNITS = ("si", "motor", "counts")
INTERPOLATIONS = ("linear", "cubic")
FORMATS = ("csv", "plcopen")
#: The unit of the master and of the slave as written, by master / units.
MASTER_UNIT = {"time": "s", "position": "deg"}
SLAVE_UNIT = {"si": "m", "motor": "rev", "counts": "counts"}
#: The drive's control cycle the table is checked on, s.
CYCLE = 1e-3
TC6 = "http://www.plcopen.org/xml/tc6_0201"


@dataclass(frozen=True)
class CamTable:
    """Master and slave positions (in ``master``'s and ``units``' units), the profile's
    duration (s), the crosshead's open position (m) and the drive that converts."""

    master: np.ndarray
    slave: np.ndarray
    kind: str  # master: time or position
    units: str
    duration: float
    x_open: float
    drive: Drive = field(repr=False)

    def slave_si(self, slave: np.ndarray) -> np.ndarray:
        """Slave values in the table's units as crosshead positions, m."""
        return self.x_open + np.asarray(slave) / _per_metre(self.units, self.drive)

    def master_time(self, master: np.ndarray) -> np.ndarray:
        """Master values as time, s."""
        return np.asarray(master) * (self.duration / 360.0 if self.kind == "position" else 1.0)


def _per_metre(units: str, drive: Drive) -> float:
    """Slave units per metre of crosshead travel."""
    turn = drive.ratio * drive.lead  # crosshead travel per motor turn, m
    return {"si": 1.0, "motor": 1.0 / turn, "counts": drive.pulses_per_rev / turn}[units]


def _choice(name: str, value: str, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise ParameterError(f"cam {name} must be one of {', '.join(allowed)}, got {value!r}")


def default_points(profile: Profile, interpolation: str) -> int:
    """Points of a table a drive can follow within 1 % of the plan: one per control cycle
    for linear interpolation (between points its velocity steps, and each step is an
    acceleration over one cycle), one per 10 ms for a cubic spline."""
    step = CYCLE if interpolation == "linear" else 10 * CYCLE
    return math.ceil(profile.duration / step - 1e-9) + 1


def cam_table(profile: Profile, drive: Drive, points: int | None = None, *,
              master: str = "time", units: str = "si", interpolation: str = "cubic"
              ) -> CamTable:
    """The profile as a cam table of ``points`` equally spaced master positions (default
    :func:`default_points`), the slave's travel from the profile's start."""
    _choice("master", master, MASTERS)
    _choice("units", units, UNITS)
    _choice("interpolation", interpolation, INTERPOLATIONS)
    points = default_points(profile, interpolation) if points is None else points
    if not (isinstance(points, int) and 2 <= points <= 100_000):
        raise ParameterError(f"cam points must be an integer 2 to 100000, got {points!r}")
    t = np.linspace(0.0, profile.duration, points)
    x = profile.sample(t)[0]
    scale = 360.0 / profile.duration if master == "position" else 1.0
    return CamTable(t * scale, (x - x[0]) * _per_metre(units, drive), master, units,
                    profile.duration, float(x[0]), drive)


def drive_samples(table: CamTable, interpolation: str, period: float = CYCLE
                  ) -> tuple[np.ndarray, ...]:
    """The crosshead motion the drive commands from the table: re-interpolated
    (``linear``, or a cubic spline with the rest at both ends the table's ends keep)
    and sampled every ``period`` s; velocity and acceleration as the drive's position
    setpoints give them (central differences over the periods). Time, position, velocity,
    acceleration, SI."""
    _choice("interpolation", interpolation, INTERPOLATIONS)
    t_knots = table.master_time(table.master)
    x_knots = table.slave_si(table.slave)
    t = sample_times(table.duration, period)
    if interpolation == "linear":
        x = np.interp(t, t_knots, x_knots)
    else:
        x = CubicSpline(t_knots, x_knots, bc_type="clamped")(t)
    v = np.gradient(x, t)
    a = np.gradient(v, t)
    return t, x, v, a


def check_table(table: CamTable, interpolation: str, cfg: PlantConfig, limits: DriveLimits,
                planned_peak: float) -> dict[str, float]:
    """The table as the drive interpolates it, through the plant: the largest velocity,
    acceleration and motor torque over their limits and the peak input force over the
    plan's (each at most 1.01 for a table that keeps the plan within 1 %)."""
    t, x, v, a = drive_samples(table, interpolation)
    force = np.asarray(plant_outputs(x, v, a, cfg).input_force, float)
    peak = float(np.max(np.abs(force)))
    return {"velocity": float(np.max(np.abs(v))) / limits.velocity,
            "acceleration": float(np.max(np.abs(a))) / limits.acceleration,
            "motor_torque": limits.torque_ratio(table.drive, v, a, force),
            "peak_force": peak / planned_peak, "peak_force_newton": peak}


def _header(table: CamTable, interpolation: str, settings: dict[str, object]) -> dict:
    return {**settings, "master": table.kind, "units": table.units,
            "interpolation": interpolation, "duration": table.duration,
            "x_open": table.x_open, "points": int(table.master.size)}


def write_csv(path: str | Path, table: CamTable, interpolation: str,
              settings: dict[str, object]) -> None:
    """The table as CSV: ``# key = value`` lines (what it was made for, SI), then the
    columns with their units."""
    buffer = io.StringIO()
    for key, value in _header(table, interpolation, settings).items():
        if value is not None:
            buffer.write(f"# {key} = {value!r}\n" if isinstance(value, str)
                         else f"# {key} = {value}\n")
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow([f"master [{MASTER_UNIT[table.kind]}]",
                     f"slave [{SLAVE_UNIT[table.units]}]"])
    writer.writerows(zip(map(repr, table.master.tolist()), map(repr, table.slave.tolist())))
    Path(path).write_text(buffer.getvalue().replace("'", '"'))


def read_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Master and slave columns of a cam CSV."""
    rows = [r for r in Path(path).read_text().splitlines() if r and not r.startswith("#")]
    data = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
    return data[:, 0], data[:, 1]


def _sub(parent: ET.Element, tag: str, **attrs: str) -> ET.Element:
    return ET.SubElement(parent, f"{{{TC6}}}{tag}", attrs)


def plcopen_xml(table: CamTable, interpolation: str, settings: dict[str, object],
                name: str = "ClampCam") -> str:
    """The table as a PLCopen TC6 XML v2.01 project (module docstring)."""
    ET.register_namespace("", TC6)
    root = ET.Element(f"{{{TC6}}}project")
    _sub(root, "fileHeader", companyName="toggle-clamp", productName="toggle plan",
         productVersion="1", creationDateTime="2026-01-01T00:00:00")
    content = _sub(root, "contentHeader", name=name)
    coordinates = _sub(content, "coordinateInfo")
    for language in ("fbd", "ld", "sfc"):
        _sub(_sub(coordinates, language), "scaling", x="1", y="1")
    types = _sub(root, "types")
    struct = _sub(_sub(_sub(_sub(types, "dataTypes"), "dataType", name="CamPoint"),
                       "baseType"), "struct")
    for member in ("MasterPosition", "SlavePosition"):
        _sub(_sub(struct, "variable", name=member), "type").append(
            ET.Element(f"{{{TC6}}}LREAL"))
    _sub(types, "pous")
    resource = _sub(_sub(_sub(_sub(root, "instances"), "configurations"), "configuration",
                         name="Clamp"), "resource", name="Drive")
    variables = _sub(resource, "globalVars", constant="true")
    variable = _sub(variables, "variable", name="CamTable")
    array = _sub(_sub(variable, "type"), "array")
    _sub(array, "dimension", lower="0", upper=str(table.master.size - 1))
    _sub(_sub(array, "baseType"), "derived", name="CamPoint")
    values = _sub(_sub(variable, "initialValue"), "arrayValue")
    for m, s in zip(table.master.tolist(), table.slave.tolist()):
        point = _sub(_sub(values, "value"), "structValue")
        for member, number in (("MasterPosition", m), ("SlavePosition", s)):
            _sub(_sub(point, "value", member=member), "simpleValue", value=repr(number))
    text = "; ".join(f"{k} = {v}" for k, v in _header(table, interpolation, settings).items()
                     if v is not None)
    _sub(_sub(variable, "documentation"), "xhtml").text = (
        f"master [{MASTER_UNIT[table.kind]}], slave [{SLAVE_UNIT[table.units]}]; {text}")
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True)


def read_plcopen(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Master and slave positions of a table written by :func:`plcopen_xml`."""
    root = ET.fromstring(text)
    ns = {"p": TC6}
    points = root.findall(".//p:variable[@name='CamTable']/p:initialValue/p:arrayValue/"
                          "p:value/p:structValue", ns)
    data = [[float(p.find(f"p:value[@member='{m}']/p:simpleValue", ns).get("value"))
             for m in ("MasterPosition", "SlavePosition")] for p in points]
    return tuple(np.array(data).T)
