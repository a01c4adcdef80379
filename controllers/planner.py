"""Optimal crosshead motion for a clamp stroke: least drive force under real limits.

The optimal control problem, solved with CasADi and IPOPT through the plant's
own equations (:func:`toggle.plant.plant_outputs`, what the FMU compiles):

* states crosshead position, velocity and acceleration, jerk piecewise
  constant on N intervals, discretised exactly (the triple integrator);
* two phases joined at mold contact: the approach (the contact position is
  pinned to node N1, so the force's kink at contact falls on a node and the
  platen's speed there is a node value) and the clamping up to the toggle.
  Approach nodes are evaluated with the mold-free plant, clamping nodes with
  the mold; the two agree up to contact, so this is the FMU's model;
* objective the peak input force (epigraph variable s, |F_k| <= s, plus a
  small weight on the squared jerk to make the optimum unique) or the
  integral of F^2; the minimum-time mode minimises the duration under
  |F_k| <= force limit;
* constraints: rest at the open position and at the toggle, monotone stroke
  inside the stroke limits, velocity, acceleration, jerk (at the nodes) and
  motor-torque limits (:mod:`controllers.limits`), platen speed at mold
  contact, and no creeping through the clamping (``CREEP_FACTOR``).

Variables are scaled by the stroke, a reference time (the kinematic minimum)
and a reference force; the interval lengths of the two phases are variables
and the duration is a constraint whose bounds fix it or leave it free. The
objective weights, the mold-contact position and the force scale are
parameters. So one built problem (:class:`StrokeProblem`, shared by
:func:`planner_for` across mold heights) serves every duration, mode and mold
height, and a re-plan warm-starts IPOPT from the previous primal and dual
solution, stretched in time to the new duration. IPOPT's functions are per-node
jets of the plant feeding a model of the rest (see :class:`StrokeProblem`),
compiled to machine code once and kept on disk under a hash of everything that
determines them (this code and the toggle model's, the plant, limits, contact
speed and N: :mod:`controllers.compiled`), so a new process builds a problem in
milliseconds; without a C compiler they are built symbolically and interpreted.

Speed (``benchmarks/bench_planner.py``, chang2021, N = 200, 3 s, two cores): a
cold plan takes about 0.18 s with the disk cache filled (the problem loaded in
under 10 ms, 63 IPOPT iterations), a warm re-plan about 10 ms for another
duration (3 iterations) and 16 ms for another mold height (6 iterations); the
first plan of a plant (or after any change of the code) compiles for about 5 s.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import astuple, dataclass, field, replace
from typing import Any

import casadi as ca
import numpy as np
from scipy.optimize import brentq

import controllers
import toggle
from controllers.compiled import Unit, compiled, source_digest
from controllers.limits import DriveLimits, drive_limits
from controllers.profiles import Profile, ProfileSamples, minimum_time, predict, s_curve
from toggle.elastics import ClampingError, clamp_state, clamp_stroke, contact_position
from toggle.params import HALVES, Dynamics, Mechanism, ParameterError, load_preset
from toggle.plant import PlantConfig, plant_outputs

OBJECTIVES = ("peak", "rms")
CONTACT_SPEED = 5e-3  # m/s, default limit on the platen's speed at mold contact
INTERVALS = 200
#: While clamping the crosshead moves at least this many times the plant's friction-smoothing
#: speed (tanh(v / v_eps)), except while it settles in the last tenth of the clamping phase:
#: below it the smooth friction model fades out, and a plan creeping there would exploit that.
CREEP_FACTOR = 10.0
_REGULARISATION = 1e-2  # weight of the squared jerk (relative to its limit), for uniqueness
_BINDING = 0.99  # a limit counts as binding above this fraction of its value
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


class PlanningError(ValueError):
    """A request no profile can meet; the message names the binding limit."""


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
) -> PlantConfig:
    """The plant to plan for, with the mold-contact position set.

    Give the mold-contact crosshead position ``x_contact`` or the clamp force
    ``clamp_force`` (N) to hold at rest in the locked position, not both;
    without either the preset's final tie-bar force sets it
    (:func:`toggle.elastics.contact_position`). ``masses`` overrides or, for a
    preset without [dynamics], supplies crosshead, links, platen (kg) and
    guide_damping (N s/m).
    """
    mech = load_preset(mechanism) if isinstance(mechanism, str) else mechanism
    if masses:
        dynamics = (replace(mech.dynamics, **masses) if mech.dynamics
                    else Dynamics(**masses) if {"crosshead", "links", "platen"} <= set(masses)
                    else None)
        mech = replace(mech, dynamics=dynamics)
    if mech.dynamics is None:
        raise ParameterError(f"preset {mech.name!r} has no [dynamics] section: give the masses "
                             "(crosshead, links, platen)")
    mu = mech.clamp.mu if mu is None and mech.clamp else mu
    x_open, x_final = clamp_stroke(mech)
    if x_contact is not None and clamp_force is not None:
        raise ParameterError("give either the mold-contact position or the clamp force")
    if clamp_force is not None:
        x_contact = _contact_for_clamp_force(mech, mu, clamp_force, x_open, x_final)
    elif x_contact is None:
        x_contact = contact_position(mech, mu, mech.clamp.final_tiebar_force)
    elif not (x_open < x_contact < x_final):
        raise ClampingError(f"mold-contact position {x_contact!r} m is outside the stroke "
                            f"({x_open:.6g}, {x_final:.6g}) m")
    return PlantConfig(mech, mu=mu, x_contact=x_contact)


def _contact_for_clamp_force(mech: Mechanism, mu: float, force: float, x_open: float,
                             x_final: float) -> float:
    """Contact position whose clamp force at rest in the locked position is ``force``."""
    if not (math.isfinite(force) and force > 0):
        raise ClampingError(f"clamp force must be positive, got {force!r} N")

    def at_rest(xc: float) -> float:  # the plant's clamp force at v = 0 (friction direction 0)
        states = [clamp_state(x_final, xc, mech, mu, 0.0, half=h) for h in HALVES]
        return 0.5 * sum(float(s.clamp_force) for s in states)

    reach = at_rest(x_open)
    if force >= reach:
        raise ClampingError(
            f"a clamp force of {force:.6g} N is beyond reach: with the molds touching at the "
            f"open position the stroke builds only {reach:.6g} N"
        )
    return float(brentq(lambda xc: at_rest(xc) - force, x_open, x_final, xtol=1e-15))


def _min_jerk(tau: np.ndarray) -> tuple[np.ndarray, ...]:
    """Rest-to-rest septic polynomial on [0, 1] and its first three derivatives."""
    c = np.array([-20.0, 70.0, -84.0, 35.0, 0, 0, 0, 0])
    return tuple(np.polyval(np.polyder(c, m) if m else c, tau) for m in range(4))


#: The plant outputs the problem evaluates at the nodes (see :meth:`StrokeProblem._spans`).
_OUTPUTS = ("free", "mold", "contact")
#: The functions compiled to machine code: jets of each output (value, + gradient, + Hessian),
#: then the model (:meth:`StrokeProblem._model_functions`).
_NAMES = (*(f"{name}{order}" for name in _OUTPUTS for order in range(3)), "input_force",
          "f_plain", "grad_f_plain", "fg", "grad_f", "jac_g", "hess_lag")
#: Optimisation level of the compilation units: the jets are small code doing the plant's
#: arithmetic (-O1 makes them two to three times faster than -O0), the model is 1.6 MB of
#: straight-line C, compiled in seconds at -O0 and in half a minute at -O1, which would save
#: a tenth of the solve time.
_OPTIMISATION = {"jets": ("-O1",), "model": ("-O0",)}
#: The code that determines the problem's functions, hashed when this module is imported (so
#: the hash matches the code this process runs, even if the files change later).
_SOURCE = source_digest(toggle, controllers)
#: Upper triangle of a symmetric 3 x 3 matrix, row by row (the per-node plant Hessians).
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_JET = 10  # rows of a node's plant data: value, gradient (3), Hessian upper triangle (6)


def _problem_key(cfg: PlantConfig, limits: DriveLimits, contact_speed: float,
                 intervals: int) -> str:
    """Everything that determines a :class:`StrokeProblem`'s functions, the key of their
    disk cache: the code and the problem's inputs (every field of the frozen parameters,
    floats in their exact repr)."""
    return "\n".join((_SOURCE, *map(repr, (astuple(cfg), astuple(limits), contact_speed,
                                            intervals))))


def _jets(name: str, output: ca.SX, z: ca.SX, xc: ca.SX, nodes: int
          ) -> tuple[ca.Function, ...]:
    """One plant output h(z, x_contact) of a node, z = (x, v, a), as three functions of
    (z at ``nodes`` nodes, x_contact) -> its value, first- and second-order jet at each node,
    a :data:`_JET`-row column per node (missing orders zero). Mapped here, so that the map
    is compiled into a loop too."""
    H, g = ca.hessian(output, z)
    zero = ca.SX.zeros
    rows = (ca.vertcat(output, zero(_JET - 1)), ca.vertcat(output, g, zero(_JET - 4)),
            ca.vertcat(output, g, *[H[i, j] for i, j in _UPPER]))
    return tuple(ca.Function(f"{name}{k}_node", [z, xc], [r], {"cse": True}).map(
        f"{name}{k}", "serial", nodes, [1], []) for k, r in enumerate(rows))


class StrokeProblem:
    """The optimal control problem for one mold-free plant, drive limits and contact-speed
    limit, built once; the mold-contact position is one of its parameters.

    Variables are scaled: position xi = (x - x_open) / S, velocity, acceleration and jerk
    in units of S / T_ref^k, interval lengths theta in units of T_ref. The plant enters
    only through its outputs at the nodes (input force, platen speed at contact), each a
    function of that node's (x, v, a). So IPOPT's derivatives are assembled from per-node
    jets (value, gradient, Hessian of each output, small SX functions mapped over the nodes)
    and a small SX graph of the rest, in which each output is its second-order Taylor model
    about the current point: exact value, gradient and Hessian of the Lagrangian there,
    without CasADi differentiating through the mapped plant at every call. Both come from
    the disk cache of compiled code when it holds this problem (:func:`_problem_key`),
    else they are built and compiled; only the small MX graph joining them is built here.
    """

    def __init__(self, cfg: PlantConfig, limits: DriveLimits, contact_speed: float,
                 intervals: int) -> None:
        if not (isinstance(intervals, int) and intervals >= 4):
            raise ParameterError(f"intervals must be an integer >= 4, got {intervals!r}")
        if not (math.isfinite(contact_speed) and contact_speed > 0):
            raise ParameterError(f"contact speed must be > 0 m/s, got {contact_speed!r}")
        self.config, self.limits, self.contact_speed = cfg, limits, contact_speed
        self.x_open, self.x_final = clamp_stroke(cfg.mechanism)
        lo, hi = cfg.input_range
        if not (lo <= self.x_open and self.x_final <= hi):
            raise ParameterError("the stroke leaves the assemblable range")
        self.stroke = self.x_final - self.x_open
        self.n1, self.n2 = intervals - intervals // 2, intervals // 2
        self.size = 4 * intervals + 6
        self.n_constraints = 3 * intervals + 1 + 2 * (intervals + 2) + 2
        self.t_ref = minimum_time(self.stroke, limits.velocity, limits.acceleration, limits.jerk)
        self.jerk_bound = limits.jerk * self.t_ref**3 / self.stroke
        self._solvers: dict[tuple[bool, bool], Any] = {}
        self.last: Plan | None = None  # the latest plan, for any mold height
        self._build()

    def _nodes(self, w: Any) -> tuple[Any, ...]:
        """Scaled variables -> (xi, nu, al, jerk, th1, th2, s) and the node states (3 x N+1)."""
        N = self.n1 + self.n2
        xi, nu, al = (w[k * (N + 1):(k + 1) * (N + 1)] for k in range(3))
        S, t_ref = self.stroke, self.t_ref
        z = ca.vertcat(self.x_open + S * xi.T, S / t_ref * nu.T, S / t_ref**2 * al.T)
        return xi, nu, al, w[3 * N + 3:4 * N + 3], w[4 * N + 3], w[4 * N + 4], w[4 * N + 5], z

    def _spans(self) -> tuple[slice, ...]:
        """The nodes of each of :data:`_OUTPUTS`: the mold-free input force over the approach,
        the input force with the mold over the clamping, the platen speed at contact."""
        n1, N = self.n1, self.n1 + self.n2
        return slice(0, n1 + 1), slice(n1, N + 1), slice(n1, n1 + 1)

    def _symbolic(self) -> list[Unit]:
        """The per-node jets of :data:`_OUTPUTS` and the model as SX functions, in
        compilation units (see :data:`_OPTIMISATION`)."""
        z, xc = ca.SX.sym("z", 3), ca.SX.sym("x_contact")
        free = plant_outputs(z[0], z[1], z[2], self.config)
        mold = plant_outputs(z[0], z[1], z[2], self.config, x_contact=xc)
        outputs = (free.input_force, mold.input_force, free.platen_velocity)
        jets = [fn for name, out, nodes in zip(_OUTPUTS, outputs, self._spans())
                for fn in _jets(name, ca.SX(out), z, xc, nodes.stop - nodes.start)]
        force = ca.Function("input_force", [z, xc], [mold.input_force], {"cse": True})
        *values, hess = self._model_functions()
        return [(_OPTIMISATION["jets"], [*jets, force]), (_OPTIMISATION["model"], values),
                (_OPTIMISATION["model"], [hess])]

    def _model(self, w: ca.SX, w0: ca.SX, p: ca.SX, data: ca.SX) -> tuple[ca.SX, ca.SX]:
        """Objective and constraints with each plant output replaced by its Taylor model
        about the point w0, from the node data (:data:`_JET` rows per output and node, the
        outputs' nodes :meth:`_spans`)."""
        n1, n2 = self.n1, self.n2
        xi, nu, al, io, th1, th2, s, z = self._nodes(w)
        dz = z - self._nodes(w0)[-1]
        outputs, col = [], 0
        for nodes in self._spans():
            d, n = dz[:, nodes], nodes.stop - nodes.start
            block = data[:, col:col + n]
            quad = sum((1 if i == j else 2) * block[4 + k, :] * d[i, :] * d[j, :]
                       for k, (i, j) in enumerate(_UPPER))
            outputs.append(block[0, :] + ca.sum1(block[1:4, :] * d) + quad / 2)
            col += n
        F = ca.vertcat(outputs[0].T, outputs[1].T) / p[5]
        contact = outputs[2] / self.contact_speed
        h = ca.vertcat(ca.repmat(th1, n1, 1), ca.repmat(th2, n2, 1))
        dyn = ca.vertcat(
            xi[1:] - (xi[:-1] + h * (nu[:-1] + h * (al[:-1] / 2 + h * io / 6))),
            nu[1:] - (nu[:-1] + h * (al[:-1] + h * io / 2)),
            al[1:] - (al[:-1] + h * io),
        )

        def integral(Fp: ca.SX, step: ca.SX) -> ca.SX:  # trapezoidal rule
            return step * (ca.sumsqr(Fp) - (Fp[0] ** 2 + Fp[-1] ** 2) / 2)

        energy = integral(F[:n1 + 1], th1) + integral(F[n1 + 1:], th2)
        duration = n1 * th1 + n2 * th2
        objective = (p[0] * s + p[1] * energy + p[2] * duration
                     + p[3] * ca.dot(h, (io / self.jerk_bound) ** 2))
        return objective, ca.vertcat(dyn, xi[n1], F - s, F + s, contact, duration)

    def _model_functions(self) -> list[ca.Function]:
        """The model's value (f, g), gradient, constraint Jacobian and Hessian of the
        Lagrangian, functions of (w, p, node data): derivatives of the Taylor models taken
        about w0, then evaluated at w0 = w, where the models are exact to second order. And
        the objective's value and gradient without the force integral (its weight p[1]
        zero: the peak and minimum-time objectives), functions of (w, p) alone, so that
        IPOPT evaluates no plant for them."""
        m = sum(nodes.stop - nodes.start for nodes in self._spans())
        w, w0 = ca.SX.sym("w", self.size), ca.SX.sym("w0", self.size)
        p, data = ca.SX.sym("p", 6), ca.SX.sym("data", _JET, m)
        lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", self.n_constraints)
        f, g = self._model(w, w0, p, data)
        hess = ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), w)[0])
        f, g, grad, jac, hess = ca.substitute(
            [f, g, ca.gradient(f, w), ca.jacobian(g, w), hess], [w0], [w])
        args, opts = [w, p, data], {"cse": True}
        plain, plain_grad = ca.substitute([f, grad], [p[1]], [0.0])
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
        key = _problem_key(self.config, self.limits, self.contact_speed, N)
        fn = dict(zip(_NAMES, compiled("stroke", key, _NAMES, self._symbolic)))
        W, P = ca.MX.sym("x", self.size), ca.MX.sym("p", 6)
        L_f, L_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", self.n_constraints)
        z = self._nodes(W)[-1]

        def node_data(order: int) -> ca.MX:
            return ca.horzcat(*[fn[f"{name}{order}"](z[:, nodes], P[4])
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
        n1 = self.n1
        self.monitor = ca.Function("monitor", [W, P], [
            ca.vertcat(values[0, :n1 + 1].T, values[0, n1 + 1:N + 2].T),
            values[0, N + 2] / self.contact_speed])
        nf = N + 2
        self.g_bounds = (
            np.concatenate([np.zeros(3 * N), [np.nan], np.full(nf, -np.inf), np.zeros(nf),
                            [-np.inf, 0.0]]),
            np.concatenate([np.zeros(3 * N), [np.nan], np.zeros(nf), np.full(nf, np.inf),
                            [1.0, np.inf]]))

    def input_force(self, x: Any, v: Any, a: Any, x_contact: float) -> np.ndarray:
        """The plant's input force (N) at the points (x, v, a) with the mold at ``x_contact``
        (the function of the clamping phase's jets, exact before contact too, compiled)."""
        z = np.vstack(np.broadcast_arrays(x, v, a)).astype(float)
        return np.asarray(self._force(z, x_contact))[0]

    def solver(self, warm: bool, energy: bool) -> Any:
        """The IPOPT instance, cold or with the warm-start options, for an objective with
        the force integral (``energy``) or without it (each built once)."""
        if (warm, energy) not in self._solvers:
            nlp, grad_f = self._nlp[energy]
            opts = {"ipopt": {**_IPOPT, **(_WARM if warm else {})}, "print_time": False,
                    "error_on_fail": False, "calc_lam_p": False, "no_nlp_grad": True,
                    "grad_f": grad_f, **self._derivatives}
            self._solvers[warm, energy] = ca.nlpsol("plan", "ipopt", nlp, opts)
        return self._solvers[warm, energy]


@functools.lru_cache(maxsize=8)
def _problem_for(cfg: PlantConfig, limits: DriveLimits, contact_speed: float,
                 intervals: int) -> StrokeProblem:
    """A built problem, shared by the planners of every mold height of one plant."""
    return StrokeProblem(cfg, limits, contact_speed, intervals)


class ClampPlanner:
    """Plans strokes of one plant with its mold, on a :class:`StrokeProblem`.

    :meth:`solve` plans a stroke of a given duration, :meth:`minimum_time`
    the fastest one under a force limit; each warm-starts from the previous
    solution on the same problem (another duration or mold height) unless told
    otherwise. Without ``problem`` the planner builds its own.
    """

    def __init__(self, cfg: PlantConfig, limits: DriveLimits, *,
                 contact_speed: float = CONTACT_SPEED, intervals: int = INTERVALS,
                 problem: StrokeProblem | None = None) -> None:
        if cfg.x_contact is None:
            raise ParameterError("the planner needs a mold-contact position (x_contact)")
        self.problem = problem or StrokeProblem(cfg.with_(x_contact=None), limits,
                                                contact_speed, intervals)
        pr = self.problem
        self.config, self.limits, self.contact_speed = cfg, limits, contact_speed
        self.x_open, self.x_final, self.stroke, self.t_ref = (pr.x_open, pr.x_final, pr.stroke,
                                                              pr.t_ref)
        self.n1, self.n2 = pr.n1, pr.n2
        self.xi_contact = (cfg.x_contact - self.x_open) / self.stroke
        self.force_limit = limits.force(cfg.mechanism.drive)
        self.f_ref = self._reference_force()

    @property
    def last(self) -> Plan | None:
        """The latest plan on this planner's problem (any mold height)."""
        return self.problem.last

    def _force(self, x: Any, v: Any, a: Any) -> np.ndarray:
        """The plant's input force at the points (x, v, a) with this planner's mold, N."""
        return self.problem.input_force(x, v, a, self.config.x_contact)

    def _reference_force(self) -> float:
        """Scale of the input force: its quasi-static peak at the reference speed, N."""
        xs = np.linspace(self.x_open, self.x_final, 401)
        f = self._force(xs, self.stroke / self.t_ref, 0.0)
        return max(float(np.max(np.abs(f))), 1e-6)

    def _parameters(self, weights: list[float]) -> list[float]:
        return [*weights, self.config.x_contact, self.f_ref]

    # ---- solving --------------------------------------------------------------------

    def _bounds(self, force_limit: float) -> tuple[np.ndarray, np.ndarray]:
        N, S, t_ref, lim = self.n1 + self.n2, self.stroke, self.t_ref, self.limits
        lbx, ubx = np.empty(4 * N + 6), np.empty(4 * N + 6)
        spans = ((0.0, 1.0),  # stroke limits
                 (0.0, lim.velocity * t_ref / S),  # monotone stroke, top speed
                 (-lim.acceleration * t_ref**2 / S, lim.acceleration * t_ref**2 / S))
        for k, (lo, hi) in enumerate(spans):
            lbx[k * (N + 1):(k + 1) * (N + 1)], ubx[k * (N + 1):(k + 1) * (N + 1)] = lo, hi
        lbx[3 * N + 3:4 * N + 3] = -self.problem.jerk_bound
        ubx[3 * N + 3:4 * N + 3] = self.problem.jerk_bound
        # no creeping through the clamping below the friction model's smoothing speed
        creep = CREEP_FACTOR * self.config.velocity_epsilon * t_ref / S
        lbx[N + 1 + self.n1:2 * N + 1 - max(2, self.n2 // 10)] = creep
        for k in (N + 1, 2 * N + 2, 2 * N + 1, 3 * N + 2):  # rest at both ends
            lbx[k] = ubx[k] = 0.0
        ubx[0], lbx[N] = 0.0, 1.0  # from the open position to the toggle
        lbx[4 * N + 3:4 * N + 5], ubx[4 * N + 3:4 * N + 5] = 1e-6, np.inf
        lbx[4 * N + 5], ubx[4 * N + 5] = 0.0, force_limit / self.f_ref
        return lbx, ubx

    def _initial_guess(self, duration: float) -> np.ndarray:
        """The septic rest-to-rest polynomial over ``duration``, split at mold contact."""
        n1, n2, r = self.n1, self.n2, self.t_ref / duration
        tau_c = brentq(lambda t: _min_jerk(np.array(t))[0] - self.xi_contact, 0.0, 1.0)
        tau = np.concatenate([np.linspace(0, tau_c, n1 + 1), np.linspace(tau_c, 1, n2 + 1)[1:]])
        xi, nu, al, _ = _min_jerk(tau)
        jerk = np.diff(al) / np.diff(tau)
        f = self._force(self.x_open + self.stroke * xi, self.stroke * nu / duration,
                        self.stroke * al / duration**2)
        s = float(np.max(np.abs(f))) / self.f_ref
        return np.concatenate([xi, nu * r, al * r**2, jerk * r**3,
                               [tau_c / n1 / r, (1 - tau_c) / n2 / r, s]])

    def _stretched(self, start: Plan, duration: float) -> dict[str, np.ndarray]:
        """A previous solution stretched in time to ``duration`` (the warm start)."""
        N, sol = self.n1 + self.n2, start.solution
        r = start.duration / duration
        w = sol["x"].copy()
        for k, power in enumerate((1, 2, 3), start=1):
            w[k * (N + 1):(k + 1) * (N + 1) - (k == 3)] *= r**power
        w[4 * N + 3:4 * N + 5] /= r
        return {"x0": w, "lam_x0": sol["lam_x"], "lam_g0": sol["lam_g"]}

    def _run(self, weights: list[float], t_bounds: tuple[float, float], force_limit: float,
             objective: str, start: Plan | None, warm: bool) -> tuple[Plan, bool]:
        start = start or self.last
        warm = warm and start is not None and start.solution["x"].size == self.problem.size
        lbx, ubx = self._bounds(force_limit)
        lbg, ubg = (b.copy() for b in self.problem.g_bounds)
        lbg[-1], ubg[-1] = (t / self.t_ref for t in t_bounds)
        lbg[3 * (self.n1 + self.n2)] = ubg[3 * (self.n1 + self.n2)] = self.xi_contact
        target = min(max(2 * self.t_ref, t_bounds[0]), t_bounds[1])
        args = self._stretched(start, target) if warm else {"x0": self._initial_guess(target)}
        args["x0"] = np.clip(args["x0"], lbx, ubx)
        solver = self.problem.solver(warm, energy=weights[1] > 0)
        tic = time.perf_counter()
        sol = solver(p=self._parameters(weights), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, **args)
        elapsed = time.perf_counter() - tic
        stats = solver.stats()
        solution = {k: np.asarray(sol[k]).ravel() for k in ("x", "lam_x", "lam_g")}
        plan = self._plan(solution, objective, elapsed, int(stats["iter_count"]), warm)
        return plan, bool(stats["success"])

    def _plan(self, sol: dict[str, np.ndarray], objective: str, elapsed: float, iterations: int,
              warm: bool) -> Plan:
        N, n1, S, t_ref = self.n1 + self.n2, self.n1, self.stroke, self.t_ref
        w = sol["x"]
        steps = t_ref * np.concatenate([np.full(n1, w[4 * N + 3]), np.full(self.n2, w[4 * N + 4])])
        profile = Profile(knots=np.concatenate(([0.0], np.cumsum(steps))),
                          x=self.x_open + S * w[:N], v=S / t_ref * w[N + 1:2 * N + 1],
                          a=S / t_ref**2 * w[2 * N + 2:3 * N + 2],
                          jerk=S / t_ref**3 * w[3 * N + 3:4 * N + 3])
        return Plan(profile, self.config, objective,
                    float(profile.knots[n1]), elapsed, iterations, warm, sol)

    def solve(self, duration: float, objective: str = "peak", *, start: Plan | None = None,
              warm: bool = True) -> Plan:
        """The stroke of ``duration`` s minimising the peak input force (``"peak"``) or
        the integral of its square (``"rms"``); raises :class:`PlanningError` if none exists."""
        if objective not in OBJECTIVES:
            raise ParameterError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
        if not (math.isfinite(duration) and duration > 0):
            raise ParameterError(f"duration must be a positive time, got {duration!r} s")
        self._check_force(self.force_limit)
        if duration < self.t_ref:
            self._too_short(duration)
        weights = [1.0, 0.0, 0.0, _REGULARISATION] if objective == "peak" else [0.0, 1.0, 0.0, 0.0]
        plan, ok = self._run(weights, (duration, duration), self.force_limit, objective, start,
                             warm)
        if not ok and warm:  # a poor warm start: retry from the cold guess
            plan, ok = self._run(weights, (duration, duration), self.force_limit, objective,
                                 None, False)
        if not ok:
            self._too_short(duration)
        self.problem.last = plan
        return plan

    def minimum_time(self, force_limit: float | None = None, *, start: Plan | None = None,
                     warm: bool = True) -> Plan:
        """The fastest stroke with |input force| at most ``force_limit`` N (default: the
        motor-torque limit)."""
        limit = self.force_limit if force_limit is None else min(force_limit, self.force_limit)
        if not (math.isfinite(limit) and limit > 0):
            raise ParameterError(f"force limit must be > 0 N, got {force_limit!r}")
        self._check_force(limit)
        bounds, weights = (self.t_ref, 100 * self.t_ref), [0.0, 0.0, 1.0, _REGULARISATION]
        plan, ok = self._run(weights, bounds, limit, "time", start, warm)
        if not ok and warm:
            plan, ok = self._run(weights, bounds, limit, "time", None, False)
        if not ok:
            status = self.problem.solver(False, energy=False).stats()["return_status"]
            raise PlanningError("the planner found no profile that meets the drive limits "
                                f"(IPOPT: {status})")
        self.problem.last = plan
        return plan

    # ---- diagnosis ------------------------------------------------------------------

    def binding_limits(self, plan: Plan, force_limit: float | None = None) -> list[str]:
        """Names of the limits the plan runs at (within 1 %)."""
        F, contact = (np.asarray(v).ravel()
                      for v in self.problem.monitor(plan.solution["x"], self._parameters([0] * 4)))
        pr, lim = plan.profile, self.limits
        limit = self.force_limit if force_limit is None else force_limit
        found = {
            f"velocity (max {lim.velocity * 1e3:.4g} mm/s)": np.max(pr.v) / lim.velocity,
            f"acceleration (max {lim.acceleration:.4g} m/s^2)":
                np.max(np.abs(pr.a)) / lim.acceleration,
            f"jerk (max {lim.jerk:.4g} m/s^3)": np.max(np.abs(pr.jerk)) / lim.jerk,
            f"motor torque (max {lim.torque:.4g} N m, {limit:.4g} N thrust)":
                np.max(np.abs(F)) / limit,
            f"platen speed at mold contact (max {self.contact_speed * 1e3:.4g} mm/s)": contact[0],
        }
        return [name for name, ratio in found.items() if ratio >= _BINDING]

    @functools.cached_property
    def _creep_thrust(self) -> float:
        """The largest input force of clamping at creep speed, N."""
        xs = np.linspace(self.config.x_contact, self.x_final, 401)
        return float(np.max(self._force(xs, CREEP_FACTOR * self.config.velocity_epsilon, 0.0)))

    def _check_force(self, limit: float) -> None:
        """Refuse a force limit below the clamping thrust at creep speed (no profile can
        clamp without creeping under the friction model's smoothing speed)."""
        need = self._creep_thrust
        if need > limit:
            bound = (f"the force limit of {limit:.4g} N" if limit < self.force_limit else
                     f"the {limit:.4g} N the motor torque limit ({self.limits.torque:.4g} N m) "
                     "allows")
            raise PlanningError(
                f"clamping to {self.clamp_force():.6g} N needs a thrust of {need:.4g} N even "
                f"at creep speed, above {bound}"
            )

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
                intervals: int = INTERVALS) -> ClampPlanner:
    """A planner on a kept problem, so that a re-plan for the same plant, for any mold
    height, neither rebuilds nor starts cold."""
    problem = _problem_for(cfg.with_(x_contact=None), limits, contact_speed, intervals)
    return ClampPlanner(cfg, limits, contact_speed=contact_speed, intervals=intervals,
                        problem=problem)


def baselines(cfg: PlantConfig, limits: DriveLimits, duration: float
              ) -> dict[str, ProfileSamples]:
    """The trapezoidal and S-curve strokes of the same duration and limits, predicted."""
    x_open, x_final = clamp_stroke(cfg.mechanism)
    return {
        name: predict(s_curve(x_open, x_final, duration, limits.velocity, limits.acceleration,
                              jerk), cfg)
        for name, jerk in (("trapezoidal", math.inf), ("s_curve", limits.jerk))
    }


def default_duration(planner: ClampPlanner) -> float:
    """Twice the kinematic minimum stroke time, rounded up to 0.1 s."""
    return math.ceil(20 * planner.t_ref) / 10


def plan_default_profile(preset: str, *, period: float = 1e-3) -> Any:
    """The preset's default plan as a :class:`hil.samples.Trajectory` sampled every ``period``."""
    from hil.samples import Trajectory

    cfg = plan_config(preset)
    planner = planner_for(cfg, drive_limits(cfg.mechanism))
    plan = planner.solve(default_duration(planner))
    t = np.arange(0.0, plan.duration + period / 2, period)
    return Trajectory.from_positions(plan.profile.sample(t)[0], period)
