"""Optimal crosshead motion for a clamp stroke: least time or least drive force under
real limits, planned.

:class:`ClampPlanner` is the solver of one stroke (:class:`controllers.stroke_solver.
StrokeSolver`: a given duration, the best of several starts, the lower bound) with the
searches built on it: the fastest stroke under a force limit, the least peak of any
duration and the trade-off between the two; :func:`planner_for` keeps one planner per
plant, and the jobs (:func:`best_plan`, :func:`trade_off_curve`) run them in a second
process (:mod:`controllers.background`). The plant with its mold is
:func:`controllers.plans.plan_config`'s; the reports on a plan (peaks, torque,
protection zone, binding limits) are :mod:`controllers.stroke_reports`'s.

The opening (break-away) stroke, ``planner_for(..., opening=True)``, is the same
problem run backwards in time (the plant evaluated at -v): its plans are reversed
profiles from rest at the toggle to rest at the open position.

:meth:`ClampPlanner.minimum_time` lets the optimiser decide whether a force
limit can be met, by continuation from the fastest stroke down to the limit
(a trade-off's points each continued from the last), and checks the limit on the
plan's 1 ms samples (tightening it where the samples between the nodes exceed it);
a limit below the lower bound, or below the least peak of any duration
(:meth:`ClampPlanner.least_peak`), is refused before the continuation. With
``variants`` (the clamp with dimensional errors) the force limits and the peak
hold for the worst plant: a robust plan.

One built problem (shared by :func:`planner_for`) serves every duration, mode, mold
height, friction, mass, drive and drive limit.

Speed (``benchmarks/bench_planner.py``, chang2021, N = 200, 3 s, two shared
cores): a cold plan takes about 0.25 s with the disk cache filled (the problem
loaded in about 12 ms, 62 IPOPT iterations), a warm re-plan about 14 ms for
another duration (3 iterations), 25 ms for another mold height and 17 ms for
another v_max or mu; the best of several starts about 1.3 s, minimum time under
a force limit about 2 s. The first plan of a plant (or after a change of the code it
uses) plans with the functions interpreted while they compile in the background
(:mod:`controllers.compiled`): ``benchmarks/bench_cold_plans.py``.
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Callable

import numpy as np

from controllers.limits import DriveLimits
from controllers.plans import (
    CONTACT_SPEED,
    INTERVALS,
    NO_PROTECTION,
    Plan,
    PlanningError,
    Protection,
)
from controllers.progress import Progress, reporting
from controllers.stroke_problem import REGULARISATION, WEIGHTS, neutral, problem_for
from controllers.stroke_solver import GAP, TIGHTEN, StrokeSolver
from toggle.params import ParameterError
from toggle.plant import PlantConfig

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
#: A limit re-imposed where the 1 ms samples exceed it between the nodes: lower by this
#: times the excess (and a trade-off's next point by this times the last excess, ahead).
_TIGHTEN_BY = 1.5


class ClampPlanner(StrokeSolver):
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

    #: The least peak (:meth:`least_peak`), once known.
    _least: Plan | None = None
    #: How far the last minimum-time plan's 1 ms samples rose above the force limit
    #: imposed at its nodes and midpoints (relative): a trade-off's next point imposes its
    #: limit lower by :data:`_TIGHTEN_BY` times that from the start (:meth:`minimum_time`).
    _between = 0.0

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
        is tightened by the excess and the plan repeated. ``ask_least`` false: no least
        peak is asked (:meth:`trade_off`'s points)."""
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
            self._expect(1)
            plan = self._fastest(self.force_limit, start, warm)
            self._advance()
        if plan is None:
            raise PlanningError(self._unreachable(limit, None))
        top = min(self.worst_peak(plan), self.force_limit)
        if ask_least and self._asks_least(limit, top) and limit < self.worst_peak(
                least := self.least_peak()) * (1 - _LEAST_MARGIN):
            raise PlanningError(self._unreachable(limit, least) + (
                " (the least peak of any duration it finds)"))
        levels = self._levels(top, limit, _TRADE_STEP if continued else _LIMIT_STEP)
        # a trade-off's point: its limit imposed lower from the start by what the samples
        # rose above the last point's between the nodes, which spares the re-plan that
        # tightening would be (a third of the dry cycle's curve; the same margin it adds)
        levels[-1] *= (1 - _TIGHTEN_BY * self._between) if continued else 1.0
        imposed = limit
        self._expect(len(levels))
        for level in levels:
            imposed = level
            reached = self._fastest(level, plan, True)
            self._advance()
            if reached is None:
                raise PlanningError(self._unreachable(limit, plan))
            plan = reached
        factor = 1.0
        self._between = max(self.worst_peak(plan) / imposed - 1.0, 0.0)
        for _ in range(TIGHTEN):  # between the nodes: the 1 ms samples decide
            excess, over = self.worst_peak(plan) - limit, self.torque_ratio(plan) - 1.0
            if excess <= 0 and over <= 0:
                break
            imposed -= _TIGHTEN_BY * max(excess, 0.0)
            factor /= 1.0 + _TIGHTEN_BY * max(over, 0.0)
            self._torque = self._torque or over > 0
            self._expect(1)
            reached = self._fastest(imposed, plan, True, factor)
            self._advance()
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
        the toggle, down to a quarter of that peak), each continued from the last; the curve
        ends at the first limit the continuation does not reach. ``progress`` is called
        after each of the ``points`` limits (each is several seconds of IPOPT).

        No point asks :meth:`least_peak` (issue 45): a point reached is a stroke within its
        limit, so no duration's least peak lies above that limit, and a point not reached
        ends the curve either way. Asked ahead in a third process (issue 37), it competed
        with the two curves for two cores and changed no curve of seven compared."""
        if not (isinstance(points, int) and points >= 2):
            raise ParameterError(f"points must be an integer >= 2, got {points!r}")
        tick = progress or (lambda: None)
        fastest = self._fastest(self.force_limit, None, False)
        if fastest is None:
            raise PlanningError(self._unreachable(self.force_limit, None))
        tick()
        top = min(self.worst_peak(fastest), self.force_limit)
        bound = self.lower_bound()
        bottom = bound * (1 + GAP) if bound > 0 else top / 4
        plans = [fastest]
        for limit in (float(v) for v in np.geomspace(top, bottom, points)[1:]):
            torque, last = self._torque, self.problem.last
            try:
                plans.append(self.minimum_time(limit, start=plans[-1], continued=True,
                                               ask_least=False))
            except PlanningError:  # the planner as it was before the point not reached
                self._torque, self.problem.last = torque, last
                break
            finally:
                tick()
        return plans

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
            self._expect(1)
            plan, ok = self._run(WEIGHTS["peak"], (self.t_ref, self.longest),
                                 self.force_limit, "peak", start, True)
            self._advance()
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


def default_duration(planner: ClampPlanner) -> float:
    """Twice the kinematic minimum stroke time, rounded up to 0.1 s."""
    return math.ceil(20 * planner.t_ref) / 10
