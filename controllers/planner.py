"""Optimal crosshead motion for a clamp stroke: least time or least drive force under
real limits, solved.

:class:`ClampPlanner` solves the optimal control problem of
:mod:`controllers.stroke_problem` (its variables, constraints and objective: the plant's
own equations through CasADi, solved by IPOPT) for a plant with its mold
(:func:`controllers.plans.plan_config`): a stroke of a given duration (:meth:`~ClampPlanner.solve`),
the best of several starts, the fastest under a force limit, the trade-off between the
two. The setup and the reports on a plan (peaks, torque, protection zone, binding limits)
are :mod:`controllers.stroke_reports`'s.

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

One built problem (shared by :func:`planner_for`) serves every duration, mode, mold
height, friction, mass, drive and drive limit, and a re-plan warm-starts IPOPT from the
previous primal and dual solution, stretched in time to the new duration.

Speed (``benchmarks/bench_planner.py``, chang2021, N = 200, 3 s, two shared
cores): a cold plan takes about 0.25 s with the disk cache filled (the problem
loaded in about 12 ms, 62 IPOPT iterations), a warm re-plan about 14 ms for
another duration (3 iterations), 25 ms for another mold height and 17 ms for
another v_max or mu; the best of several starts about 1.3 s, minimum time under
a force limit about 2 s; the first plan of a plant (or after a change of the
code it uses) compiles for about 10 s.
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable

import casadi as ca
import numpy as np
from scipy.optimize import brentq

from controllers import background
from controllers import progress as solves
from controllers.background import Background
from controllers.bounds import peak_lower_bound
from controllers.limits import DriveLimits
from controllers.plans import (
    CONTACT_SPEED,
    CREEP_FACTOR,
    INTERVALS,
    NO_PROTECTION,
    Plan,
    PlanningError,
    Protection,
)
from controllers.profiles import Profile, s_curve
from controllers.progress import Progress, reporting
from controllers.stroke_problem import (
    REGULARISATION,
    WEIGHTS,
    StrokeProblem,
    neutral,
    objective_weights,
    problem_for,
)
from controllers.stroke_reports import StrokeReports
from toggle.interrupts import signals_survive
from toggle.params import ParameterError
from toggle.plant import PlantConfig

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
_TIGHTEN = 4  # re-plans of minimum_time with the limit tightened by the excess between nodes


def _min_jerk(tau: np.ndarray) -> tuple[np.ndarray, ...]:
    """Rest-to-rest septic polynomial on [0, 1] and its first three derivatives."""
    c = np.array([-20.0, 70.0, -84.0, 35.0, 0, 0, 0, 0])
    return tuple(np.polyval(np.polyder(c, m) if m else c, tau) for m in range(4))


class ClampPlanner(StrokeReports):
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
    against its own baseline). The setup and the reports on a plan are
    :class:`controllers.stroke_reports.StrokeReports`'s.
    """

    #: The solving's state, set on the planner once known: whether its plans need the
    #: torque rows (:meth:`_run`), the least peak (:meth:`least_peak`) and the lower bound
    #: (:meth:`lower_bound`).
    _torque: bool = False
    _least: Plan | None = None
    _bound: float | None = None
    #: :func:`planner_for`'s arguments that made this planner, for a job that needs the
    #: same planner in a second process (:func:`least_peak_job`); None if made otherwise.
    recipe: tuple[object, ...] | None = None

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
        solves.expect(1 + (previous is not None) + len(_LATE_STARTS))
        plans = [self.solve(duration, objective, warm=False, energy_weight=energy_weight)]
        solves.advance()
        if previous is not None:
            plans.append(self.solve(duration, objective, start=previous,
                                    energy_weight=energy_weight))
            solves.advance()
        for left, stretch in enumerate(_LATE_STARTS):
            if key(min(plans, key=key)) <= good:
                solves.advance(len(_LATE_STARTS) - left)  # skipped: counted as done
                break
            plan, ok = self._run(weights, (duration, duration), self.force_limit,
                                 objective, None, False,
                                 guess=self._late_guess(duration, stretch))
            solves.advance()
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
                     warm: bool = True, continued: bool = False, ask_least: bool = True
                     ) -> Plan:
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
        is tightened by the excess and the plan repeated. ``ask_least`` false: the least
        peak's refusal is left to the caller (:meth:`trade_off`, which has it computed in a
        second process meanwhile)."""
        limit = self.force_limit if force_limit is None else min(force_limit, self.force_limit)
        if not (math.isfinite(limit) and limit > 0):
            raise ParameterError(f"force limit must be > 0 N, got {force_limit!r}")
        if limit < self.lower_bound():
            raise PlanningError(self._unreachable(limit, None) + (
                f": no stroke of any duration peaks below {self.lower_bound():.4g} N "
                "(the lower bound, inertia relief included)"))
        if continued and start is not None:
            plan: Plan | None = start
        else:
            solves.expect(1)
            plan = self._fastest(self.force_limit, start, warm)
            solves.advance()
        if plan is None:
            raise PlanningError(self._unreachable(limit, None))
        top = min(self.worst_peak(plan), self.force_limit)
        if ask_least and self._asks_least(limit, top) and limit < self.worst_peak(
                least := self.least_peak()) * (1 - _LEAST_MARGIN):
            raise PlanningError(self._unreachable(limit, least) + (
                " (the least peak of any duration it finds)"))
        levels = self._levels(top, limit, _TRADE_STEP if continued else _LIMIT_STEP)
        imposed = limit
        solves.expect(len(levels))
        for level in levels:
            imposed = level
            reached = self._fastest(level, plan, True)
            solves.advance()
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
            solves.expect(1)
            reached = self._fastest(imposed, plan, True, factor)
            solves.advance()
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
        bound = self.lower_bound()
        bottom = bound * (1 + _GAP) if bound > 0 else top / 4
        limits = [float(v) for v in np.geomspace(top, bottom, points)[1:]]
        return self._trade_off_points([fastest], limits, tick, background.parallel())

    def _trade_off_points(self, plans: list[Plan], limits: list[float],
                          tick: Callable[[], object], ahead: bool) -> list[Plan]:
        """The trade-off's points under ``limits`` after ``plans``, each continued from the
        last, up to the first no stroke meets. ``ahead``: where a limit first asks for the
        least peak (:meth:`minimum_time`), it is computed in a second process
        (:func:`least_peak_job`, from this planner's state then) while the points go on
        here, and their refusals are decided once it is known: the same points, and a
        mold curve's seconds of :meth:`best` off this process's path."""
        plans = list(plans)
        job: Background | None = None
        asked = 0  # the index into plans of the point that asked for the least peak
        torque = []  # self._torque before each point, to restore where the curve ends
        broke = False  # the last point's continuation failed
        with contextlib.ExitStack() as stack:
            for limit in limits:
                top = min(self.worst_peak(plans[-1]), self.force_limit)
                if (ahead and job is None and self._least is None and self.recipe
                        and self._asks_least(limit, top)):
                    job = stack.enter_context(Background(
                        least_peak_job, self.recipe, self.lower_bound(), self._torque,
                        self.problem.last))
                    asked = len(plans)
                torque.append(self._torque)
                try:
                    plan = self.minimum_time(limit, start=plans[-1], continued=True,
                                             ask_least=job is None)
                except PlanningError:
                    broke = True
                    break
                finally:
                    tick()
                plans.append(plan)
            if job is None:
                return plans
            try:
                self._least, needs_torque = job.result()
            except PlanningError:  # where the least peak was asked, the curve ended
                return self._ended(plans, asked, torque[asked - 1])
        if needs_torque and not torque[asked - 1]:  # its solves switched the torque rows on
            self._torque = True  # for every later point, as here they would have: again
            self._restore(plans[asked - 1], asked)
            return self._trade_off_points(plans[:asked], limits[asked - 1:], lambda: None,
                                          False)
        least = self.worst_peak(self._least) * (1 - _LEAST_MARGIN)
        # the refusals minimum_time left to this, the failed point's too (refused, it
        # would not have been tried)
        for k in range(asked, len(plans) + broke):
            top = min(self.worst_peak(plans[k - 1]), self.force_limit)
            if self._asks_least(limits[k - 1], top) and limits[k - 1] < least:
                return self._ended(plans, k, torque[k - 1])
        return plans

    def _ended(self, plans: list[Plan], k: int, torque: bool) -> list[Plan]:
        """The curve up to point ``k`` (its limit refused), the planner as it was then."""
        self._torque = torque
        self._restore(plans[k - 1], k)
        return plans[:k]

    def _restore(self, last: Plan, k: int) -> None:
        """The latest plan as it was before point ``k``: the previous point's (the
        fastest stroke's, k = 1, was never kept as the latest)."""
        if k > 1:
            self.problem.last = last

    def _asks_least(self, limit: float, top: float) -> bool:
        """Whether :meth:`minimum_time` asks :meth:`least_peak` for ``limit`` below a
        plan's peak ``top``: within :data:`_NEAR_BOUND` of the lower bound."""
        return limit < top and limit < self.lower_bound() * (1 + _NEAR_BOUND)

    def least_peak(self) -> Plan:
        """The stroke of least peak input force the planner finds over every duration up
        to :attr:`longest`: the best plan of the default duration (:meth:`best`), then
        with the duration free, warm from it (kept: computed once per planner). No force
        limit below its peak is met by any plan the continuation of :meth:`minimum_time`
        reaches."""
        if self._least is None:
            previous = self.problem.last
            start = self.best(default_duration(self))
            solves.expect(1)
            plan, ok = self._run(WEIGHTS["peak"], (self.t_ref, self.longest),
                                 self.force_limit, "peak", start, True)
            solves.advance()
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
        bounds, weights = (self.t_ref, 100 * self.t_ref), [0.0, 0.0, 1.0, REGULARISATION, 0.0]
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
                protection: Protection = NO_PROTECTION, opening: bool = False) -> ClampPlanner:
    """A planner on a kept problem, so that a re-plan for the same plant (and variants),
    for any mold height, friction, drive limits or protection zone, neither rebuilds nor
    starts cold. ``opening``: the opening (break-away) stroke from the toggle back to the
    open position instead of the closing one (:class:`ClampPlanner`)."""
    problem = problem_for(neutral(cfg), intervals, tuple(neutral(v) for v in variants),
                          opening=opening)
    planner = ClampPlanner(cfg, limits, contact_speed=contact_speed, intervals=intervals,
                           problem=problem, variants=variants, scales=scales,
                           protection=protection)
    planner.recipe = (cfg, limits, contact_speed, intervals, variants, scales, protection,
                      opening)
    return planner


def trade_off_curve(cfg: PlantConfig, limits: DriveLimits, contact_speed: float,
                    intervals: int, protection: Protection, points: int,
                    progress: Callable[[], object] | None = None) -> list[Plan]:
    """:meth:`ClampPlanner.trade_off` of the plant's planner (:func:`planner_for`): a
    job for :class:`controllers.background.Background`."""
    return planner_for(cfg, limits, contact_speed, intervals,
                       protection=protection).trade_off(points, progress)


def best_plan(cfg: PlantConfig, limits: DriveLimits, contact_speed: float, intervals: int,
              protection: Protection, duration: float, objective: str,
              bound: float | None = None, progress: Progress | None = None) -> Plan:
    """:meth:`ClampPlanner.best` of the plant's planner (:func:`planner_for`): a job for
    :class:`controllers.background.Background`, its solves counted on ``progress``.
    ``bound``: the plant's :meth:`ClampPlanner.lower_bound` if the caller has it (the same
    value, not computed again)."""
    planner = planner_for(cfg, limits, contact_speed, intervals, protection=protection)
    if bound is not None and planner._bound is None:
        planner._bound = bound
    with reporting(progress) if progress is not None else contextlib.nullcontext():
        return planner.best(duration, objective)


def least_peak_job(recipe: tuple[object, ...], bound: float, torque: bool,
                   last: Plan | None, progress: Callable[[], object] | None = None
                   ) -> tuple[Plan, bool]:
    """:meth:`ClampPlanner.least_peak` of the planner ``planner_for(*recipe)`` in the state
    of the one that asks (its lower bound, whether it solves with the torque rows, its
    latest plan, the warm start of :meth:`ClampPlanner.best`): the same plan it would find
    itself; and whether the torque rows are on after it. A job for
    :class:`controllers.background.Background` in :meth:`ClampPlanner.trade_off`."""
    planner = planner_for(*recipe)  # type: ignore[arg-type]
    planner._bound, planner._torque, planner.problem.last = bound, torque, last
    return planner.least_peak(), planner._torque


def default_duration(planner: ClampPlanner) -> float:
    """Twice the kinematic minimum stroke time, rounded up to 0.1 s."""
    return math.ceil(20 * planner.t_ref) / 10
