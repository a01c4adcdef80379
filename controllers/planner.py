"""Optimal crosshead motion for a clamp stroke: least time or least drive force under
real limits.

The optimal control problem, solved with CasADi and IPOPT through the plant's
own equations (:func:`toggle.plant.plant_outputs`, what the FMU compiles):

* states crosshead position, velocity and acceleration, jerk piecewise
  constant on N intervals, discretised exactly (the triple integrator);
* three phases: the approach, the mold-protection zone (:class:`Protection`: its
  entry, the last distance of platen travel before contact, pinned to node NA,
  with a platen speed cap and an input-force cap) and, from mold contact
  (pinned to node N1, so the force's kink at contact falls on a node and the
  platen's speed there is a node value), the clamping up to the toggle.
  Approach nodes are evaluated with the mold-free plant, clamping nodes with
  the mold; the two agree up to contact, so this is the FMU's model;
* objective the peak input force (epigraph variable s, |F| <= s at the nodes
  and interval midpoints, plus a small weight on the squared jerk to make the
  optimum unique), the integral of F^2, or the integral of the squared motor torque
  (``"energy"``: the copper losses, :mod:`controllers.duty`), alone or weighted into the
  peak; the minimum-time mode minimises the duration under |F| <= force limit;
* constraints: rest at the open position and at the toggle, monotone stroke
  inside the stroke limits, velocity (nodes and midpoints), acceleration and
  jerk limits (:mod:`controllers.limits`), the motor torque with the drive's
  inertia (:func:`toggle.drive.drive_torque`) within the torque-speed curve at
  the motor's speed (nodes and midpoints), platen speed at mold contact, and no
  creeping through the clamping (``CREEP_FACTOR``).

The opening (break-away) stroke, ``planner_for(..., opening=True)``, is the same
problem run backwards in time (the plant evaluated at -v): its plans are reversed
profiles from rest at the toggle to rest at the open position.

Optima to trust: :meth:`ClampPlanner.best` starts from several guesses (the
problem has two families of local optima: slow or fast arrival at the mold,
the latter braking through the thrust peak) and :meth:`ClampPlanner.lower_bound`
gives what no stroke can beat (:mod:`controllers.bounds`).
:meth:`ClampPlanner.minimum_time` lets the optimiser decide whether a force
limit can be met, by continuation from the fastest stroke down to the limit
(a trade-off's points each continued from the last), and checks the limit on the
plan's 1 ms samples (tightening it where the samples between the nodes exceed it);
a limit below the lower bound, or below the least peak of any duration
(:meth:`ClampPlanner.least_peak`), is refused before the continuation. With
``variants`` (the clamp with dimensional errors) the force limits and the peak
hold for the worst plant: a robust plan.

Variables are scaled by the stroke, a reference time (the kinematic minimum)
and a reference force; the interval lengths of the two phases are variables
and the duration is a constraint whose bounds fix it or leave it free. The
objective weights, the mold-contact position, the pin friction, the scales,
the jerk and contact-speed limits, the drive (travel per radian, efficiency,
the rotor's and screw's reflected mass, the torque-speed curve) and the masses
are parameters (:data:`PARAMETERS`, :data:`MASSES`) and the other limits
bounds. So one built problem (:class:`StrokeProblem`, shared by
:func:`planner_for`) serves every duration, mode, mold height, friction,
mass, drive and drive limit, and a re-plan warm-starts IPOPT from the previous
primal and dual solution, stretched in time to the new duration. IPOPT's
functions are per-node jets of the plant feeding a model of the rest (see
:class:`StrokeProblem`), compiled to machine code once and kept on disk
under a hash of what determines them (the code this module imports, not
plots or the CLI; the plant's geometry and friction model; N:
:mod:`controllers.compiled`), so a new process builds a problem in
milliseconds; without a C compiler they are built symbolically and
interpreted.

Speed (``benchmarks/bench_planner.py``, chang2021, N = 200, 3 s, two shared
cores): a cold plan takes about 0.25 s with the disk cache filled (the problem
loaded in about 12 ms, 62 IPOPT iterations), a warm re-plan about 14 ms for
another duration (3 iterations), 25 ms for another mold height and 17 ms for
another v_max or mu; the best of several starts about 1.3 s, minimum time under
a force limit about 2 s; the first plan of a plant (or after a change of the
code it uses) compiles for about 10 s.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import astuple, dataclass, field, fields, replace
from typing import Any, NamedTuple

import casadi as ca
import numpy as np
from scipy.optimize import brentq

from controllers.bounds import peak_lower_bound
from controllers.compiled import Unit, code_digest, compiled
from controllers.limits import DriveLimits
from controllers.profiles import (
    Profile,
    ProfileError,
    ProfileSamples,
    minimum_time,
    predict,
    ramp_time,
    s_curve,
)
from toggle.drive import drive_torque, reflected_mass, torque_speed_limit, travel_per_radian
from toggle.elastics import ClampingError, clamp_stroke, contact_for_clamp_force
from toggle.interrupts import signals_survive
from toggle.params import (
    MAX_CURVE_POINTS,
    Drive,
    Dynamics,
    Mechanism,
    ParameterError,
    symbolic_copy,
)
from toggle.plant import PlantConfig, configure, plant_outputs

OBJECTIVES = ("peak", "rms", "energy")
CONTACT_SPEED = 5e-3  # m/s, default limit on the platen's speed at mold contact
#: Default mold-protection distance: this fraction of the platen's travel from the open
#: position to mold contact (4.5 mm of chang2021's 45 mm; see :func:`protection_entry`).
PROTECT_FRACTION = 0.1
#: A protection cap that is not set: a value no plan reaches (the cap stays a parameter).
_NO_CAP = 1e12
INTERVALS = 200
#: While clamping the crosshead moves at least this many times the plant's friction-smoothing
#: speed (tanh(v / v_eps)), except while it settles in the last tenth of the clamping phase:
#: below it the smooth friction model fades out, and a plan creeping there would exploit that.
CREEP_FACTOR = 10.0
_REGULARISATION = 1e-2  # weight of the squared jerk (relative to its limit), for uniqueness
_BINDING = 0.99  # a limit counts as binding above this fraction of its value
#: Objective weights (peak, force integral, duration, jerk regularisation, and whether the
#: integral is of the motor torque, with the drive's inertia, rather than of the input force)
#: of each objective: "energy" minimises the integral of the squared motor torque, the
#: motor's copper losses (R / k_t^2 times it), the part of a stroke's energy the motion
#: decides (:mod:`controllers.duty`).
_WEIGHTS = {"peak": [1.0, 0.0, 0.0, _REGULARISATION, 0.0], "rms": [0.0, 1.0, 0.0, 0.0, 0.0],
            "energy": [0.0, 1.0, 0.0, 0.0, 1.0]}
#: best(): stretches of the late S-curve starts, and the gap to the lower bound that ends
#: the search (relative).
_LATE_STARTS = (1.0, 1.1, 1.25)
_GAP = 3e-3
_LIMIT_STEP = 0.02  # largest relative step of the force limit in minimum_time's continuation
#: minimum_time asks :meth:`ClampPlanner.least_peak` (a best plan and one more solve) only
#: for a limit within this fraction above the lower bound, where the bound may not be
#: reached (chang2021: the least peak is 0.2 % above it); above, the continuation decides.
_NEAR_BOUND = 0.05
#: The least peak's local optima differ by a few 1e-5 with the starts a planner's history
#: gives :meth:`ClampPlanner.best` (chang2021: 14.94101 N in a fresh process, 14.94045 N
#: warm from other plans); a limit within this fraction below the least peak found is left
#: to the continuation, not refused.
_LEAST_MARGIN = 1e-4
#: The same from a trade-off's previous point, which is already on the path: one step to
#: the next point where they are within 40 % (six points of the dry cycle's curve, a factor
#: of four, are 32 % apart; steps of 8 % took 26 solves, one step 11, the same curve to
#: 2e-5).
_TRADE_STEP = 0.4
_BASELINE_STEP = 0.8  # factor on a baseline's acceleration while it breaks the torque curve
_TIGHTEN = 4  # re-plans of minimum_time with the limit tightened by the excess between nodes
#: The variables are scaled (see :class:`StrokeProblem`), so MUMPS's own row and column
#: scaling of every KKT matrix only costs time (a tenth of a warm re-plan).
_IPOPT = {"print_level": 0, "sb": "yes", "max_iter": 500, "tol": 1e-6,
          "acceptable_tol": 1e-4, "mu_strategy": "adaptive", "mumps_permuting_scaling": 0,
          "mumps_scaling": 0}
#: From a nearby solution the monotone barrier update, started small, takes the fewest steps.
_WARM = {"warm_start_init_point": "yes", "mu_strategy": "monotone", "mu_init": 1e-7,
         "warm_start_bound_push": 1e-9, "warm_start_bound_frac": 1e-9,
         "warm_start_slack_bound_push": 1e-9, "warm_start_slack_bound_frac": 1e-9,
         "warm_start_mult_bound_push": 1e-9}
#: A minimum-time solve warm-starts from a plan under another force limit (the steps of
#: :meth:`ClampPlanner.minimum_time`'s continuation, a trade-off's next point), farther off:
#: there the barrier starts at 1e-5 (chang2021's trade-off curve with the mold: 1270 warm
#: iterations at 1e-7, 550 at 1e-5, the same curve to 3e-7; a re-plan of another duration
#: or mold height takes 3-27 iterations at 1e-7 and 20-27 at 1e-5).
_WARM_FAR = {**_WARM, "mu_init": 1e-5}


class PlanningError(ValueError):
    """A request no profile can meet; the message names the binding limit."""


@dataclass(frozen=True)
class Protection:
    """The mold-protection zone as machine controls define it: over the last ``distance``
    m of platen travel before mold contact (default :data:`PROTECT_FRACTION` of the
    platen's travel to contact) the platen moves at most ``speed`` m/s and the input force
    stays within ``force`` N (a part left in the mold stops the clamp); None: no cap."""

    distance: float | None = None
    speed: float | None = None
    force: float | None = None

    def __post_init__(self) -> None:
        for name in ("distance", "speed", "force"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ParameterError(f"protection {name} must be > 0, got {value!r}")


def protection_entry(cfg: PlantConfig, distance: float | None) -> tuple[float, float]:
    """The crosshead position where the mold-protection zone begins, ``distance`` m of
    platen travel before mold contact (default :data:`PROTECT_FRACTION` of the platen's
    travel from the open position to contact), and that distance, m."""
    free = cfg.with_(x_contact=None)
    x_open = clamp_stroke(cfg.mechanism)[0]

    def platen(x: float) -> float:
        return float(plant_outputs(x, 0.0, 0.0, free).platen_position)

    travel = platen(cfg.x_contact) - platen(x_open)
    distance = PROTECT_FRACTION * travel if distance is None else distance
    if not 0 < distance < travel:
        raise ParameterError(f"protection distance {distance!r} m must be > 0 and shorter than "
                             f"the platen's travel to mold contact ({travel:.6g} m)")
    target = platen(cfg.x_contact) - distance
    return brentq(lambda x: platen(x) - target, x_open, cfg.x_contact, xtol=1e-14), distance


@dataclass(frozen=True)
class Plan:
    """A planned stroke: the profile, its prediction through the plant and solver data."""

    profile: Profile
    config: PlantConfig = field(repr=False)
    objective: str
    t_contact: float
    solve_time: float
    iterations: int
    warm: bool
    solution: dict[str, np.ndarray] = field(repr=False)  # scaled primal and dual solution

    @property
    def duration(self) -> float:
        return self.profile.duration

    @functools.cached_property
    def samples(self) -> ProfileSamples:
        """The profile every millisecond through the plant, computed when first asked for."""
        return predict(self.profile, self.config)

    @property
    def peak_force(self) -> float:
        return self.samples.peak_force

    @property
    def rms_force(self) -> float:
        return self.samples.rms_force


def plan_config(
    mechanism: str | Mechanism,
    *,
    mu: float | None = None,
    x_contact: float | None = None,
    clamp_force: float | None = None,
    masses: dict[str, float] | None = None,
    errors: dict[str, float] | None = None,
) -> PlantConfig:
    """The plant to plan for (:func:`toggle.plant.configure`, the one plant configuration
    the FMU also uses), with the mold-contact position set.

    Give the mold-contact crosshead position ``x_contact`` or the clamp force
    ``clamp_force`` (N) to hold at rest in the locked position, not both; without
    either the preset's final tie-bar force is that clamp force
    (:func:`toggle.elastics.contact_for_clamp_force`). ``errors`` adds dimensional errors
    by seed 000's names, as the FMU's ``delta_*`` parameters do; ``masses`` overrides or,
    for a preset without [dynamics], supplies crosshead, links, platen (kg) and
    guide_damping (N s/m).
    """
    cfg = configure(mechanism, masses=masses, errors=errors)
    mech = cfg.mechanism
    mu = cfg.friction if mu is None else mu
    x_open, x_final = clamp_stroke(mech)
    if x_contact is not None and clamp_force is not None:
        raise ParameterError("give either the mold-contact position or the clamp force")
    if x_contact is None:
        force = mech.clamp.final_tiebar_force if clamp_force is None else clamp_force
        x_contact = contact_for_clamp_force(mech, mu, force)
    elif not (x_open < x_contact < x_final):
        raise ClampingError(f"mold-contact position {x_contact!r} m is outside the stroke "
                            f"({x_open:.6g}, {x_final:.6g}) m")
    return cfg.with_(mu=mu, x_contact=x_contact)


def objective_weights(objective: str, energy_weight: float = 0.0) -> list[float]:
    """The problem's objective weights (:data:`_WEIGHTS`) of ``objective`` plus
    ``energy_weight`` times the integral of the squared motor torque (in the problem's
    scaling: force over the reference force, time over the reference time)."""
    if objective not in OBJECTIVES:
        raise ParameterError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    if not (math.isfinite(energy_weight) and energy_weight >= 0):
        raise ParameterError(f"energy weight must be a number >= 0, got {energy_weight!r}")
    if energy_weight and objective != "peak":
        raise ParameterError(f"an energy weight adds to the peak objective, not to {objective}")
    weights = list(_WEIGHTS[objective])
    if energy_weight:
        weights[1], weights[4] = energy_weight, 1.0
    return weights


def _min_jerk(tau: np.ndarray) -> tuple[np.ndarray, ...]:
    """Rest-to-rest septic polynomial on [0, 1] and its first three derivatives."""
    c = np.array([-20.0, 70.0, -84.0, 35.0, 0, 0, 0, 0])
    return tuple(np.polyval(np.polyder(c, m) if m else c, tau) for m in range(4))


#: The plant outputs the problem evaluates (see :meth:`StrokeProblem._spans`): the input
#: force at the nodes and interval midpoints of each phase, the platen speed at contact.
_OUTPUTS = ("free", "mold", "contact", "free_mid", "mold_mid", "zone", "zone_mid")
#: The functions compiled to machine code: jets of each output (value, + gradient, + Hessian),
#: then the model (:meth:`StrokeProblem._model_functions`).
_MODEL_NAMES = ("input_force", "f_plain", "grad_f_plain", "fg", "grad_f", "jac_g", "hess_lag")


def _names(plants: int) -> tuple[str, ...]:
    """Names of the compiled functions of a problem over ``plants`` plants: the jets of each
    output of each plant (``mold_mid1_2``: plant 1, second order), then the model's."""
    return (*(f"{name}{k}_{order}" for k in range(plants) for name in _OUTPUTS
              for order in range(3)), *_MODEL_NAMES)
#: Optimisation level of the compilation units: the jets are small code doing the plant's
#: arithmetic (-O1 makes them two to three times faster than -O0), the model is 1.6 MB of
#: straight-line C, compiled in seconds at -O0 and in half a minute at -O1, which would save
#: a tenth of the solve time.
_OPTIMISATION = {"jets": ("-O1",), "model": ("-O0",)}
#: The code that determines the problem's functions (this module and what it imports from
#: toggle and controllers, not plots or the CLI), hashed when this module is imported (so
#: the hash matches the code this process runs, even if the files change later).
_SOURCE = code_digest(__name__)
#: Upper triangle of a symmetric 3 x 3 matrix, row by row (the per-node plant Hessians).
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_JET = 10  # rows of a node's plant data: value, gradient (3), Hessian upper triangle (6)
#: The problem's parameters, in order: objective weights (peak, force integral, duration,
#: jerk regularisation; the mass eta m_drive whose acceleration the integral adds to the
#: input force, kg: 0, or the drive's for the motor torque), mold-contact position (m),
#: force scale (N), time scale T_ref (s), jerk limit (m/s^3), platen speed limit at contact
#: (m/s), pin friction mu; the drive: travel per motor radian (m/rad), efficiency,
#: reflected mass of rotor and screw (kg), the factor on the torque-speed curve (1, less
#: where minimum_time tightens it), the curve's speeds (rad/s) and torques (N m), padded
#: to :data:`MAX_CURVE_POINTS` points; the mold-protection zone's platen speed cap (m/s)
#: and input-force cap (N).
PARAMETERS = ("w_peak", "w_energy", "w_time", "w_jerk", "w_inertia", "x_contact", "f_ref",
              "t_ref", "jerk", "contact_speed", "mu", "travel", "efficiency", "drive_mass",
              "torque_factor",
              *(f"curve_speed{k}" for k in range(MAX_CURVE_POINTS)),
              *(f"curve_torque{k}" for k in range(MAX_CURVE_POINTS)),
              "protect_speed", "protect_force")
_P = {name: k for k, name in enumerate(PARAMETERS)}
#: The masses and guide friction of each plant (:class:`toggle.params.Dynamics`), parameters
#: of the problem after the plants' force scales, in this order for each plant.
MASSES = tuple(f.name for f in fields(Dynamics))
#: A drive and masses whose values are all parameters of the problem: what its plants
#: carry, so that neither is part of the compile key (:func:`_neutral`).
_NEUTRAL_DRIVE = Drive(ratio=1.0, lead=1.0, efficiency=1.0, pulses_per_rev=1)
_NEUTRAL_DYNAMICS = Dynamics(crosshead=1.0, links=1.0, platen=1.0)


def _neutral(cfg: PlantConfig) -> PlantConfig:
    """The plant as a problem is built for it: without mold and friction, with the neutral
    drive and masses (all parameters of the problem)."""
    return cfg.with_(x_contact=None, mu=None, mechanism=replace(
        cfg.mechanism, drive=_NEUTRAL_DRIVE, dynamics=_NEUTRAL_DYNAMICS))


def _masses(cfg: PlantConfig) -> list[float]:
    """The plant's :data:`MASSES` (kg, N s/m, N), parameters of the problem."""
    return [float(getattr(cfg.dynamics, name)) for name in MASSES]


def _curve_parameters(limits: DriveLimits) -> list[float]:
    """The torque-speed curve's speeds and torques, padded to :data:`MAX_CURVE_POINTS`
    points by flat steps beyond the last (which add nothing to the curve)."""
    speeds, torques = (list(c) for c in zip(*limits.curve))
    while len(speeds) < MAX_CURVE_POINTS:
        speeds.append(speeds[-1] + 1.0)
        torques.append(torques[-1])
    return [*speeds, *torques]


def _problem_key(cfg: PlantConfig, intervals: int, variants: tuple[PlantConfig, ...] = (),
                 opening: bool = False) -> str:
    """Everything that determines a :class:`StrokeProblem`'s functions, the key of their
    disk cache: the code the problem uses, the plants (every field of the frozen parameters,
    floats in their exact repr; mold height, friction, masses, the drive and its limits
    are parameters of the problem, not part of the key: :func:`_neutral`), N and the
    direction (opening or closing)."""
    plants = [astuple(_neutral(c)) for c in (cfg, *variants)]
    return "\n".join((_SOURCE, *map(repr, (*plants, intervals)), *(("opening",) * opening)))


def _jets(name: str, output: ca.SX, z: ca.SX, prm: ca.SX, nodes: int
          ) -> tuple[ca.Function, ...]:
    """One plant output h(z, prm) of a node, z = (x, v, a), prm = (x_contact, mu), as three
    functions of (z at ``nodes`` nodes, prm) -> its value, first- and second-order jet at
    each node, a :data:`_JET`-row column per node (missing orders zero). Mapped here, so
    that the map is compiled into a loop too."""
    H, g = ca.hessian(output, z)
    zero = ca.SX.zeros
    rows = (ca.vertcat(output, zero(_JET - 1)), ca.vertcat(output, g, zero(_JET - 4)),
            ca.vertcat(output, g, *[H[i, j] for i, j in _UPPER]))
    return tuple(ca.Function(f"{name}{k}_node", [z, prm], [r], {"cse": True}).map(
        f"{name}{k}", "serial", nodes, [1], []) for k, r in enumerate(rows))


class Layout(NamedTuple):
    """Where each scaled variable sits in the decision vector of N intervals: position,
    velocity and acceleration at the N + 1 nodes, the jerk of each interval, the interval
    lengths of the approach and the clamping, the peak's epigraph variable s, and the
    interval length of the mold-protection zone (:meth:`StrokeProblem.steps`)."""

    position: slice
    velocity: slice
    acceleration: slice
    jerk: slice
    steps: slice
    peak: int
    zone_step: int
    size: int

    @classmethod
    def of(cls, N: int) -> Layout:
        nodes = [slice(k * (N + 1), (k + 1) * (N + 1)) for k in range(3)]
        return cls(*nodes, slice(3 * N + 3, 4 * N + 3), slice(4 * N + 3, 4 * N + 5),
                   4 * N + 5, 4 * N + 6, 4 * N + 7)


class StrokeProblem:
    """The optimal control problem for one mold-free plant and N, built once; the mold
    height, the pin friction, the masses, the drive, its limits and the contact-speed limit
    are parameters (:data:`PARAMETERS`, :data:`MASSES`) or bounds, so changing them neither
    rebuilds nor recompiles.

    Variables are scaled: position xi = (x - x_open) / S, velocity, acceleration and jerk
    in units of S / T_ref^k, interval lengths theta in units of T_ref (T_ref a parameter).
    The plant enters only through its outputs at the nodes and at the interval midpoints
    (input force, platen speed at contact), each a function of that point's (x, v, a). So
    IPOPT's derivatives are assembled from per-node jets (value, gradient, Hessian of each
    output, small SX functions mapped over the nodes) and a small SX graph of the rest, in
    which each output is its second-order Taylor model about the current point: exact
    value, gradient and Hessian of the Lagrangian there, without CasADi differentiating
    through the mapped plant at every call. Both come from the disk cache of compiled code
    when it holds this problem (:func:`_problem_key`), else they are built and compiled;
    only the small MX graph joining them is built here.

    Constraints, in order (:attr:`rows`): the dynamics (3N), contact at node N1, the force
    epigraph F - s <= 0 and F + s >= 0 at nodes and midpoints, the platen speed at
    contact, the duration and the velocity at the midpoints (N); with ``torque``, the
    motor torque over the torque-speed curve at nodes and midpoints, in [-1, 1]. Those
    rows cost a third of the solve time, so the problem without them comes first and its
    sibling with them (:attr:`with_torque`, built when first asked for) serves the plans
    the curve limits (:meth:`ClampPlanner._run`); they come last, after the mold-protection
    zone's (only in :attr:`with_zone`, for plans with caps): its entry at node NA, the
    platen speed and the input force over its nodes and midpoints. The closing
    stroke has three phases, each of equal intervals: the approach (NA intervals, length
    w[4N+3]), the protection zone up to contact (N1 - NA, w[4N+6]) and the clamp-up (N - N1,
    w[4N+4]).
    ``opening``: the same problem run backwards in time (the opening stroke).
    """

    def __init__(self, cfg: PlantConfig, intervals: int,
                 variants: tuple[PlantConfig, ...] = (), torque: bool = False,
                 opening: bool = False, zone: bool = False) -> None:
        if not (isinstance(intervals, int) and intervals >= 4):
            raise ParameterError(f"intervals must be an integer >= 4, got {intervals!r}")
        self.config, self.variants, self.torque = cfg, variants, torque
        self.opening, self.zone = opening, zone
        self.plants = (cfg, *variants)
        self.x_open, self.x_final = clamp_stroke(cfg.mechanism)
        lo, hi = cfg.input_range
        if not (lo <= self.x_open and self.x_final <= hi):
            raise ParameterError("the stroke leaves the assemblable range")
        self.stroke = self.x_final - self.x_open
        N = intervals
        self.n1, self.n2 = N - N // 2, N // 2
        self.nz = max(1, self.n1 // 4)  # intervals in the mold-protection zone
        self.na = self.n1 - self.nz
        self.layout = Layout.of(N)
        self.size = self.layout.size
        # input force at the N + 2 phase nodes and N midpoints, of each plant
        self.n_forces = (2 * N + 2) * len(self.plants)
        sizes = {"dynamics": 3 * N, "contact_position": 1, "force_upper": self.n_forces,
                 "force_lower": self.n_forces, "contact_speed": len(self.plants), "duration": 1,
                 "mid_velocity": N, "zone_position": 1 if zone else 0,
                 "zone_speed": (2 * self.nz + 1) * len(self.plants) if zone else 0,
                 "zone_force": (2 * self.nz + 1) * len(self.plants) if zone else 0,
                 "torque": self.n_forces if torque else 0}
        starts = np.cumsum([0, *sizes.values()])
        self.rows = {name: slice(int(a), int(b)) for name, a, b in
                     zip(sizes, starts[:-1], starts[1:])}
        self.n_constraints = int(starts[-1])
        #: :data:`PARAMETERS`, then each plant's force scale (its forces count divided by it),
        #: then each plant's :data:`MASSES`
        self.n_parameters = len(PARAMETERS) + len(self.plants) * (1 + len(MASSES))
        self._solvers: dict[tuple[bool, bool, bool], Any] = {}
        self.last: Plan | None = None  # the latest plan, for any mold height
        self._build()

    def steps(self, w: Any) -> Any:
        """The interval lengths (scaled) of the three phases: approach, protection zone,
        clamp-up (without the caps' rows the zone's are the approach's: the zone's own
        length is then a variable fixed by its bounds, unused)."""
        lay = self.layout
        return ca.vertcat(ca.repmat(w[lay.steps.start], self.na, 1),
                          ca.repmat(w[lay.zone_step if self.zone else lay.steps.start],
                                    self.nz, 1),
                          ca.repmat(w[lay.steps.start + 1], self.n2, 1))

    def _nodes(self, w: Any, t_ref: Any) -> tuple[Any, ...]:
        """Scaled variables -> (xi, nu, al, jerk, th1, th2, s, nu at the midpoints) and the
        states (3 x 2N+1: the N+1 nodes, then the N interval midpoints)."""
        lay = self.layout
        xi, nu, al, io = (w[part] for part in lay[:4])
        th1, th2 = w[lay.steps.start], w[lay.steps.start + 1]
        h = self.steps(w) / 2
        xi_m = xi[:-1] + h * (nu[:-1] + h * (al[:-1] / 2 + h * io / 6))
        nu_m = nu[:-1] + h * (al[:-1] + h * io / 2)
        al_m = al[:-1] + h * io
        S = self.stroke
        z = ca.vertcat(self.x_open + S * ca.horzcat(xi.T, xi_m.T),
                       S / t_ref * ca.horzcat(nu.T, nu_m.T),
                       S / t_ref**2 * ca.horzcat(al.T, al_m.T))
        return xi, nu, al, io, th1, th2, w[lay.peak], nu_m, z

    def _spans(self) -> tuple[slice, ...]:
        """The columns of the states (:meth:`_nodes`) of each of :data:`_OUTPUTS`: the
        mold-free input force over the approach, the input force with the mold over the
        clamping, the platen speed at contact, then the forces at the midpoints, then the
        platen speed over the protection zone's nodes and midpoints."""
        n1, na, N = self.n1, self.na, self.n1 + self.n2
        return (slice(0, n1 + 1), slice(n1, N + 1), slice(n1, n1 + 1),
                slice(N + 1, N + 1 + n1), slice(N + 1 + n1, 2 * N + 1),
                slice(na, n1 + 1), slice(N + 1 + na, N + 1 + n1))

    def _symbolic(self) -> list[Unit]:
        """The per-node jets of :data:`_OUTPUTS` and the model as SX functions, in
        compilation units (see :data:`_OPTIMISATION`)."""
        # prm: x_contact, mu, the plant's MASSES
        z, prm = ca.SX.sym("z", 3), ca.SX.sym("prm", 2 + len(MASSES))
        dynamics = symbolic_copy(_NEUTRAL_DYNAMICS, **dict(zip(MASSES, ca.vertsplit(prm[2:]))))
        jets = []
        for k, plant in enumerate(self.plants):
            plant = plant.with_(mechanism=replace(plant.mechanism, dynamics=dynamics))
            # the opening stroke is the closing one run backwards in time: v -> -v
            v = -z[1] if self.opening else z[1]
            free = plant_outputs(z[0], v, z[2], plant, mu=prm[1])
            mold = plant_outputs(z[0], v, z[2], plant, x_contact=prm[0], mu=prm[1])
            speed = -free.platen_velocity if self.opening else free.platen_velocity
            outputs = (free.input_force, mold.input_force, speed, free.input_force,
                       mold.input_force, speed, speed)
            jets += [fn for name, out, nodes in zip(_OUTPUTS, outputs, self._spans())
                     for fn in _jets(f"{name}{k}_", ca.SX(out), z, prm,
                                     nodes.stop - nodes.start)]
            if k == 0:
                force = ca.Function("input_force", [z, prm], [mold.input_force], {"cse": True})
        *values, hess = self._model_functions()
        return [(_OPTIMISATION["jets"], [*jets, force]), (_OPTIMISATION["model"], values),
                (_OPTIMISATION["model"], [hess])]

    def _model(self, w: ca.SX, w0: ca.SX, p: ca.SX, data: ca.SX) -> tuple[ca.SX, ca.SX]:
        """Objective and constraints with each plant output replaced by its Taylor model
        about the point w0, from the node data (:data:`_JET` rows per output and node, the
        outputs' nodes :meth:`_spans`)."""
        n1, na, t_ref = self.n1, self.na, p[_P["t_ref"]]
        xi, nu, al, io, th1, th2, s, nu_m, z = self._nodes(w, t_ref)
        thz = w[self.layout.zone_step] if self.zone else th1
        dz = z - self._nodes(w0, t_ref)[-1]
        outputs, col = [], 0
        for nodes in self._spans() * len(self.plants):
            d, n = dz[:, nodes], nodes.stop - nodes.start
            block = data[:, col:col + n]
            quad = sum((1 if i == j else 2) * block[4 + k, :] * d[i, :] * d[j, :]
                       for k, (i, j) in enumerate(_UPPER))
            outputs.append(block[0, :] + ca.sum1(block[1:4, :] * d) + quad / 2)
            col += n
        each = len(_OUTPUTS)
        torque = self._torque_ratio(outputs, z, p) if self.torque else ca.SX(0, 1)
        F = ca.vertcat(outputs[0].T, outputs[1].T) / p[_P["f_ref"]]  # the first plant's
        scales = p[len(PARAMETERS):len(PARAMETERS) + len(self.plants)]
        forces = ca.vertcat(*[ca.vertcat(*[outputs[k + j].T for j in (0, 1, 3, 4)])
                              / scales[k // each] for k in range(0, len(outputs), each)]
                            ) / p[_P["f_ref"]]
        contact = ca.vertcat(*outputs[2::each]) / p[_P["contact_speed"]]
        zone_speed = ca.vertcat(*[ca.vertcat(outputs[k + 5].T, outputs[k + 6].T)
                                  for k in range(0, len(outputs), each)]) / p[_P["protect_speed"]]
        zone_force = ca.vertcat(*[ca.vertcat(outputs[k][:, na:].T, outputs[k + 3][:, na:].T)
                                  for k in range(0, len(outputs), each)]) / p[_P["protect_force"]]
        h = self.steps(w)
        dyn = ca.vertcat(
            xi[1:] - (xi[:-1] + h * (nu[:-1] + h * (al[:-1] / 2 + h * io / 6))),
            nu[1:] - (nu[:-1] + h * (al[:-1] + h * io / 2)),
            al[1:] - (al[:-1] + h * io),
        )

        def integral(Fp: ca.SX, step: ca.SX) -> ca.SX:  # trapezoidal rule
            return step * (ca.sumsqr(Fp) - (Fp[0] ** 2 + Fp[-1] ** 2) / 2)

        # the integrand: the input force, or (w_inertia = eta m_drive) the motor torque over
        # p / eta (toggle.drive.drive_torque), at the nodes in F's order (node n1 twice)
        N = n1 + self.n2
        F = F + p[_P["w_inertia"]] * ca.vertcat(z[2, :n1 + 1].T, z[2, n1:N + 1].T) / p[
            _P["f_ref"]]
        energy = (integral(F[:na + 1], th1) + integral(F[na:n1 + 1], thz)
                  + integral(F[n1 + 1:], th2))
        duration = ca.sum1(h)
        jerk_bound = p[_P["jerk"]] * t_ref**3 / self.stroke
        objective = (p[_P["w_peak"]] * s + p[_P["w_energy"]] * energy
                     + p[_P["w_time"]] * duration
                     + p[_P["w_jerk"]] * ca.dot(h, (io / jerk_bound) ** 2))
        return objective, ca.vertcat(dyn, xi[n1], forces - s, forces + s, contact, duration,
                                     nu_m, *((xi[na], zone_speed, zone_force) if self.zone else ()),
                                     torque)

    def _torque_ratio(self, outputs: list[ca.SX], z: ca.SX, p: ca.SX) -> ca.SX:
        """The motor torque (:func:`toggle.drive.drive_torque` of each plant's input force
        and the acceleration) over the torque-speed curve at the motor speed (times the
        curve's factor), at the nodes and midpoints: rows in [-1, 1] (one two-sided row
        each, half the rows, and half the cost of the KKT system, of a pair)."""
        travel = p[_P["travel"]]
        speeds = [p[_P[f"curve_speed{k}"]] for k in range(MAX_CURVE_POINTS)]
        torques = [p[_P[f"curve_torque{k}"]] for k in range(MAX_CURVE_POINTS)]
        torque, limit = [], []
        for k in range(0, len(outputs), len(_OUTPUTS)):
            for j in (0, 1, 3, 4):
                states = z[:, self._spans()[j]]
                torque.append(drive_torque(outputs[k + j], states[2, :], travel,
                                           p[_P["efficiency"]], p[_P["drive_mass"]]).T)
                limit.append(p[_P["torque_factor"]] * torque_speed_limit(
                    states[1, :] / travel, speeds, torques).T)
        return ca.vertcat(*torque) / ca.vertcat(*limit)

    def _model_functions(self) -> list[ca.Function]:
        """The model's value (f, g), gradient, constraint Jacobian and Hessian of the
        Lagrangian, functions of (w, p, node data): derivatives of the Taylor models taken
        about w0, then evaluated at w0 = w, where the models are exact to second order. And
        the objective's value and gradient without the force integral (its weight zero: the
        peak and minimum-time objectives), functions of (w, p) alone, so that IPOPT
        evaluates no plant for them."""
        m = sum(nodes.stop - nodes.start for nodes in self._spans()) * len(self.plants)
        w, w0 = ca.SX.sym("w", self.size), ca.SX.sym("w0", self.size)
        p, data = ca.SX.sym("p", self.n_parameters), ca.SX.sym("data", _JET, m)
        lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", self.n_constraints)
        f, g = self._model(w, w0, p, data)
        hess = ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), w)[0])
        f, g, grad, jac, hess = ca.substitute(
            [f, g, ca.gradient(f, w), ca.jacobian(g, w), hess], [w0], [w])
        args, opts = [w, p, data], {"cse": True}
        plain, plain_grad = ca.substitute([f, grad], [p[_P["w_energy"]]], [0.0])
        return [ca.Function("f_plain", [w, p], [plain], opts),
                ca.Function("grad_f_plain", [w, p], [plain, plain_grad], opts),
                ca.Function("fg", args, [f, g], opts),
                ca.Function("grad_f", args, [f, grad], opts),
                ca.Function("jac_g", args, [g, jac], opts),
                ca.Function("hess_lag", [*args, lam_f, lam_g], [hess], opts)]

    def _build(self) -> None:
        """The NLP functions IPOPT calls (value, gradient, constraint Jacobian, Hessian of
        the Lagrangian), each the per-node jets mapped over the nodes feeding the model;
        the jets and the model come compiled from the disk cache where possible."""
        N = self.n1 + self.n2
        key = _problem_key(self.config, N, self.variants, self.opening) + (
            "\ntorque" if self.torque else "") + ("\nzone" if self.zone else "")
        names = _names(len(self.plants))
        fn = dict(zip(names, compiled("stroke", key, names, self._symbolic)))
        W, P = ca.MX.sym("x", self.size), ca.MX.sym("p", self.n_parameters)
        L_f, L_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", self.n_constraints)
        z = self._nodes(W, P[_P["t_ref"]])[-1]
        first, n = len(PARAMETERS) + len(self.plants), len(MASSES)
        prm = [ca.vertcat(P[_P["x_contact"]], P[_P["mu"]], P[first + n * k:first + n * (k + 1)])
               for k in range(len(self.plants))]

        def node_data(order: int) -> ca.MX:
            return ca.horzcat(*[fn[f"{name}{k}_{order}"](z[:, nodes], prm[k])
                                for k in range(len(self.plants))
                                for name, nodes in zip(_OUTPUTS, self._spans())])

        self._force = fn["input_force"]
        values, slopes = node_data(0), node_data(1)
        f, g = fn["fg"](W, P, values)
        objectives = {True: (f, fn["grad_f"](W, P, slopes)),
                      False: (fn["f_plain"](W, P), fn["grad_f_plain"](W, P))}
        self._nlp = {energy: (ca.Function("nlp", [W, P], [obj, g], ["x", "p"], ["f", "g"]),
                              ca.Function("nlp_grad_f", [W, P], grad, ["x", "p"],
                                          ["f", "grad_f_x"]))
                     for energy, (obj, grad) in objectives.items()}
        self._derivatives = {
            "jac_g": ca.Function("nlp_jac_g", [W, P], fn["jac_g"](W, P, slopes),
                                 ["x", "p"], ["g", "jac_g_x"]),
            "hess_lag": ca.Function("nlp_hess_l", [W, P, L_f, L_g],
                                    [fn["hess_lag"](W, P, node_data(2), L_f, L_g)],
                                    ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"]),
        }
        n1, spans = self.n1, self._spans()
        forces = [values[0, col:col + s.stop - s.start] for col, s in
                  zip(np.cumsum([0, *(s.stop - s.start for s in spans)]), spans)]
        #: input force (N) at the nodes and midpoints, platen speed at contact (m/s), the
        #: states (x, v, a) at the nodes and midpoints (columns in the forces' order)
        self.monitor = ca.Function("monitor", [W, P], [
            ca.vertcat(forces[0][:n1 + 1].T, forces[1][1:].T, forces[3].T, forces[4].T),
            forces[2], z])
        lbg, ubg = np.zeros(self.n_constraints), np.zeros(self.n_constraints)
        r = self.rows
        lbg[r["force_upper"]], ubg[r["force_lower"]] = -np.inf, np.inf
        lbg[r["contact_speed"]], ubg[r["contact_speed"]] = -np.inf, 1.0
        lbg[r["zone_speed"]], ubg[r["zone_speed"]] = -np.inf, 1.0
        lbg[r["zone_force"]], ubg[r["zone_force"]] = -1.0, 1.0
        ubg[r["duration"]] = np.inf
        lbg[r["torque"]], ubg[r["torque"]] = -1.0, 1.0
        self.g_bounds = (lbg, ubg)

    @functools.cached_property
    def with_torque(self) -> StrokeProblem:
        """The same problem with the torque-speed curve's rows (itself if it has them)."""
        if self.torque:
            return self
        return _problem_for(self.config, self.n1 + self.n2, self.variants, torque=True,
                            opening=self.opening, zone=self.zone)

    @functools.cached_property
    def with_zone(self) -> StrokeProblem:
        """The same problem with the mold-protection caps' rows (itself if it has them):
        the plans without caps do without them."""
        if self.zone:
            return self
        return _problem_for(self.config, self.n1 + self.n2, self.variants, torque=self.torque,
                            opening=self.opening, zone=True)

    def input_force(self, x: Any, v: Any, a: Any, cfg: PlantConfig) -> np.ndarray:
        """The input force (N) at the points (x, v, a) of the plant ``cfg`` (its mold, pin
        friction and masses; the function of the clamping phase's jets, exact before
        contact too, compiled)."""
        z = np.vstack(np.broadcast_arrays(x, v, a)).astype(float)
        return np.asarray(self._force(z, [cfg.x_contact, cfg.friction,
                                          *_masses(cfg)]))[0]

    def solver(self, warm: bool, energy: bool, far: bool = False) -> Any:
        """The IPOPT instance, cold or with the warm-start options (``far``: from a plan
        under another force limit, :data:`_WARM_FAR`), for an objective with the force
        integral (``energy``) or without it (each built once)."""
        far = far and warm
        if (warm, energy, far) not in self._solvers:
            nlp, grad_f = self._nlp[energy]
            options = (_WARM_FAR if far else _WARM) if warm else {}
            opts = {"ipopt": {**_IPOPT, **options}, "print_time": False,
                    "error_on_fail": False, "calc_lam_p": False, "no_nlp_grad": True,
                    "grad_f": grad_f, **self._derivatives}
            self._solvers[warm, energy, far] = ca.nlpsol("plan", "ipopt", nlp, opts)
        return self._solvers[warm, energy, far]


@functools.lru_cache(maxsize=8)
def _problem_for(cfg: PlantConfig, intervals: int, variants: tuple[PlantConfig, ...] = (),
                 torque: bool = False, opening: bool = False, zone: bool = False
                 ) -> StrokeProblem:
    """A built problem, shared by the planners of every mold height, friction, drive and
    drive limits of one plant (and variants), with or without the torque rows, closing or
    opening."""
    return StrokeProblem(cfg, intervals, variants, torque, opening, zone)


class ClampPlanner:
    """Plans strokes of one plant with its mold, on a :class:`StrokeProblem`.

    :meth:`solve` plans a stroke of a given duration, :meth:`minimum_time`
    the fastest one under a force limit; each warm-starts from the previous
    solution on the same problem (another duration, mold height, friction or
    drive limit) unless told otherwise. Without ``problem`` the planner builds
    its own. With ``variants`` (the clamp with other dimensional errors or masses) the
    force limits and the peak objective hold for the worst of the plant and its variants,
    with the mold at the same crosshead position: a robust plan (:meth:`worst_peak`).
    ``scales`` divide the variants' forces in the objective and the limit (default 1:
    the absolute worst case; a variant's baseline peak over the plant's weighs each
    against its own baseline).
    """

    def __init__(self, cfg: PlantConfig, limits: DriveLimits, *,
                 contact_speed: float = CONTACT_SPEED, intervals: int = INTERVALS,
                 problem: StrokeProblem | None = None,
                 variants: tuple[PlantConfig, ...] = (),
                 scales: tuple[float, ...] | None = None,
                 protection: Protection = Protection()) -> None:
        if cfg.x_contact is None:
            raise ParameterError("the planner needs a mold-contact position (x_contact)")
        if not (math.isfinite(contact_speed) and contact_speed > 0):
            raise ParameterError(f"contact speed must be > 0 m/s, got {contact_speed!r}")
        self.problem = problem or StrokeProblem(
            _neutral(cfg), intervals, tuple(_neutral(v) for v in variants))
        pr = self.problem
        self.config, self.limits, self.contact_speed = cfg, limits, contact_speed
        self.variants = tuple(v.with_(x_contact=cfg.x_contact, mu=cfg.mu) for v in variants)
        self.scales = tuple(scales or (1.0,) * len(variants))
        if len(self.scales) != len(variants) or not all(
                math.isfinite(k) and k > 0 for k in self.scales):
            raise ParameterError(f"need one positive force scale per variant, got {scales!r}")
        self.x_open, self.x_final, self.stroke = pr.x_open, pr.x_final, pr.stroke
        self.t_ref = minimum_time(self.stroke, limits.velocity, limits.acceleration, limits.jerk)
        self.jerk_bound = limits.jerk * self.t_ref**3 / self.stroke
        self.n1, self.n2 = pr.n1, pr.n2
        self.xi_contact = (cfg.x_contact - self.x_open) / self.stroke
        self.x_zone, self.protect_distance = protection_entry(cfg, protection.distance)
        self.xi_zone = (self.x_zone - self.x_open) / self.stroke
        self.protect_speed, self.protect_force = protection.speed, protection.force
        #: with a cap the zone's entry is pinned to a node; without, the approach and the zone
        #: share one interval length (the problem of a plain two-phase stroke)
        self.capped = (protection.speed, protection.force) != (None, None)
        self.force_limit = limits.force(cfg.mechanism.drive)
        self.f_ref = self._reference_force()
        #: whether this planner's plans need the torque rows (see :meth:`_run`)
        self._torque = False
        self._least: Plan | None = None  # :meth:`least_peak`, once computed
        self._bound: float | None = None  # :meth:`lower_bound`, once computed

    @property
    def creep_speed(self) -> float:
        """The slowest crosshead speed the plans keep while clamping, m/s."""
        return CREEP_FACTOR * self.config.velocity_epsilon

    def clamping_creeps(self, settle: int) -> bool:
        """Whether the clamping (mold contact to the final position) is long enough to hold
        the creep floor on all but its last ``settle`` of n2 intervals: the floor holds for
        at least (n2 - settle) / settle times the fastest stop from :attr:`creep_speed`, so
        the clamping must be longer than that travel. A shorter one (a mold set within
        ~0.2 mm of the toggle on chang2021) builds so little force that its friction cannot
        be exploited, and the floor would make it infeasible."""
        lim, v = self.limits, min(self.creep_speed, self.limits.velocity)
        stop = ramp_time(v, lim.acceleration, lim.jerk)  # creep speed to rest
        travel = v * stop * ((self.n2 - settle) / settle + 0.5)
        return self.x_final - self.config.x_contact > travel

    @property
    def longest(self) -> float:
        """The longest duration planned, s: the S-curve cruising at :attr:`creep_speed`
        (slower strokes, the plan's and the baselines', would cross the clamping where the
        smoothed friction model fades)."""
        return minimum_time(self.stroke, min(self.creep_speed, self.limits.velocity),
                            self.limits.acceleration, self.limits.jerk)

    @property
    def last(self) -> Plan | None:
        """The latest plan on this planner's problem (any mold height)."""
        return self.problem.last

    def _force(self, x: Any, v: Any, a: Any) -> np.ndarray:
        """The plant's input force at the points (x, v, a) with this planner's mold, N."""
        return self.problem.input_force(x, v, a, self.config)

    def _reference_force(self) -> float:
        """Scale of the input force: its quasi-static peak at the reference speed, N."""
        xs = np.linspace(self.x_open, self.x_final, 401)
        f = self._force(xs, self.stroke / self.t_ref, 0.0)
        return max(float(np.max(np.abs(f))), 1e-6)

    def _parameters(self, weights: list[float], torque_factor: float = 1.0,
                    caps: tuple[float | None, float | None] = (None, None)) -> list[float]:
        """The problem's :data:`PARAMETERS` for these objective weights, factor on the
        torque-speed curve and protection caps (speed, force; None: none), then the plants'
        force scales."""
        drive = self.config.mechanism.drive
        weights = [*weights, 0.0][:5]
        weights[4] *= drive.efficiency * reflected_mass(drive)  # w_inertia, kg
        return [*weights, self.config.x_contact, self.f_ref, self.t_ref, self.limits.jerk,
                self.contact_speed, self.config.friction, travel_per_radian(drive),
                drive.efficiency, reflected_mass(drive), torque_factor,
                *_curve_parameters(self.limits), *(_NO_CAP if c is None else c for c in caps),
                1.0, *self.scales,
                *(m for plant in (self.config, *self.variants) for m in _masses(plant))]

    # ---- solving --------------------------------------------------------------------

    def _bounds(self, force_limit: float) -> tuple[np.ndarray, np.ndarray]:
        N, S, t_ref, lim = self.n1 + self.n2, self.stroke, self.t_ref, self.limits
        lay = self.problem.layout
        lbx, ubx = np.empty(lay.size), np.empty(lay.size)
        spans = ((0.0, 1.0),  # stroke limits
                 (0.0, lim.velocity * t_ref / S),  # monotone stroke, top speed
                 (-lim.acceleration * t_ref**2 / S, lim.acceleration * t_ref**2 / S),
                 (-self.jerk_bound, self.jerk_bound))
        for part, (lo, hi) in zip(lay, spans):
            lbx[part], ubx[part] = lo, hi
        # no creeping through the clamping below the friction model's smoothing speed
        # (unless the clamping is too short to cross at creep speed and still settle)
        settle = max(2, self.n2 // 10)
        if self.clamping_creeps(settle):
            v0 = lay.velocity.start
            lbx[v0 + self.n1:v0 + N - settle] = self.creep_speed * t_ref / S
        for part in (lay.velocity, lay.acceleration):  # rest at both ends
            lbx[part.start] = ubx[part.start] = lbx[part.stop - 1] = ubx[part.stop - 1] = 0.0
        ubx[lay.position.start] = 0.0  # from the open position
        lbx[lay.position.stop - 1] = 1.0  # to the toggle
        lbx[lay.steps], ubx[lay.steps] = 1e-6, np.inf
        lbx[lay.peak], ubx[lay.peak] = 0.0, force_limit / self.f_ref
        # the zone's own interval length: free with the caps' rows, else fixed and unused
        lbx[lay.zone_step], ubx[lay.zone_step] = (1e-6, np.inf) if self.capped else (1.0, 1.0)
        return lbx, ubx

    def _constraint_bounds(self, problem: StrokeProblem, t_bounds: tuple[float, float]
                           ) -> tuple[np.ndarray, ...]:
        """Bounds of the constraints: the duration's, contact at node N1, the top speed
        (and a monotone stroke) at the interval midpoints."""
        lbg, ubg = (b.copy() for b in problem.g_bounds)
        rows = problem.rows
        lbg[rows["duration"]], ubg[rows["duration"]] = (t / self.t_ref for t in t_bounds)
        lbg[rows["contact_position"]] = ubg[rows["contact_position"]] = self.xi_contact
        lbg[rows["zone_position"]] = ubg[rows["zone_position"]] = self.xi_zone  # with caps
        ubg[rows["mid_velocity"]] = self.limits.velocity * self.t_ref / self.stroke
        return lbg, ubg

    def _initial_guess(self, duration: float) -> np.ndarray:
        """The septic rest-to-rest polynomial over ``duration``, split at the protection
        zone's entry and at mold contact."""
        r = self.t_ref / duration
        tau_z, tau_c = (brentq(lambda t, xi=xi: _min_jerk(np.array(t))[0] - xi, 0.0, 1.0)
                        for xi in (self.xi_zone, self.xi_contact))
        tau_z = tau_z if self.capped else tau_c * self.problem.na / self.n1
        tau = self._split(1.0, tau_z, tau_c)
        xi, nu, al, _ = _min_jerk(tau)
        jerk = np.diff(al) / np.diff(tau)
        f = self._force(self.x_open + self.stroke * xi, self.stroke * nu / duration,
                        self.stroke * al / duration**2)
        s = float(np.max(np.abs(f))) / self.f_ref
        return np.concatenate([xi, nu * r, al * r**2, jerk * r**3,
                               self._tail(1.0, tau_z, tau_c, r, s)])

    def _split(self, duration: float, t_zone: float, t_contact: float) -> np.ndarray:
        """The node times of a stroke entering the zone at ``t_zone``, in contact at
        ``t_contact``."""
        na, nz, n2 = self.problem.na, self.problem.nz, self.n2
        return np.concatenate([np.linspace(0.0, t_zone, na + 1),
                               np.linspace(t_zone, t_contact, nz + 1)[1:],
                               np.linspace(t_contact, duration, n2 + 1)[1:]])

    def _tail(self, duration: float, t_zone: float, t_contact: float, unit: float, s: float
              ) -> np.ndarray:
        """The last variables: the approach's and clamp-up's interval lengths, the force
        epigraph ``s`` (scaled) and the zone's interval length, times in ``unit``."""
        return np.array([t_zone / self.problem.na / unit, (duration - t_contact) / self.n2 / unit,
                         s, (t_contact - t_zone) / self.problem.nz / unit])

    def _guess_from(self, profile: Profile, duration: float) -> np.ndarray:
        """A profile sampled at the nodes as the scaled variables (nodes split at its mold
        contact), the jerk from the accelerations: an initial guess."""
        t = np.linspace(0.0, duration, 4001)
        tz, tc = (float(np.interp(x, profile.sample(t)[0], t))
                  for x in (self.x_zone, self.config.x_contact))
        tz = tz if self.capped else tc * self.problem.na / self.n1
        S, t_ref = self.stroke, self.t_ref
        t = self._split(duration, tz, tc)
        x, v, a = profile.sample(t)
        s = float(np.max(np.abs(self._force(x, v, a)))) / self.f_ref
        return np.concatenate([(x - self.x_open) / S, v * t_ref / S, a * t_ref**2 / S,
                               np.diff(a) / np.diff(t) * t_ref**3 / S,
                               self._tail(duration, tz, tc, t_ref, s)])

    def _late_guess(self, duration: float, stretch: float) -> np.ndarray:
        """The fastest S-curve stretched in time by ``stretch`` (at most to ``duration``),
        started late so that it ends at ``duration``: it reaches
        the mold at speed and brakes through the clamping, where the braking relieves the
        thrust (the other family of optima than the polynomial guess's slow arrival)."""
        lim = self.limits
        fastest = s_curve(self.x_open, self.x_final, min(self.t_ref * stretch, duration),
                          lim.velocity,
                          lim.acceleration, lim.jerk)
        delay = duration - fastest.duration
        late = Profile(fastest.knots + delay, fastest.x, fastest.v, fastest.a, fastest.jerk)
        late = Profile(np.concatenate(([0.0], late.knots)), np.concatenate(([late.x[0]], late.x)),
                       np.concatenate(([0.0], late.v)), np.concatenate(([0.0], late.a)),
                       np.concatenate(([0.0], late.jerk)))
        return self._guess_from(late, duration)

    def _stretched(self, start: Plan, duration: float, problem: StrokeProblem
                   ) -> dict[str, np.ndarray]:
        """A previous solution stretched in time to ``duration`` and rescaled to this
        planner's time and force scales (the warm start on ``problem``)."""
        sol, lay = start.solution, problem.layout
        t_ref, f_ref = sol["scales"]
        r = start.duration / duration * self.t_ref / t_ref
        w = sol["x"].copy()
        for part, power in ((lay.velocity, 1), (lay.acceleration, 2), (lay.jerk, 3)):
            w[part] *= r**power
        w[lay.steps] /= r
        w[lay.zone_step] /= r
        w[lay.peak] *= f_ref / self.f_ref
        # the rows of the caps and the torque come last: a start from a sibling problem
        # (without them, or with others) shares only the rows before them
        lam_g = np.zeros(problem.n_constraints)
        common = (lam_g.size if sol["lam_g"].size == lam_g.size
                  else min(problem.rows["mid_velocity"].stop, sol["lam_g"].size))
        lam_g[:common] = sol["lam_g"][:common]
        return {"x0": w, "lam_x0": sol["lam_x"], "lam_g0": lam_g}

    def _run(self, weights: list[float], t_bounds: tuple[float, float], force_limit: float,
             objective: str, start: Plan | None, warm: bool,
             guess: np.ndarray | None = None, torque_factor: float = 1.0) -> tuple[Plan, bool]:
        """Solve; with protection caps, where the plan's 1 ms samples exceed a cap between
        the nodes, impose it tighter by the excess and re-solve from the plan."""
        caps = imposed = (self.protect_speed, self.protect_force)
        plan, ok = self._solve_torque(weights, t_bounds, force_limit, objective, start, warm,
                                      guess, torque_factor, caps)
        for _ in range(_TIGHTEN if caps != (None, None) else 0):
            if not ok:
                break
            zone = self.protection(plan)
            reached = (zone["peak_platen_speed"], zone["peak_input_force"])
            excess = [0.0 if c is None else max(r - c, 0.0) for c, r in zip(caps, reached)]
            if not any(excess):
                break
            imposed = tuple(c if c is None else c - 1.5 * e for c, e in zip(imposed, excess))
            plan, ok = self._solve_torque(weights, t_bounds, force_limit, objective, plan, True,
                                          None, torque_factor, imposed)
        return plan, ok

    def _problem(self, torque: bool) -> StrokeProblem:
        """This planner's problem, with the torque rows or not, with the caps' rows if it
        has caps."""
        problem = self.problem.with_torque if torque else self.problem
        return problem.with_zone if self.capped else problem

    def _solve_torque(self, weights: list[float], t_bounds: tuple[float, float],
                      force_limit: float, objective: str, start: Plan | None, warm: bool,
                      guess: np.ndarray | None, torque_factor: float,
                      caps: tuple[float | None, float | None]) -> tuple[Plan, bool]:
        """One IPOPT solve. Without the torque rows first (unless an earlier plan of this
        planner needed them); where that plan's motor torque at the nodes and midpoints
        exceeds the torque-speed curve, again from it with the rows (and for every later
        plan of this planner)."""
        problem = self._problem(self._torque)
        plan, ok = self._solve_on(problem, weights, t_bounds, force_limit, objective, start,
                                  warm, guess, torque_factor, caps)
        if ok and not self._torque and self.node_torque_ratio(plan) > 1.0:
            self._torque = True
            plan, ok = self._solve_on(self._problem(True), weights, t_bounds,
                                      force_limit, objective, plan, True, None, torque_factor,
                                      caps)
        return plan, ok

    def _solve_on(self, problem: StrokeProblem, weights: list[float],
                  t_bounds: tuple[float, float], force_limit: float, objective: str,
                  start: Plan | None, warm: bool, guess: np.ndarray | None,
                  torque_factor: float, caps: tuple[float | None, float | None]
                  ) -> tuple[Plan, bool]:
        start = start or self.last
        warm = warm and start is not None and start.solution["x"].size == problem.size
        lbx, ubx = self._bounds(force_limit)
        lbg, ubg = self._constraint_bounds(problem, t_bounds)
        target = min(max(2 * self.t_ref, t_bounds[0]), t_bounds[1])
        if guess is not None:
            args, warm = {"x0": guess}, False
        else:
            args = (self._stretched(start, target, problem) if warm
                    else {"x0": self._initial_guess(target)})
        args["x0"] = np.clip(args["x0"], lbx, ubx)
        solver = problem.solver(warm, energy=weights[1] > 0, far=objective == "time")
        tic = time.perf_counter()
        with signals_survive():  # IPOPT would turn a Ctrl-C into a failed solve
            sol = solver(p=self._parameters(weights, torque_factor, caps), lbx=lbx, ubx=ubx,
                         lbg=lbg, ubg=ubg, **args)
        elapsed = time.perf_counter() - tic
        stats = solver.stats()
        solution = {k: np.asarray(sol[k]).ravel() for k in ("x", "lam_x", "lam_g", "f")}
        solution["scales"] = np.array([self.t_ref, self.f_ref])
        plan = self._plan(problem, solution, objective, elapsed, int(stats["iter_count"]), warm)
        return plan, bool(stats["success"])

    def _plan(self, problem: StrokeProblem, sol: dict[str, np.ndarray], objective: str,
              elapsed: float, iterations: int, warm: bool) -> Plan:
        n1, S, t_ref, lay = self.n1, self.stroke, self.t_ref, self.problem.layout
        w = sol["x"]
        if not problem.zone:  # the zone's intervals are the approach's: a start for with_zone
            w[lay.zone_step] = w[lay.steps.start]
        steps = t_ref * np.asarray(problem.steps(ca.DM(w))).ravel()
        profile = Profile(knots=np.concatenate(([0.0], np.cumsum(steps))),
                          x=self.x_open + S * w[lay.position][:-1],
                          v=S / t_ref * w[lay.velocity][:-1],
                          a=S / t_ref**2 * w[lay.acceleration][:-1],
                          jerk=S / t_ref**3 * w[lay.jerk])
        t_contact = float(profile.knots[n1])
        if self.problem.opening:  # solved backwards in time
            profile = profile.reversed()
            t_contact = profile.duration - t_contact
        return Plan(profile, self.config, objective, t_contact, elapsed, iterations, warm, sol)

    def solve(self, duration: float, objective: str = "peak", *, start: Plan | None = None,
              warm: bool = True, energy_weight: float = 0.0) -> Plan:
        """The stroke of ``duration`` s minimising the peak input force (``"peak"``), the
        integral of its square (``"rms"``) or of the squared motor torque (``"energy"``),
        plus ``energy_weight`` times the latter (:func:`objective_weights`); raises
        :class:`PlanningError` if none exists."""
        weights = objective_weights(objective, energy_weight)
        self.check_duration(duration)
        plan, ok = self._run(weights, (duration, duration), self.force_limit, objective, start,
                             warm)
        if not ok and warm:  # a poor warm start: retry from the cold guess
            plan, ok = self._run(weights, (duration, duration), self.force_limit, objective,
                                 None, False)
        if not ok:
            self._too_short(duration)
        self.problem.last = plan
        return plan

    def check_duration(self, duration: float) -> None:
        """Refuse a stroke duration no plan (or baseline) can honestly have: not positive,
        shorter than the kinematic minimum under the drive limits, longer than
        :attr:`longest`."""
        if not (math.isfinite(duration) and duration > 0):
            raise ParameterError(f"duration must be a positive time, got {duration!r} s")
        if duration < self.t_ref:
            self._too_short(duration)
        if duration > self.longest:
            raise PlanningError(
                f"duration {duration:.4g} s is too long for the plant's friction model: the "
                f"stroke would creep below {self.creep_speed * 1e3:.3g} mm/s "
                f"({CREEP_FACTOR:g} x its smoothing speed velocity_epsilon), where the "
                f"smoothed Coulomb friction fades and plans and baselines alike would be "
                f"compared on an artefact; the longest stroke planned is {self.longest:.4g} s")

    def best(self, duration: float, objective: str = "peak", energy_weight: float = 0.0
             ) -> Plan:
        """:meth:`solve` from several starts, the best plan: the polynomial guess, the
        previous plan (warm) and late S-curves (:meth:`_late_guess`), stopping once a peak
        plan is within :data:`_GAP` of :meth:`lower_bound`. The problem has two families
        of local optima, slow and fast arrival at the mold; a single start finds either.
        Judged by the peak on the 1 ms samples, the RMS force, or (energy, weighted) the
        objective's value."""
        weights = objective_weights(objective, energy_weight)
        previous = self.last
        key = (self.worst_peak if weights[1] == 0 else (lambda p: p.rms_force)
               if objective == "rms" else (lambda p: float(p.solution["f"][0])))
        good = self.lower_bound() * (1 + _GAP) if weights[1] == 0 else 0.0
        plans = [self.solve(duration, objective, warm=False, energy_weight=energy_weight)]
        if previous is not None:
            plans.append(self.solve(duration, objective, start=previous,
                                    energy_weight=energy_weight))
        for stretch in _LATE_STARTS:
            if key(min(plans, key=key)) <= good:
                break
            plan, ok = self._run(weights, (duration, duration), self.force_limit,
                                 objective, None, False,
                                 guess=self._late_guess(duration, stretch))
            if ok:
                plans.append(plan)
        self.problem.last = min(plans, key=key)
        return self.problem.last

    def lower_bound(self) -> float:
        """A lower bound on the peak input force of any stroke under this planner's
        limits, of any duration (:func:`controllers.bounds.peak_lower_bound`), N; computed
        once per planner (a trade-off asks each of its two planners in turn). With variants
        the plant's bound still holds for :meth:`worst_peak`, which is at least the plant's
        peak."""
        if self._bound is None:  # the bound is the clamping's; none for the opening
            self._bound = 0.0 if self.problem.opening else peak_lower_bound(
                self.config, self.x_final, self.limits.velocity, self.limits.acceleration,
                self.creep_speed)
        return self._bound

    def minimum_time(self, force_limit: float | None = None, *, start: Plan | None = None,
                     warm: bool = True, continued: bool = False) -> Plan:
        """The fastest stroke with |input force| at most ``force_limit`` N (default: the
        motor-torque limit) at every instant, also between the nodes.

        The optimiser decides whether a limit can be met: it first plans the fastest stroke
        under the torque limit alone, then lowers the force limit from that plan's peak to
        the requested one in steps of at most :data:`_LIMIT_STEP`, each warm-started from
        the last (a cold start under a tight limit stalls in a slow local optimum);
        ``continued``: ``start`` is the fastest plan under a looser limit (the previous
        point of a trade-off), and the steps (at most :data:`_TRADE_STEP`) go down from it.
        A limit near the lower bound (:data:`_NEAR_BOUND`) and below the least peak of any
        duration (:meth:`least_peak`, less :data:`_LEAST_MARGIN`) is refused before the
        continuation, which would otherwise end in IPOPT failing to meet it, warm and cold
        (a minute and a half on chang2021 at 14.91 N). The limit and the motor's
        torque-speed curve are imposed at the nodes and interval
        midpoints; where the plan's 1 ms samples through the plant still exceed either, it
        is tightened by the excess and the plan repeated."""
        limit = self.force_limit if force_limit is None else min(force_limit, self.force_limit)
        if not (math.isfinite(limit) and limit > 0):
            raise ParameterError(f"force limit must be > 0 N, got {force_limit!r}")
        if limit < self.lower_bound():
            raise PlanningError(self._unreachable(limit, None) + (
                f": no stroke of any duration peaks below {self.lower_bound():.4g} N "
                "(the lower bound, inertia relief included)"))
        plan = start if continued and start is not None else self._fastest(
            self.force_limit, start, warm)
        if plan is None:
            raise PlanningError(self._unreachable(limit, None))
        top = min(self.worst_peak(plan), self.force_limit)
        near = limit < self.lower_bound() * (1 + _NEAR_BOUND)
        if limit < top and near and limit < self.worst_peak(
                least := self.least_peak()) * (1 - _LEAST_MARGIN):
            raise PlanningError(self._unreachable(limit, least) + (
                " (the least peak of any duration it finds)"))
        levels = self._levels(top, limit, _TRADE_STEP if continued else _LIMIT_STEP)
        imposed = limit
        for level in levels:
            imposed = level
            reached = self._fastest(level, plan, True)
            if reached is None:
                raise PlanningError(self._unreachable(limit, plan))
            plan = reached
        factor = 1.0
        for _ in range(_TIGHTEN):  # between the nodes: the 1 ms samples decide
            excess, over = self.worst_peak(plan) - limit, self.torque_ratio(plan) - 1.0
            if excess <= 0 and over <= 0:
                break
            imposed -= 1.5 * max(excess, 0.0)
            factor /= 1.0 + 1.5 * max(over, 0.0)
            self._torque = self._torque or over > 0
            reached = self._fastest(imposed, plan, True, factor)
            if reached is None:
                raise PlanningError(self._unreachable(limit, plan))
            plan = reached
        self.problem.last = plan
        return plan

    def trade_off(self, points: int = 6, progress: Callable[[], object] | None = None
                  ) -> list[Plan]:
        """The trade-off between stroke time and peak input force: the fastest stroke under
        ``points`` force limits from the unconstrained fastest stroke's peak down to just
        above :meth:`lower_bound` (geometrically spaced; without a bound, as for a mold at
        the toggle, down to a quarter of that peak), each continued from the last; limits
        no stroke meets are left out. ``progress`` is called after each of the ``points``
        limits (each is several seconds of IPOPT)."""
        if not (isinstance(points, int) and points >= 2):
            raise ParameterError(f"points must be an integer >= 2, got {points!r}")
        tick = progress or (lambda: None)
        fastest = self._fastest(self.force_limit, None, False)
        if fastest is None:
            raise PlanningError(self._unreachable(self.force_limit, None))
        tick()
        top = min(self.worst_peak(fastest), self.force_limit)
        plans, start = [fastest], fastest
        bound = self.lower_bound()
        bottom = bound * (1 + _GAP) if bound > 0 else top / 4
        for limit in np.geomspace(top, bottom, points)[1:]:
            try:
                plan = self.minimum_time(float(limit), start=start, continued=True)
            except PlanningError:
                break
            finally:
                tick()
            plans.append(plan)
            start = plan
        return plans

    def least_peak(self) -> Plan:
        """The stroke of least peak input force the planner finds over every duration up
        to :attr:`longest`: the best plan of the default duration (:meth:`best`), then
        with the duration free, warm from it (kept: computed once per planner). No force
        limit below its peak is met by any plan the continuation of :meth:`minimum_time`
        reaches."""
        if self._least is None:
            previous = self.problem.last
            start = self.best(default_duration(self))
            plan, ok = self._run(_WEIGHTS["peak"], (self.t_ref, self.longest),
                                 self.force_limit, "peak", start, True)
            self._least = min([start, *([plan] if ok else [])], key=self.worst_peak)
            self.problem.last = previous
        return self._least

    @staticmethod
    def _levels(peak: float, limit: float, step: float = _LIMIT_STEP) -> list[float]:
        """Force limits from ``peak`` down to ``limit``, each at most ``step``
        (relative) below the last; just ``limit`` if it is not below ``peak``."""
        if limit >= peak:
            return [limit]
        steps = min(math.ceil(math.log(peak / limit) / math.log1p(step)), 40)
        return [float(v) for v in np.geomspace(peak, limit, steps + 1)[1:]]

    def _fastest(self, limit: float, start: Plan | None, warm: bool,
                 torque_factor: float = 1.0) -> Plan | None:
        """The minimum-time plan under the force limit and the torque-speed curve (times
        ``torque_factor``) imposed at nodes and midpoints, or None if IPOPT finds none
        (warm, then cold)."""
        bounds, weights = (self.t_ref, 100 * self.t_ref), [0.0, 0.0, 1.0, _REGULARISATION, 0.0]
        plan, ok = self._run(weights, bounds, limit, "time", start, warm,
                             torque_factor=torque_factor)
        if not ok and warm:
            plan, ok = self._run(weights, bounds, limit, "time", None, False,
                                 torque_factor=torque_factor)
        return plan if ok else None

    def _unreachable(self, limit: float, best: Plan | None) -> str:
        """Why no stroke meets ``limit``: which limit binds, the lowest peak reached."""
        which = ("the force limit" if limit < self.force_limit
                 else f"the motor's torque-speed curve ({self.limits.torque:.4g} N m at "
                      "standstill)")
        caps = [f"{name} {value:.4g} {unit}" for name, value, unit in (
            ("input force", self.protect_force, "N"),
            ("platen speed", self.protect_speed, "m/s")) if value is not None]
        if caps:
            which += f" or the mold-protection caps ({', '.join(caps)})"
        force = f"{self.clamp_force():.6g} N"
        stroke = (f"opening from a clamp force of {force}" if self.problem.opening
                  else f"clamping to {force}")
        text = (f"{which} {'bind' if caps else 'binds'}: the planner found no stroke {stroke} "
                f"with an input force of at most {limit:.4g} N")
        if best is not None:
            text += (f"; the lowest peak it reached is {self.worst_peak(best):.4g} N, in a stroke "
                     f"of {best.duration:.4g} s")
        return text

    # ---- diagnosis ------------------------------------------------------------------

    def node_forces(self, plan: Plan) -> tuple[np.ndarray, float]:
        """Input force at the nodes and interval midpoints (N), platen speed at contact
        (m/s), from the plan's solution."""
        F, contact, _ = self.problem.monitor(plan.solution["x"], self._parameters([0] * 4))
        return np.asarray(F).ravel(), float(contact)

    def node_torque_ratio(self, plan: Plan) -> float:
        """The plan's largest motor torque over the torque-speed curve at the nodes and
        midpoints (the plant, not its variants), from its solution: cheap, no sampling."""
        F, _, z = self.problem.monitor(plan.solution["x"], self._parameters([0] * 4))
        z = np.asarray(z)
        return self.limits.torque_ratio(self.config.mechanism.drive, z[1], z[2],
                                        np.asarray(F).ravel())

    def protection(self, plan: Plan) -> dict[str, float]:
        """The plan in the mold-protection zone on its 1 ms samples through the plant: the
        time the platen spends there (s), its peak speed (m/s) and the peak |input force|
        (N); the zone's distance (m), entry and caps (m/s, N; None: no cap)."""
        s = plan.samples
        inside = (s.position >= self.x_zone) & (
            s.time >= plan.t_contact if self.problem.opening else s.time <= plan.t_contact)
        speed = plant_outputs(s.position[inside], s.velocity[inside], s.acceleration[inside],
                              self.config.with_(x_contact=None)).platen_velocity
        return {"distance": self.protect_distance, "x_entry": self.x_zone,
                "time": self._zone_time(plan),
                "peak_platen_speed": float(np.max(np.abs(speed), initial=0.0)),
                "peak_input_force": float(np.max(np.abs(s.input_force[inside]), initial=0.0)),
                "speed_cap": self.protect_speed, "force_cap": self.protect_force}

    def _zone_time(self, plan: Plan) -> float:
        """Time the plan spends in the protection zone, s: from the crosshead's crossing of
        the zone's entry (interpolated on the 1 ms samples) to mold contact (opening: from
        separation to the crossing)."""
        s, opening = plan.samples, self.problem.opening
        closing = s.time <= plan.t_contact if not opening else s.time >= plan.t_contact
        x, t = s.position[closing], s.time[closing]
        crossing = float(np.interp(self.x_zone, x[::-1], t[::-1]) if opening
                         else np.interp(self.x_zone, x, t))
        return abs(plan.t_contact - crossing)

    def worst_peak(self, plan: Plan) -> float:
        """The plan's peak input force (1 ms samples through the plant), N: the worst over
        the plant and its variants (each divided by its scale)."""
        return max([plan.peak_force, *(predict(plan.profile, v).peak_force / k
                                       for v, k in zip(self.variants, self.scales))])

    def torque_ratio(self, plan: Plan) -> float:
        """The plan's largest motor torque over the torque-speed curve at the motor's speed
        (1 ms samples through the plant and its variants): at most 1 within the curve."""
        drive = self.config.mechanism.drive
        return max(self.limits.torque_ratio(drive, s.velocity, s.acceleration, s.input_force)
                   for s in (plan.samples, *(predict(plan.profile, v) for v in self.variants)))

    def binding_limits(self, plan: Plan, force_limit: float | None = None) -> list[str]:
        """Names of the limits the plan runs at (within 1 %), the force limit judged by the
        plan's 1 ms samples through the plant."""
        pr, lim = plan.profile, self.limits
        contact = self.node_forces(plan)[1]
        peak = self.worst_peak(plan)
        found = {
            f"velocity (max {lim.velocity * 1e3:.4g} mm/s)": np.max(np.abs(pr.v)) / lim.velocity,
            f"acceleration (max {lim.acceleration:.4g} m/s^2)":
                np.max(np.abs(pr.a)) / lim.acceleration,
            f"jerk (max {lim.jerk:.4g} m/s^3)": np.max(np.abs(pr.jerk)) / lim.jerk,
            f"motor torque (torque-speed curve, {lim.torque:.4g} N m at standstill)":
                self.torque_ratio(plan),
            f"platen speed at mold contact (max {self.contact_speed * 1e3:.4g} mm/s)":
                contact / self.contact_speed,
        }
        if force_limit is not None and force_limit < self.force_limit:
            found[f"input force (max {force_limit:.4g} N)"] = peak / force_limit
        zone, where = self.protection(plan), (
            f"over the first {self.protect_distance * 1e3:.3g} mm after mold separation"
            if self.problem.opening else f"over the last {self.protect_distance * 1e3:.3g} mm")
        if self.protect_speed is not None:
            found[f"mold-protection platen speed (max {self.protect_speed * 1e3:.4g} mm/s "
                  f"{where})"] = zone["peak_platen_speed"] / self.protect_speed
        if self.protect_force is not None:
            found[f"mold-protection input force (max {self.protect_force:.4g} N {where})"] = (
                zone["peak_input_force"] / self.protect_force)
        return [name for name, ratio in found.items() if ratio >= _BINDING]

    def clamp_force(self) -> float:
        """Clamp force held at rest in the locked position, N."""
        return float(plant_outputs(self.x_final, 0.0, 0.0, self.config).clamp_force)

    def _too_short(self, duration: float) -> None:
        fastest = self.minimum_time(warm=False)
        binding = ", ".join(self.binding_limits(fastest)) or "the drive limits"
        raise PlanningError(
            f"duration {duration:.4g} s is too short: the shortest feasible stroke takes "
            f"{fastest.duration:.4g} s (binding: {binding})"
        )


@functools.lru_cache(maxsize=8)
def planner_for(cfg: PlantConfig, limits: DriveLimits, contact_speed: float = CONTACT_SPEED,
                intervals: int = INTERVALS, variants: tuple[PlantConfig, ...] = (),
                scales: tuple[float, ...] | None = None,
                protection: Protection = Protection(), opening: bool = False) -> ClampPlanner:
    """A planner on a kept problem, so that a re-plan for the same plant (and variants),
    for any mold height, friction, drive limits or protection zone, neither rebuilds nor
    starts cold. ``opening``: the opening (break-away) stroke from the toggle back to the
    open position instead of the closing one (:class:`ClampPlanner`)."""
    problem = _problem_for(_neutral(cfg), intervals, tuple(_neutral(v) for v in variants),
                           opening=opening)
    return ClampPlanner(cfg, limits, contact_speed=contact_speed, intervals=intervals,
                        problem=problem, variants=variants, scales=scales,
                        protection=protection)


def trade_off_curve(cfg: PlantConfig, limits: DriveLimits, contact_speed: float,
                    intervals: int, protection: Protection, points: int,
                    progress: Callable[[], object] | None = None) -> list[Plan]:
    """:meth:`ClampPlanner.trade_off` of the plant's planner (:func:`planner_for`): a
    job for :class:`controllers.background.Background`."""
    return planner_for(cfg, limits, contact_speed, intervals,
                       protection=protection).trade_off(points, progress)


def best_plan(cfg: PlantConfig, limits: DriveLimits, contact_speed: float, intervals: int,
              protection: Protection, duration: float, objective: str,
              progress: Callable[[], object] | None = None) -> Plan:
    """:meth:`ClampPlanner.best` of the plant's planner (:func:`planner_for`): a job for
    :class:`controllers.background.Background` (``progress`` is not called)."""
    return planner_for(cfg, limits, contact_speed, intervals,
                       protection=protection).best(duration, objective)


def baseline_stroke(cfg: PlantConfig, limits: DriveLimits, duration: float,
                    jerk: float | None = None) -> Profile:
    """The S-curve stroke of the plant's clamp in ``duration`` under the limits (the jerk
    limit's unless ``jerk`` is given; inf: the trapezoidal velocity profile), held to the
    motor's torque-speed curve: where the stroke at full acceleration breaks it (the
    drive's inertia needs torque), the acceleration is lowered, in steps of
    :data:`_BASELINE_STEP` and then by bisection, to the highest that keeps the curve, as
    far as the duration allows (else the stroke at full acceleration, which the caller
    reports as breaking the curve: :meth:`DriveLimits.torque_ratio`)."""
    x_open, x_final = clamp_stroke(cfg.mechanism)
    jerk = limits.jerk if jerk is None else jerk
    drive = cfg.mechanism.drive

    def stroke(factor: float) -> Profile:
        return s_curve(x_open, x_final, duration, limits.velocity,
                       factor * limits.acceleration, jerk)

    def within(factor: float) -> bool:
        try:
            s = predict(stroke(factor), cfg)
        except ProfileError:  # too slow an acceleration for the duration
            return False
        return limits.torque_ratio(drive, s.velocity, s.acceleration, s.input_force) <= 1.0

    if within(1.0):
        return stroke(1.0)
    high, low = 1.0, _BASELINE_STEP
    while not within(low):
        if low < 1e-3:
            return stroke(1.0)
        high, low = low, low * _BASELINE_STEP
    for _ in range(20):  # the highest acceleration within the curve, to 0.01 %
        middle = 0.5 * (low + high)
        low, high = (middle, high) if within(middle) else (low, middle)
        if high - low < 1e-4 * high:
            break
    return stroke(low)


def baselines(cfg: PlantConfig, limits: DriveLimits, duration: float
              ) -> dict[str, ProfileSamples]:
    """The trapezoidal and S-curve strokes of the same duration and limits, predicted."""
    return {name: predict(baseline_stroke(cfg, limits, duration, jerk), cfg)
            for name, jerk in (("trapezoidal", math.inf), ("s_curve", limits.jerk))}


def default_duration(planner: ClampPlanner) -> float:
    """Twice the kinematic minimum stroke time, rounded up to 0.1 s."""
    return math.ceil(20 * planner.t_ref) / 10
