"""ToggleClamp: the double-toggle clamp as an FMI 2.0 Co-Simulation slave.

A thin shell: the physics is :mod:`toggle.plant` (which composes the one
model of :mod:`toggle`); this file only declares the interface, mirroring
the test rig: the drive commands the input-link position ``x_cmd``, the
linear encoder reads ``platen_position``, the load cell reads ``input_force``.
Build with ``toggle build-fmu`` (writes build/ToggleClamp.fmu).
"""

import math

from pythonfmu import DefaultExperiment

from toggle.fmu_slave import DeclaredSlave, Var
from toggle.params import PAPER_NAMES
from toggle.plant import CompiledPlant, DriveState, configure, follow

#: Parameter value that means "the preset's value".
PRESET = -1.0
#: Dimensional errors, one parameter per dimension of each half (seed 000's names).
ERRORS = tuple(name for half in ("lower", "upper") for name in PAPER_NAMES[half].values())
MASSES = {"m_crosshead": "crosshead", "m_links": "links", "m_platen": "platen",
          "guide_damping": "guide_damping"}
OUTPUTS = (
    ("x", "m", "Input-link (crosshead) position"),
    ("velocity", "m/s", "Input-link velocity"),
    ("acceleration", "m/s2", "Input-link acceleration"),
    ("platen_position", "m", "Moving-platen position from the link-4 pivot (linear encoder)"),
    ("platen_velocity", "m/s", "Moving-platen velocity"),
    ("input_force", "N", "Force between drive and input link (load cell)"),
    ("clamp_force", "N", "Clamping force on the mold"),
    ("tiebar_force", "N", "Total tie-bar force"),
    ("mechanical_advantage", "1", "Clamp force over input force with pin friction"),
    ("toggle_angle", "rad", "Toggle angle alpha (theta4 of the lower half)"),
    ("asymmetry", "m", "Upper minus lower half output position"),
    ("motor_torque", "N.m", "Drive motor torque (ball screw and belt)"),
)


class ToggleClamp(DeclaredSlave):
    """Nine-link double-toggle clamp driven by position; see the module doc."""

    author = "toggle-clamp"
    description = "Double-toggle mold/die clamp: kinematics, pin friction, elastics, inertia"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=10.0, step_size=1e-3)
    STATE_EXCLUDE = frozenset({"_plant"})
    ATOMIC_STEP = True  # _publish assigns only after CompiledPlant returned finite outputs
    VARIABLES = (
        Var("preset", "parameter", "", "Shipped preset name or TOML path", start="chang2021"),
        Var("mu", "parameter", "1", "Pin friction coefficient; -1: the preset's",
            start=PRESET),
        Var("x_contact", "parameter", "m",
            "Crosshead position at mold contact; at or beyond the toggle: no mold", start=1.0),
        Var("m_crosshead", "parameter", "kg", "Crosshead mass; -1: the preset's", start=PRESET),
        Var("m_links", "parameter", "kg", "Lumped link mass; -1: the preset's", start=PRESET),
        Var("m_platen", "parameter", "kg", "Moving-platen mass; -1: the preset's", start=PRESET),
        Var("guide_damping", "parameter", "N.s/m", "Viscous guide friction; -1: the preset's",
            start=PRESET),
        Var("drive_bandwidth", "parameter", "Hz",
            "Drive tracking bandwidth; 0: ideal position source", start=0.0, min=0.0),
        Var("drive_damping", "parameter", "1", "Drive tracking damping ratio", start=0.7,
            min=0.0),
        *(Var(f"delta_{n}", "parameter", "m", f"Dimensional error of {n}", start=0.0)
          for n in ERRORS),
        Var("x_cmd", "input", "m", "Commanded input-link position", start=-3.4386e-3),
        *(Var(name, "output", unit, text, depends_on=()) for name, unit, text in OUTPUTS),
    )

    def _given(self, name: str) -> float | None:
        """A parameter's value, None for the preset's (-1); anything else must be >= 0."""
        value = getattr(self, name)
        if value == PRESET:
            return None
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"parameter {name} must be >= 0 (or -1 for the preset's), "
                             f"got {value!r}")
        return value

    def initialize(self) -> None:
        for name in ("drive_bandwidth", "drive_damping"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"parameter {name} must be finite and >= 0, got {value!r}")
        masses = {field: self._given(name) for name, field in MASSES.items()}
        cfg = configure(
            self.preset,
            mu=self._given("mu"),
            x_contact=self.x_contact,
            masses={k: v for k, v in masses.items() if v is not None},
            errors={n: getattr(self, f"delta_{n}") for n in ERRORS},
        )
        self._plant = CompiledPlant(cfg)
        self._drive = DriveState(self.x_cmd, 0.0, 0.0)
        self._publish()

    def step(self, current_time: float, step_size: float) -> None:
        drive = follow(self._drive, self.x_cmd, step_size, self.drive_bandwidth,
                       self.drive_damping)
        self._publish(drive)

    def _publish(self, drive: DriveState | None = None) -> None:
        drive = drive or self._drive
        outputs = self._plant(*drive)  # raises outside the range
        self._drive = drive
        self.__dict__.update(zip(outputs._fields, outputs))  # the output variables
