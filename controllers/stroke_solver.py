"""Solving one clamp stroke: the bounds, the starting points, one IPOPT solve and the
best of several starts.

:class:`StrokeSolver` solves the optimal control problem of
:mod:`controllers.stroke_problem` (its variables, constraints and objective: the plant's
own equations through CasADi, solved by IPOPT) for a plant with its mold: a stroke of a
given duration (:meth:`~StrokeSolver.solve`) and the best of several starts
(:meth:`~StrokeSolver.best`: the problem has two families of local optima, slow or fast
arrival at the mold, the latter braking through the thrust peak), stopping at the lower
bound (:meth:`~StrokeSolver.lower_bound`, :mod:`controllers.bounds`). A re-plan
warm-starts IPOPT from the previous primal and dual solution, stretched in time to the
new duration. The fastest stroke under a force limit and the trade-off are
:class:`controllers.planner.ClampPlanner`'s, which is this solver with them.
"""

from __future__ import annotations

import math
import time

import casadi as ca
import numpy as np

from controllers import progress as solves
from controllers.bounds import peak_lower_bound
from controllers.plans import CREEP_FACTOR, Plan, PlanningError
from controllers.profiles import Profile, s_curve
from controllers.stroke_problem import StrokeProblem, objective_weights
from controllers.stroke_reports import StrokeReports
from toggle.interrupts import signals_survive
from toggle.params import ParameterError
from toggle.roots import brentq

#: best(): stretches of the late S-curve starts, and the gap to the lower bound that ends
#: the search (relative).
LATE_STARTS = (1.0, 1.1, 1.25)
GAP = 3e-3
TIGHTEN = 4  # re-plans with a cap or limit tightened by the excess between nodes


def _min_jerk(tau: np.ndarray) -> tuple[np.ndarray, ...]:
    """Rest-to-rest septic polynomial on [0, 1] and its first three derivatives."""
    c = np.array([-20.0, 70.0, -84.0, 35.0, 0, 0, 0, 0])
    return tuple(np.polyval(np.polyder(c, m) if m else c, tau) for m in range(4))


class StrokeSolver(StrokeReports):
    """Solves strokes of one plant with its mold, on a :class:`StrokeProblem`:
    :meth:`solve` a stroke of a given duration, :meth:`best` the best of several starts;
    each warm-starts from the previous solution on the same problem (another duration,
    mold height, friction or drive limit) unless told otherwise. The setup and the
    reports on a plan are :class:`controllers.stroke_reports.StrokeReports`'s."""

    #: The solving's state, set on the solver once known: whether its plans need the
    #: torque rows (:meth:`_run`) and the lower bound (:meth:`lower_bound`).
    _torque: bool = False
    _bound: float | None = None

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
        for _ in range(TIGHTEN if caps != (None, None) else 0):
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
        previous plan (warm) and late S-curves (:meth:`_late_guess`, :meth:`late_starts`),
        stopping once a peak plan is within :data:`GAP` of :meth:`lower_bound`. The
        problem has two families of local optima, slow and fast arrival at the mold; a
        single start finds either. Judged by the peak on the 1 ms samples, the RMS force,
        or (energy, weighted) the objective's value."""
        weights = objective_weights(objective, energy_weight)
        previous = self.last
        key = (self.worst_peak if weights[1] == 0 else (lambda p: p.rms_force)
               if objective == "rms" else (lambda p: float(p.solution["f"][0])))
        good = self.lower_bound() * (1 + GAP) if weights[1] == 0 else 0.0
        late = self.late_starts(objective)
        self._expect(self.best_solves(objective))
        plans = [self.solve(duration, objective, warm=False, energy_weight=energy_weight)]
        self._advance()
        if previous is not None:
            plans.append(self.solve(duration, objective, start=previous,
                                    energy_weight=energy_weight))
            self._advance()
        for left, stretch in enumerate(late):
            if key(min(plans, key=key)) <= good:
                self._expect(left - len(late))  # skipped: no longer coming
                break
            plan, ok = self._run(weights, (duration, duration), self.force_limit,
                                 objective, None, False,
                                 guess=self._late_guess(duration, stretch))
            self._advance()
            if ok:
                plans.append(plan)
        self.problem.last = min(plans, key=key)
        return self.problem.last

    def late_starts(self, objective: str = "peak") -> tuple[float, ...]:
        """The stretches of :meth:`best`'s late S-curve starts: :data:`LATE_STARTS`, none
        for a robust plan's peak (a plant with variants). A late start wins the nominal
        clamp's peak by 0.4 % (chang2021, 3.1 s); for the worst peak over the variants the
        polynomial start's plan was within 0.25 % of the best of all four starts in each
        of the 33 cases of ``benchmarks/bench_robust_starts.py`` (2 presets, 6 error sets,
        3 durations: within :data:`GAP`, the search's own tolerance), where the late
        starts took three quarters of the solving (docs/planning.md)."""
        return () if self.variants and objective == "peak" else LATE_STARTS

    @property
    def solve_weight(self) -> float:
        """A solve's expected time relative to others' (the progress's ETA): its problem's
        constraint rows, in thousands (the functions and the KKT system grow with them;
        chang2021's robust problem has 2412 rows to its nominal twin's 1607, and its solve
        took 1.8 times as long an iteration)."""
        return self.problem.n_constraints / 1000

    def _expect(self, steps: int) -> None:
        """Announce ``steps`` solves of this planner on the progress (:attr:`solve_weight`)."""
        solves.expect(steps, self.solve_weight)

    def _advance(self) -> None:
        """Count one solve of this planner done on the progress."""
        solves.advance(1, self.solve_weight)

    def best_solves(self, objective: str = "peak") -> int:
        """The solves :meth:`best` announces now (some may be skipped)."""
        return 1 + (self.last is not None) + len(self.late_starts(objective))

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

    def _too_short(self, duration: float) -> None:
        fastest = self.minimum_time(warm=False)
        binding = ", ".join(self.binding_limits(fastest)) or "the drive limits"
        raise PlanningError(
            f"duration {duration:.4g} s is too short: the shortest feasible stroke takes "
            f"{fastest.duration:.4g} s (binding: {binding})"
        )

