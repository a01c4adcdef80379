"""The optimal control problem of a clamp stroke, declared: its variables, parameters,
constraints and objective, and its functions compiled for IPOPT.

The problem, built with CasADi through the plant's own equations
(:func:`toggle.plant.plant_outputs`, what the FMU compiles):

* states crosshead position, velocity and acceleration, jerk piecewise
  constant on N intervals, discretised exactly (the triple integrator);
* three phases: the approach, the mold-protection zone (its entry, the last distance of
  platen travel before contact, pinned to node NA, with a platen speed cap and an
  input-force cap) and, from mold contact (pinned to node N1, so the force's kink at
  contact falls on a node and the platen's speed there is a node value), the clamping up
  to the toggle. Approach nodes are evaluated with the mold-free plant, clamping nodes
  with the mold; the two agree up to contact, so this is the FMU's model;
* objective the peak input force (epigraph variable s, |F| <= s at the nodes
  and interval midpoints, plus a small weight on the squared jerk to make the
  optimum unique), the integral of F^2, or the stroke's electrical energy (``"energy"``:
  shaft power with the screw's efficiency by the direction of power flow plus the copper
  losses, :mod:`controllers.duty`), alone or weighted into the peak; the minimum-time
  mode minimises the duration under |F| <= force limit;
* constraints: rest at the open position and at the toggle, monotone stroke
  inside the stroke limits, velocity (nodes and midpoints), acceleration and
  jerk limits (:mod:`controllers.limits`), the motor torque with the drive's
  inertia (:func:`toggle.drive.drive_torque`) within the torque-speed curve at
  the motor's speed (nodes and midpoints), platen speed at mold contact, and no
  creeping through the clamping (the planner's bounds, :mod:`controllers.planner`).

The opening (break-away) stroke is the same problem run backwards in time (the plant
evaluated at -v).

Variables are scaled by the stroke, a reference time (the kinematic minimum)
and a reference force; the interval lengths of the two phases are variables
and the duration is a constraint whose bounds fix it or leave it free. The
objective weights, the mold-contact position, the pin friction, the scales,
the jerk and contact-speed limits, the drive (travel per radian, efficiency,
the rotor's and screw's reflected mass, the torque-speed curve) and the masses
are parameters (:data:`PARAMETERS`, :data:`MASSES`) and the other limits
bounds. So one built problem (:class:`StrokeProblem`, shared by
:func:`problem_for`) serves every duration, mode, mold height, friction,
mass, drive and drive limit. IPOPT's functions are per-node jets of the plant feeding
a model of the rest (see :class:`StrokeProblem`), compiled to machine code once and kept
on disk under a hash of what determines them (the code this module imports, not the
solving, the reports, plots or the CLI; the plant's geometry and friction model; N:
:mod:`controllers.compiled`), so a new process builds a problem in milliseconds; without
a C compiler they are built symbolically and interpreted.
"""

from __future__ import annotations

import functools
import math
from dataclasses import astuple, fields, replace
from typing import TYPE_CHECKING, Any, NamedTuple

import casadi as ca
import numpy as np

from controllers.compiled import Unit, code_digest, compiled
from controllers.limits import DriveLimits
from toggle.drive import drive_torque, flow_factor, torque_speed_limit
from toggle.elastics import clamp_stroke
from toggle.params import (
    MAX_CURVE_POINTS,
    Drive,
    Dynamics,
    ParameterError,
    symbolic_copy,
)
from toggle.plant import PlantConfig, plant_outputs

if TYPE_CHECKING:  # not imported: the plans are no part of the compiled problem's key
    from controllers.plans import Plan

OBJECTIVES = ("peak", "rms", "energy")
REGULARISATION = 1e-2  # weight of the squared jerk (relative to its limit), for uniqueness
#: Objective weights (peak, integral, duration, jerk regularisation, and whether the
#: integral is the electrical energy rather than that of the squared input force: see
#: :data:`INTEGRAND`) of each objective: "energy" minimises the stroke's electrical energy
#: (shaft power with the screw's efficiency by the direction of power flow, plus the
#: copper losses: :mod:`controllers.duty`).
WEIGHTS = {"peak": [1.0, 0.0, 0.0, REGULARISATION, 0.0], "rms": [0.0, 1.0, 0.0, 0.0, 0.0],
           "energy": [0.0, 1.0, 0.0, 0.0, 1.0]}
#: A protection cap that is not set: a value no plan reaches (the cap stays a parameter).
NO_CAP = 1e12
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
#: the planner's minimum-time continuation, a trade-off's next point), farther off: there
#: the barrier starts at 1e-5 (chang2021's trade-off curve with the mold: 1270 warm
#: iterations at 1e-7, 550 at 1e-5, the same curve to 3e-7; a re-plan of another duration
#: or mold height takes 3-27 iterations at 1e-7 and 20-27 at 1e-5).
_WARM_FAR = {**_WARM, "mu_init": 1e-5}


def objective_weights(objective: str, energy_weight: float = 0.0) -> list[float]:
    """The problem's objective weights (:data:`WEIGHTS`) of ``objective`` plus
    ``energy_weight`` times the stroke's electrical energy (in the problem's scaling: over
    the reference force times the stroke)."""
    if objective not in OBJECTIVES:
        raise ParameterError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    if not (math.isfinite(energy_weight) and energy_weight >= 0):
        raise ParameterError(f"energy weight must be a number >= 0, got {energy_weight!r}")
    if energy_weight and objective != "peak":
        raise ParameterError(f"an energy weight adds to the peak objective, not to {objective}")
    weights = list(WEIGHTS[objective])
    if energy_weight:
        weights[1], weights[4] = energy_weight, 1.0
    return weights


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
#: The integrand of the objective's integral, g = w_copper T^2 + w_shaft T v at the nodes
#: (trapezoidal rule), T = F k + m a over the force scale: ``inertia`` m, kg, and k by the
#: direction of the thrust power F v (:func:`toggle.drive.flow_factor`: 1 / ``forward``
#: driving, ``reverse`` back-driven, blended over :data:`FLOW_SMOOTHING`). With m = 0,
#: k = 1, w_copper = 1 and w_shaft = 0 it is the integral of F^2 (``"rms"``); with the
#: drive's m_drive, eta and eta', w_shaft = 1 and w_copper the copper losses' c p^2 f_ref
#: T_ref / S it is the electrical energy of the stroke over f_ref S (``"energy"``: shaft
#: power T_m omega plus copper losses c T_m^2, :mod:`controllers.duty`).
INTEGRAND = ("inertia", "forward", "reverse", "w_shaft", "w_copper")
#: The thrust power (over f_ref S / T_ref) over which the planner's motor torque blends the
#: forward and the back-driving efficiency (smooth for IPOPT; the duty switches exactly).
FLOW_SMOOTHING = 1e-2
#: The problem's parameters, in order: objective weights (peak, integral, duration, jerk
#: regularisation), the integral's integrand (:data:`INTEGRAND`), mold-contact position (m),
#: force scale (N), time scale T_ref (s), jerk limit (m/s^3), platen speed limit at contact
#: (m/s), pin friction mu; the drive: travel per motor radian (m/rad), efficiency,
#: reflected mass of rotor and screw (kg), the factor on the torque-speed curve (1, less
#: where minimum_time tightens it), the curve's speeds (rad/s) and torques (N m), padded
#: to :data:`MAX_CURVE_POINTS` points; the mold-protection zone's platen speed cap (m/s)
#: and input-force cap (N).
PARAMETERS = ("w_peak", "w_energy", "w_time", "w_jerk", *INTEGRAND, "x_contact", "f_ref",
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
#: carry, so that neither is part of the compile key (:func:`neutral`).
_NEUTRAL_DRIVE = Drive(ratio=1.0, lead=1.0, efficiency=1.0, pulses_per_rev=1)
_NEUTRAL_DYNAMICS = Dynamics(crosshead=1.0, links=1.0, platen=1.0)


def neutral(cfg: PlantConfig) -> PlantConfig:
    """The plant as a problem is built for it: without mold and friction, with the neutral
    drive and masses (all parameters of the problem)."""
    return cfg.with_(x_contact=None, mu=None, mechanism=replace(
        cfg.mechanism, drive=_NEUTRAL_DRIVE, dynamics=_NEUTRAL_DYNAMICS))


def plant_masses(cfg: PlantConfig) -> list[float]:
    """The plant's :data:`MASSES` (kg, N s/m, N), parameters of the problem."""
    return [float(getattr(cfg.dynamics, name)) for name in MASSES]


def curve_parameters(limits: DriveLimits) -> list[float]:
    """The torque-speed curve's speeds and torques, padded to :data:`MAX_CURVE_POINTS`
    points by flat steps beyond the last (which add nothing to the curve)."""
    speeds, torques = (list(c) for c in zip(*limits.curve))
    while len(speeds) < MAX_CURVE_POINTS:
        speeds.append(speeds[-1] + 1.0)
        torques.append(torques[-1])
    return [*speeds, *torques]


def problem_key(cfg: PlantConfig, intervals: int, variants: tuple[PlantConfig, ...] = (),
                opening: bool = False) -> str:
    """Everything that determines a :class:`StrokeProblem`'s functions, the key of their
    disk cache: the code the problem uses, the plants (every field of the frozen parameters,
    floats in their exact repr; mold height, friction, masses, the drive and its limits
    are parameters of the problem, not part of the key: :func:`neutral`), N and the
    direction (opening or closing)."""
    plants = [astuple(neutral(c)) for c in (cfg, *variants)]
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
    when it holds this problem (:func:`problem_key`), else they are built and compiled;
    only the small MX graph joining them is built here.

    Constraints, in order (:attr:`rows`): the dynamics (3N), contact at node N1, the force
    epigraph F - s <= 0 and F + s >= 0 at nodes and midpoints, the platen speed at
    contact, the duration and the velocity at the midpoints (N); with ``torque``, the
    motor torque over the torque-speed curve at nodes and midpoints, in [-1, 1]. Those
    rows cost a third of the solve time, so the problem without them comes first and its
    sibling with them (:attr:`with_torque`, built when first asked for) serves the plans
    the curve limits (the planner's ``_run``); they come last, after the mold-protection
    zone's (only in :attr:`with_zone`, for plans with caps): its entry at node NA, the
    platen speed and the input force over its nodes and midpoints. The closing
    stroke has three phases, each of equal intervals: the approach (NA intervals, length
    w[4N+3]), the protection zone up to contact (N1 - NA, w[4N+6]) and the clamp-up (N - N1,
    w[4N+4]).
    ``opening``: the same problem run backwards in time (the opening stroke).
    """

    def __init__(self, cfg: PlantConfig, intervals: int,
                 variants: tuple[PlantConfig, ...] = (), torque: bool = False,
                 opening: bool = False, zone: bool = False, machine_code: bool = True
                 ) -> None:
        if not (isinstance(intervals, int) and intervals >= 4):
            raise ParameterError(f"intervals must be an integer >= 4, got {intervals!r}")
        self.config, self.variants, self.torque = cfg, variants, torque
        self.opening, self.zone, self.machine_code = opening, zone, machine_code
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
        units: list[Unit] = []  # one unit of jets per plant: compiled in parallel
        for k, plant in enumerate(self.plants):
            plant = plant.with_(mechanism=replace(plant.mechanism, dynamics=dynamics))
            # the opening stroke is the closing one run backwards in time: v -> -v
            v = -z[1] if self.opening else z[1]
            free = plant_outputs(z[0], v, z[2], plant, mu=prm[1])
            mold = plant_outputs(z[0], v, z[2], plant, x_contact=prm[0], mu=prm[1])
            speed = -free.platen_velocity if self.opening else free.platen_velocity
            outputs = (free.input_force, mold.input_force, speed, free.input_force,
                       mold.input_force, speed, speed)
            jets = [fn for name, out, nodes in zip(_OUTPUTS, outputs, self._spans())
                    for fn in _jets(f"{name}{k}_", ca.SX(out), z, prm, nodes.stop - nodes.start)]
            if k == 0:
                jets.append(ca.Function("input_force", [z, prm], [mold.input_force],
                                        {"cse": True}))
            units.append((_OPTIMISATION["jets"], jets))
        *values, hess = self._model_functions()
        return [*units, (_OPTIMISATION["model"], values), (_OPTIMISATION["model"], [hess])]

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

        def integral(g: ca.SX, step: ca.SX) -> ca.SX:  # trapezoidal rule
            return step * (ca.sum1(g) - (g[0] + g[-1]) / 2)

        # the integrand (INTEGRAND) at the nodes in F's order (node n1 twice); the opening
        # stroke's physical velocity is -nu (it is solved backwards in time)
        N = n1 + self.n2
        v = ca.vertcat(nu[:n1 + 1], nu[n1:]) * (-1 if self.opening else 1)
        k = flow_factor(F * v, p[_P["forward"]], p[_P["reverse"]], FLOW_SMOOTHING)
        T = F * k + p[_P["inertia"]] * ca.vertcat(z[2, :n1 + 1].T, z[2, n1:N + 1].T) / p[
            _P["f_ref"]]
        g = p[_P["w_copper"]] * T**2 + p[_P["w_shaft"]] * T * v
        energy = (integral(g[:na + 1], th1) + integral(g[na:n1 + 1], thz)
                  + integral(g[n1 + 1:], th2))
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
        key = problem_key(self.config, N, self.variants, self.opening) + (
            "\ntorque" if self.torque else "") + ("\nzone" if self.zone else "")
        names = _names(len(self.plants))
        # the jets (a unit per plant, first) carry the arithmetic: compiled for a first answer
        # too, each keyed by its plant alone (a robust plan's nominal clamp reuses them)
        jets = [f"{problem_key(plant, N, opening=self.opening)}\nplant {k}"
                for k, plant in enumerate(self.plants)]
        fn = dict(zip(names, compiled("stroke", key, names, self._symbolic,
                                      self.machine_code, first=jets)))
        #: whether it all came compiled from the disk cache (else another process rebuilds it)
        self.loaded = fn[_MODEL_NAMES[-1]].is_a("External")
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
        return self._sibling(torque=True, zone=self.zone)

    @functools.cached_property
    def with_zone(self) -> StrokeProblem:
        """The same problem with the mold-protection caps' rows (itself if it has them):
        the plans without caps do without them."""
        if self.zone:
            return self
        return self._sibling(torque=self.torque, zone=True)

    def _sibling(self, torque: bool, zone: bool) -> StrokeProblem:
        """This problem with or without the torque's and the zone's rows: the shared one of
        :func:`problem_for` when compiled, a problem of its own when interpreted (planned
        once, it would only push the shared ones out of the cache)."""
        if self.machine_code:
            return problem_for(self.config, self.n1 + self.n2, self.variants, torque=torque,
                               opening=self.opening, zone=zone)
        return StrokeProblem(self.config, self.n1 + self.n2, self.variants, torque=torque,
                             opening=self.opening, zone=zone, machine_code=False)

    def input_force(self, x: Any, v: Any, a: Any, cfg: PlantConfig) -> np.ndarray:
        """The input force (N) at the points (x, v, a) of the plant ``cfg`` (its mold, pin
        friction and masses; the function of the clamping phase's jets, exact before
        contact too, compiled)."""
        z = np.vstack(np.broadcast_arrays(x, v, a)).astype(float)
        return np.asarray(self._force(z, [cfg.x_contact, cfg.friction,
                                          *plant_masses(cfg)]))[0]

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
def problem_for(cfg: PlantConfig, intervals: int, variants: tuple[PlantConfig, ...] = (),
                torque: bool = False, opening: bool = False, zone: bool = False
                ) -> StrokeProblem:
    """A built problem, shared by the planners of every mold height, friction, drive and
    drive limits of one plant (and variants), with or without the torque rows, closing or
    opening (compiled: a problem interpreted is planned once and is its own)."""
    return StrokeProblem(cfg, intervals, variants, torque, opening, zone)

