"""ToggleClamp: the double-toggle clamp as an FMI 2.0 Co-Simulation slave.

A thin shell: the physics is :mod:`toggle.plant` (which composes the one
model of :mod:`toggle`); this file only declares the interface, mirroring
the test rig: the drive commands the input-link position ``x_cmd``, the
linear encoder reads ``platen_position``, the load cell reads ``input_force``.

One FMU is one preset: ``toggle build-fmu [--preset NAME]`` puts the
preset's TOML next to this file in the FMU (``preset.toml``); its values are
the parameters' start values, and the declared min/max are physical bounds.
Outside an FMU (tests, the native builder) the module reads chang2021.
"""

import math
from pathlib import Path

from pythonfmu import DefaultExperiment

from fmu_src import state as fmu_state
from fmu_src.slave import DeclaredSlave, Var
from fmu_src.state import StateError
from toggle.drive import reflected_mass, travel_per_radian
from toggle.kinematics import stroke_limits
from toggle.params import (
    DYNAMICS_PARAMETERS,
    PAPER_NAMES,
    Mechanism,
    dynamics_fields,
    load_preset,
)
from toggle.plant import (
    MAX_INPUT_ACCELERATION,
    MAX_INPUT_SPEED,
    DriveState,
    HystereticPlant,
    PlantConfig,
    configure,
    drive_step,
)

_PRESET_FILE = Path(__file__).with_name("preset.toml")
#: The preset this FMU is built for, read once at import (no file is read later).
MECHANISM = load_preset(str(_PRESET_FILE) if _PRESET_FILE.is_file() else "chang2021")
#: Dimensional errors, one parameter per dimension of each half (seed 000's names).
ERRORS = tuple(name for half in ("lower", "upper") for name in PAPER_NAMES[half].values())
MAX_ERROR = 5e-3  # m: a dimensional error, not a redesign
#: The drive's rotating inertias (toggle.drive.reflected_mass), kg m^2.
INERTIAS = {"rotor_inertia": "Motor rotor inertia (with its pulley)",
            "screw_inertia": "Ball-screw inertia (with its pulley and coupling)"}
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
    ("motor_torque", "N.m", "Drive motor torque: thrust through ball screw and belt, and the "
     "rotor's and screw's inertia"),
)


#: Nominal magnitudes of the drive's states (Model Exchange scales its absolute tolerances
#: by them): 1 mm, so that a master's tolerance resolves a mold's compression of a few um.
NOMINALS = {"x": 1e-3, "velocity": 0.1}


def drive_bandwidth(mech: Mechanism) -> float:
    """The default ``drive_bandwidth`` (Hz) of the FMU of ``mech``: its real drive's.

    A linear lag is true to a drive only while the motor is not saturated, and the
    largest setpoint jump a clamp takes is its whole stroke S (x_open to the toggle). The
    lag's response to a jump starts with the acceleration w^2 S; the motor's standstill
    torque T0 (the [drive] torque-speed curve's first point, else its rated torque) gives
    at most a = T0 / (p (m_drive + crosshead + links + platen)), p the travel per motor
    radian and m_drive the rotor's and screw's reflected mass. w = sqrt(a / S), to 3
    digits: 2.27 Hz for chang2021 (a = 11 m/s^2), 1.36 Hz for lin2003_sm55. Any jump then
    asks for at most about (x_cmd range / S) a, far within the input link's bounds at any
    step size (docs/fmu.md). Without torque data: 0, the ideal drive.
    """
    drive, dyn = mech.drive, mech.dynamics
    torque = drive.torque_speed[0][1] if drive.torque_speed else drive.rated_torque
    if not torque:
        return 0.0
    mass = float(reflected_mass(drive)) + dyn.crosshead + dyn.links + dyn.platen
    x_open, x_toggle = stroke_limits(mech.lower)
    accel = torque / (travel_per_radian(drive) * mass)
    return float(f"{math.sqrt(accel / (x_toggle - x_open)) / (2 * math.pi):.3g}")


def variables(mech: Mechanism) -> tuple[Var, ...]:
    """The variable table of the FMU built for ``mech``: its values as start values."""
    cfg = PlantConfig(mech)
    x_open, x_toggle = stroke_limits(mech.lower)
    x_lo, x_hi = cfg.input_range
    dyn = mech.dynamics
    mass_max = 100 * max(dyn.crosshead, dyn.links, dyn.platen, 1.0)
    # bounds: masses 100 times the largest; damping in N s/m and frictions in N beyond any
    # clamp this size (1e3 times the mass bound; a friction of 1e5 N per kg of it); a
    # friction's rate strengthening of 100 per e-fold of speed
    top = {"kg": mass_max, "N.s/m": 1e3 * mass_max, "N": 1e3 * mass_max, "1": 100.0}
    return (
        Var("preset", "parameter", "", "Preset this FMU is built for (fixed; build another "
            "with toggle build-fmu --preset)", start=mech.name),
        Var("mu", "parameter", "1", "Kinetic pin friction coefficient", start=cfg.friction,
            min=0.0, max=1.0),
        Var("x_contact", "parameter", "m", "Crosshead position at mold contact; the toggle "
            "position (start and max): no mold", start=x_toggle, min=x_open, max=x_toggle),
        *(Var(name, "parameter", unit, text, start=float(getattr(dyn, field)), min=0.0,
              max=top[unit])
          for name, (field, unit, text) in DYNAMICS_PARAMETERS.items()),
        *(Var(name, "parameter", "kg.m2", text, start=float(getattr(mech.drive, name)),
              min=0.0, max=100 * max(mech.drive.rotor_inertia, mech.drive.screw_inertia, 0.01))
          for name, text in INERTIAS.items()),
        Var("drive_bandwidth", "parameter", "Hz",
            "Drive tracking bandwidth (default: the preset's drive, see docs/fmu.md); 0: ideal "
            "position source", start=drive_bandwidth(mech), min=0.0, max=1e3),
        Var("drive_damping", "parameter", "1", "Drive tracking damping ratio", start=0.7,
            min=0.0, max=10.0),
        *(Var(f"delta_{n}", "parameter", "m", f"Dimensional error of {n}", start=0.0,
              min=-MAX_ERROR, max=MAX_ERROR) for n in ERRORS),
        Var("x_cmd", "input", "m", "Commanded input-link position", start=x_open, min=x_lo,
            max=x_hi),
        *(Var(name, "output", unit, text, depends_on=(), nominal=NOMINALS.get(name))
          for name, unit, text in OUTPUTS),
    )


class ToggleClamp(DeclaredSlave):
    """Nine-link double-toggle clamp driven by position; see the module doc."""

    author = "toggle-clamp"
    description = "Double-toggle mold/die clamp: kinematics, pin friction, elastics, inertia"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=10.0, step_size=1e-3)
    ATOMIC_STEP = True  # _publish assigns only after CompiledPlant returned finite outputs
    VARIABLES = variables(MECHANISM)
    _PARAMETERS = tuple(v.name for v in VARIABLES if v.causality == "parameter")

    def _config(self) -> PlantConfig:
        if self.preset != MECHANISM.name:
            raise ValueError(f"parameter preset: this FMU is built for {MECHANISM.name!r}, "
                             f"not {fmu_state.short(self.preset)}; build one with toggle "
                             "build-fmu --preset")
        return configure(
            MECHANISM,
            mu=self.mu,
            x_contact=self.x_contact,
            masses=dynamics_fields({name: getattr(self, name) for name in DYNAMICS_PARAMETERS}),
            drive={name: getattr(self, name) for name in INERTIAS},
            errors={n: getattr(self, f"delta_{n}") for n in ERRORS},
        )

    def _build_plant(self) -> None:
        """Compile the plant of the current parameters, unless it is already that one."""
        key = tuple(getattr(self, name) for name in self._PARAMETERS)
        if getattr(self, "_plant_key", None) != key:
            self._plant = HystereticPlant(self._config())
            self._plant_key = key

    def initialize(self) -> None:
        self._build_plant()
        self._plant.state = (None, 0.0)  # the pin friction's slip state starts relaxed
        self._drive = DriveState.at_rest(self.x_cmd)
        self._publish()

    def step(self, current_time: float, step_size: float) -> None:
        self._plant.plant.check_input(self.x_cmd)  # a position error first, not a speed
        # x_cmd and its derivatives are the master's at the step's start (FMI 2.0 4.2.2);
        # without derivatives x_cmd is extrapolated from the last ones, within its range
        plant = self._plant.plant
        drive = drive_step(self._drive, self.x_cmd, step_size, self.drive_bandwidth,
                           self.drive_damping, self.input_derivative("x_cmd", 1),
                           self.input_derivative("x_cmd", 2), (plant.x_min, plant.x_max))
        self._publish(drive)

    def initial_dependencies(self) -> dict[str, tuple[str, ...]]:
        """From CasADi's sparsity of the plant (fmu_src.structure), as the native build's."""
        import importlib

        # build time only, in the building Python: by a name the bundling leaves alone
        structure = importlib.import_module("fmu_src.structure")
        init = structure.structure_dependencies(configure(MECHANISM)).init
        return {v.name: init[v.name] for v in self.VARIABLES if v.causality == "output"}

    def state_identity(self) -> str:
        return f"ToggleClamp {MECHANISM.name}"

    def model_state(self) -> dict:
        return {"drive": list(self._drive), "slip": list(self._plant.state)}

    def restore_model_state(self, state: object) -> None:
        """The drive and slip state, checked as the plant made them: the motion within the
        input link's bounds, the last command within the clamp's range, the slip state at
        the drive's position and in [-1, 1], and the outputs in the state those of the
        plant there (so a forged output or drive field is refused)."""
        state = fmu_state.keys(state, frozenset({"drive", "slip"}), "the model state")
        drive, slip = state["drive"], state["slip"]
        if not (isinstance(drive, list) and len(drive) == len(DriveState._fields)):
            raise StateError(f"the model state's drive must be a list of "
                             f"{len(DriveState._fields)} numbers "
                             f"({', '.join(DriveState._fields)})")
        drive = DriveState(*(fmu_state.finite(v, f"drive {n}")
                             for n, v in zip(DriveState._fields, drive)))
        if not (isinstance(slip, list) and len(slip) == 2):
            raise StateError("the model state's slip must be a list [x m, z]")
        x_last, z = (fmu_state.finite(v, f"slip {n}") for n, v in zip(("x", "z"), slip))
        self._build_plant()  # the parameters' plant, or their error
        plant = self._plant.plant
        bounds = (("v", drive.v, MAX_INPUT_SPEED, "m/s"),
                  ("a", drive.a, MAX_INPUT_ACCELERATION, "m/s^2"))
        for name, value, bound, unit in bounds:
            if not abs(value) <= bound:
                raise StateError(f"drive {name} = {value!r} {unit} is outside "
                                 f"[{-bound:g}, {bound:g}] {unit}")
        plant.check_input(drive.u)
        if not drive.h >= 0 or drive.h == 0 and drive != DriveState.at_rest(drive.u):
            raise StateError(f"drive h = {drive.h!r} s: the last step must be > 0 s, or 0 "
                             "with the drive at rest at its command")
        if not drive.span >= 0:
            raise StateError(f"drive span = {drive.span!r} s: the slope's span must be >= 0 s")
        if x_last != drive.x or not abs(z) <= 1:
            raise StateError(f"slip state [{x_last!r}, {z!r}]: it must be at the drive's "
                             f"x = {drive.x!r} m with z in [-1, 1]")
        outputs = plant(drive.x, drive.v, drive.a, z)  # PlantError outside the range
        if any(getattr(self, n) != v for n, v in zip(outputs._fields, outputs)):
            raise StateError("the outputs in the state are not the plant's at its drive "
                             "and slip state")
        self._drive = drive
        self._plant.state = (x_last, z)

    def _publish(self, drive: DriveState | None = None) -> None:
        drive = drive or self._drive
        outputs = self._plant(drive)  # raises outside the range, before any change
        self._drive = drive
        self.__dict__.update(zip(outputs._fields, outputs))  # the output variables
