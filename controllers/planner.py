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
and the duration is a constraint whose bounds fix it or leave it free. So one
built problem (CasADi ``nlpsol``, per-point plant functions mapped over the
nodes, the objective weights as parameters) serves every duration and mode,
and a re-plan warm-starts IPOPT from the previous primal and dual solution,
stretched in time to the new duration. The mold-contact position is a number
inside :func:`~toggle.plant.plant_outputs`, so another mold height builds a
new problem (cached by :func:`planner_for`), warm-started from the previous plan.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import casadi as ca
import numpy as np
from scipy.optimize import brentq

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
_IPOPT = {"print_level": 0, "sb": "yes", "max_iter": 500, "tol": 1e-6,
          "acceptable_tol": 1e-4, "mu_strategy": "adaptive"}
_WARM = {"warm_start_init_point": "yes", "mu_init": 1e-7, "warm_start_bound_push": 1e-9,
         "warm_start_bound_frac": 1e-9, "warm_start_slack_bound_push": 1e-9,
         "warm_start_slack_bound_frac": 1e-9, "warm_start_mult_bound_push": 1e-9}


class PlanningError(ValueError):
    """A request no profile can meet; the message names the binding limit."""


@dataclass(frozen=True)
class Plan:
    """A planned stroke: the profile, its prediction through the plant and solver data."""

    profile: Profile
    samples: ProfileSamples
    objective: str
    t_contact: float
    solve_time: float
    iterations: int
    warm: bool
    solution: dict[str, np.ndarray] = field(repr=False)  # scaled primal and dual solution

    @property
    def duration(self) -> float:
        return self.profile.duration

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


class ClampPlanner:
    """The built problem for one plant, drive limits and contact-speed limit.

    :meth:`solve` plans a stroke of a given duration, :meth:`minimum_time`
    the fastest one under a force limit; each warm-starts from the previous
    solution unless told otherwise.
    """

    def __init__(self, cfg: PlantConfig, limits: DriveLimits, *,
                 contact_speed: float = CONTACT_SPEED, intervals: int = INTERVALS) -> None:
        if cfg.x_contact is None:
            raise ParameterError("the planner needs a mold-contact position (x_contact)")
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
        self.xi_contact = (cfg.x_contact - self.x_open) / self.stroke
        self.n1 = intervals - intervals // 2
        self.n2 = intervals // 2
        self.force_limit = limits.force(cfg.mechanism.drive)
        self.t_ref = minimum_time(self.stroke, limits.velocity, limits.acceleration, limits.jerk)
        self._jerk_bound = limits.jerk * self.t_ref**3 / self.stroke
        self.f_ref = self._reference_force()
        self._solvers: dict[bool, Any] = {}
        self._nlp, self._g_bounds, self._monitor = self._build()
        self.last: Plan | None = None

    # ---- construction ---------------------------------------------------------------

    def _reference_force(self) -> float:
        """Scale of the input force: its quasi-static peak at the reference speed, N."""
        xs = np.linspace(self.x_open, self.x_final, 401)
        f = plant_outputs(xs, np.full_like(xs, self.stroke / self.t_ref), 0 * xs, self.config)
        return max(float(np.max(np.abs(f.input_force))), 1e-6)

    def _plant_functions(self) -> tuple[ca.Function, ca.Function]:
        """(x, v, a) -> (F, platen velocity) of the mold-free plant, and F with the mold."""
        x, v, a = (ca.SX.sym(n) for n in "xva")
        free = plant_outputs(x, v, a, self.config.with_(x_contact=None))
        mold = plant_outputs(x, v, a, self.config)
        opts = {"cse": True}
        f_free = ca.Function("free", [x, v, a],
                             [ca.SX(free.input_force), ca.SX(free.platen_velocity)], opts)
        f_mold = ca.Function("mold", [x, v, a], [ca.SX(mold.input_force)], opts)
        return f_free, f_mold

    def _build(self) -> tuple[dict, tuple[np.ndarray, np.ndarray], ca.Function]:
        """The NLP in scaled variables: position xi = (x - x_open) / S, velocity, acceleration
        and jerk in units of S / T_ref^k, interval lengths theta in units of T_ref."""
        n1, n2 = self.n1, self.n2
        N = n1 + n2
        w = ca.MX.sym("w", 4 * N + 6)
        xi, nu, al = (w[k * (N + 1):(k + 1) * (N + 1)] for k in range(3))
        io = w[3 * N + 3:4 * N + 3]
        th1, th2, s = w[4 * N + 3], w[4 * N + 4], w[4 * N + 5]
        weights = ca.MX.sym("p", 4)  # peak, integral of F^2, duration, jerk regularisation
        d = ca.vertcat(ca.repmat(th1, n1, 1), ca.repmat(th2, n2, 1))
        dyn = ca.vertcat(
            xi[1:] - (xi[:-1] + d * (nu[:-1] + d * (al[:-1] / 2 + d * io / 6))),
            nu[1:] - (nu[:-1] + d * (al[:-1] + d * io / 2)),
            al[1:] - (al[:-1] + d * io),
        )
        S, t_ref = self.stroke, self.t_ref
        x, v, a = self.x_open + S * xi.T, S / t_ref * nu.T, S / t_ref**2 * al.T
        f_free, f_mold = self._plant_functions()
        F1, pv = f_free.map(n1 + 1)(x[:n1 + 1], v[:n1 + 1], a[:n1 + 1])
        F2 = f_mold.map(n2 + 1)(x[n1:], v[n1:], a[n1:])
        F = ca.vertcat(F1.T, F2.T) / self.f_ref

        def integral(Fp: ca.MX, h: ca.MX) -> ca.MX:  # trapezoidal rule
            return h * (ca.sumsqr(Fp) - (Fp[0] ** 2 + Fp[-1] ** 2) / 2)

        energy = integral(F[:n1 + 1], th1) + integral(F[n1 + 1:], th2)
        duration = n1 * th1 + n2 * th2
        objective = (weights[0] * s + weights[1] * energy + weights[2] * duration
                     + weights[3] * ca.dot(d, (io / self._jerk_bound) ** 2))
        g = ca.vertcat(dyn, xi[n1] - self.xi_contact, F - s, F + s,
                       pv[n1] / self.contact_speed, duration)
        nf = N + 2
        lbg = np.concatenate([np.zeros(3 * N + 1), np.full(nf, -np.inf), np.zeros(nf),
                              [-np.inf, 0.0]])
        ubg = np.concatenate([np.zeros(3 * N + 1), np.zeros(nf), np.full(nf, np.inf),
                              [1.0, np.inf]])
        nlp = {"x": w, "p": weights, "f": objective, "g": g}
        monitor = ca.Function("monitor", [w], [F, pv[n1] / self.contact_speed])
        return nlp, (lbg, ubg), monitor

    def _solver(self, warm: bool) -> Any:
        if warm not in self._solvers:
            opts = {"ipopt": {**_IPOPT, **(_WARM if warm else {})}, "print_time": False,
                    "error_on_fail": False}
            self._solvers[warm] = ca.nlpsol("plan", "ipopt", self._nlp, opts)
        return self._solvers[warm]

    # ---- solving --------------------------------------------------------------------

    def _bounds(self, force_limit: float) -> tuple[np.ndarray, np.ndarray]:
        N, S, t_ref, lim = self.n1 + self.n2, self.stroke, self.t_ref, self.limits
        lbx, ubx = np.empty(4 * N + 6), np.empty(4 * N + 6)
        spans = ((0.0, 1.0),  # stroke limits
                 (0.0, lim.velocity * t_ref / S),  # monotone stroke, top speed
                 (-lim.acceleration * t_ref**2 / S, lim.acceleration * t_ref**2 / S))
        for k, (lo, hi) in enumerate(spans):
            lbx[k * (N + 1):(k + 1) * (N + 1)], ubx[k * (N + 1):(k + 1) * (N + 1)] = lo, hi
        lbx[3 * N + 3:4 * N + 3], ubx[3 * N + 3:4 * N + 3] = -self._jerk_bound, self._jerk_bound
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
        f = plant_outputs(self.x_open + self.stroke * xi, self.stroke * nu / duration,
                          self.stroke * al / duration**2, self.config).input_force
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
        warm = warm and start is not None
        lbx, ubx = self._bounds(force_limit)
        lbg, ubg = (b.copy() for b in self._g_bounds)
        lbg[-1], ubg[-1] = (t / self.t_ref for t in t_bounds)
        target = min(max(2 * self.t_ref, t_bounds[0]), t_bounds[1])
        args = self._stretched(start, target) if warm else {"x0": self._initial_guess(target)}
        args["x0"] = np.clip(args["x0"], lbx, ubx)
        solver = self._solver(warm)
        tic = time.perf_counter()
        sol = solver(p=weights, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, **args)
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
        return Plan(profile, predict(profile, self.config), objective,
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
        self.last = plan
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
            raise PlanningError("the planner found no profile that meets the drive limits "
                                f"(IPOPT: {self._solver(False).stats()['return_status']})")
        self.last = plan
        return plan

    # ---- diagnosis ------------------------------------------------------------------

    def binding_limits(self, plan: Plan, force_limit: float | None = None) -> list[str]:
        """Names of the limits the plan runs at (within 1 %)."""
        F, contact = (np.asarray(v).ravel() for v in self._monitor(plan.solution["x"]))
        pr, lim = plan.profile, self.limits
        limit = self.force_limit if force_limit is None else force_limit
        found = {
            f"velocity (max {lim.velocity * 1e3:.4g} mm/s)": np.max(pr.v) / lim.velocity,
            f"acceleration (max {lim.acceleration:.4g} m/s^2)":
                np.max(np.abs(pr.a)) / lim.acceleration,
            f"jerk (max {lim.jerk:.4g} m/s^3)": np.max(np.abs(pr.jerk)) / lim.jerk,
            f"motor torque (max {lim.torque:.4g} N m, {limit:.4g} N thrust)":
                np.max(np.abs(F)) * self.f_ref / limit,
            f"platen speed at mold contact (max {self.contact_speed * 1e3:.4g} mm/s)": contact[0],
        }
        return [name for name, ratio in found.items() if ratio >= _BINDING]

    def _check_force(self, limit: float) -> None:
        """Refuse a force limit below the clamping thrust at creep speed (no profile can
        clamp without creeping under the friction model's smoothing speed)."""
        xs = np.linspace(self.config.x_contact, self.x_final, 401)
        creep = CREEP_FACTOR * self.config.velocity_epsilon
        need = float(np.max(plant_outputs(xs, np.full_like(xs, creep), 0 * xs,
                                          self.config).input_force))
        if need > limit:
            raise PlanningError(
                f"the motor torque limit binds: clamping to {self.clamp_force():.6g} N needs a "
                f"thrust of {need:.4g} N even at creep speed, above the {limit:.4g} N "
                f"{'the force limit' if limit < self.force_limit else 'the torque limit'} "
                f"({self.limits.torque:.4g} N m) allows"
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
    """A built planner, kept so that a re-plan for the same plant does not rebuild."""
    return ClampPlanner(cfg, limits, contact_speed=contact_speed, intervals=intervals)


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
