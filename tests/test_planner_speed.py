"""The planner's speed-ups of issues 37 and 45 give the answers the plain way gives: the
trade-off without a least peak, the robust plan's nominal twin given the bound. (Their
times are benchmarks/bench_planner_speed.py's and bench_cold_plans.py's, not asserted.)"""

from __future__ import annotations

import numpy as np
import pytest

from controllers import background, planner
from controllers.limits import drive_limits
from controllers.planner import ClampPlanner, best_plan, planner_for
from controllers.plans import NO_PROTECTION, plan_config
from controllers.stroke_solver import GAP
from toggle.plant import with_errors

INTERVALS = 60  # a coarse problem: the same code paths in a fraction of the time


def _fresh(cfg, limits):
    """A planner with no history (planner_for keeps its planners, their problem its last
    plan): both ways start from the same state."""
    fresh = planner_for.__wrapped__(cfg, limits, intervals=INTERVALS)
    fresh.problem.last = None
    return fresh


def test_a_trade_off_asks_no_least_peak_and_each_point_is_within_its_limit(monkeypatch):
    """Issue 45: the trade-off's points ask no least peak (it ran in a third process beside
    the two curves and refused nothing: a point reached is a stroke within its limit). The
    least peak fails the test if asked; the curve has all three points, each within its
    limit on the 1 ms samples."""
    monkeypatch.setattr(ClampPlanner, "least_peak", lambda self: pytest.fail("least peak"))
    cfg = plan_config("chang2021")
    fresh = _fresh(cfg, drive_limits(cfg.mechanism))
    plans = fresh.trade_off(3)
    assert len(plans) == 3
    top = min(fresh.worst_peak(plans[0]), fresh.force_limit)
    limits = np.geomspace(top, fresh.lower_bound() * (1 + GAP), 3)[1:]
    for plan, limit in zip(plans[1:], limits, strict=True):
        assert fresh.worst_peak(plan) <= limit * (1 + 1e-6)
    assert plans[-1].duration > plans[1].duration > plans[0].duration


def test_a_trade_off_point_not_reached_ends_the_curve_the_planner_as_before(monkeypatch):
    """The second limit's continuation fails (after it switched the torque rows on and left
    a plan of its own as the latest): the curve is the first two plans, the planner's
    torque rows and latest plan those of before that point."""
    cfg = plan_config("chang2021")
    fresh = _fresh(cfg, drive_limits(cfg.mechanism))
    reach = ClampPlanner.minimum_time
    calls, before = [], {}

    def failing(self, limit, **kw):
        calls.append(limit)
        if len(calls) == 2:
            before.update(torque=self._torque, last=self.problem.last)
            self._torque, self.problem.last = True, calls  # a failed continuation's mess
            raise planner.PlanningError("not reached")
        return reach(self, limit, **kw)

    monkeypatch.setattr(ClampPlanner, "minimum_time", failing)
    plans = fresh.trade_off(4)
    assert len(plans) == 2 and len(calls) == 2
    assert fresh._torque is before["torque"] is False
    assert fresh.problem.last is before["last"] is plans[1]


def test_the_nominal_twin_given_the_bound_plans_the_same():
    """A robust plan hands its bound to the nominal twin (best_plan): it is the nominal
    plant's bound (the robust planner's plant is the nominal one), and the twin's plan with
    it given is the plan without."""
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    erroneous = cfg.with_(mechanism=with_errors(cfg.mechanism, {"r8": 0.25e-3})[0])
    robust = planner_for(cfg, limits, intervals=INTERVALS, variants=(erroneous,), scales=(1.1,))
    nominal = _fresh(cfg, limits)
    assert robust.lower_bound() == nominal.lower_bound()
    plain = nominal.best(3.0)
    planner_for.cache_clear()  # best_plan's planner: a fresh one, given the bound
    nominal.problem.last = None
    given = best_plan(cfg, limits, nominal.contact_speed, INTERVALS, NO_PROTECTION, 3.0,
                      "peak", bound=robust.lower_bound())
    assert planner_for(cfg, limits, nominal.contact_speed, INTERVALS,
                       protection=NO_PROTECTION)._bound == robust.lower_bound()
    assert given.peak_force == pytest.approx(plain.peak_force, rel=1e-4)
    assert given.duration == pytest.approx(plain.duration, rel=1e-4)


@pytest.mark.parametrize("parallel", [False, True])
def test_a_robust_plans_bar_counts_its_nominal_twins_solves(monkeypatch, capsys, parallel):
    """Issue 37: ``toggle plan --robust`` on a terminal counts the nominal twin's starts
    (in the second process, or here on one core) with its own: the bar ends at a total of
    both best plans' starts, reached (the robust plan's own, counted here, and at least
    the twin's first; issue 45: a robust peak has no late starts)."""
    import io
    import re

    from controllers import progress
    from toggle_cli import main

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(progress, "SHOW_AFTER", 0.0)
    monkeypatch.setattr(background, "parallel", lambda: parallel)
    err = Terminal()
    monkeypatch.setattr("sys.stderr", err)
    run, robust_runs = ClampPlanner._run, []

    def solved(self, *args, **kwargs):
        robust_runs.extend([1] if self.variants else [])
        return run(self, *args, **kwargs)

    monkeypatch.setattr(ClampPlanner, "_run", solved)
    assert main(["plan", "--delta-r8", "0.25e-3", "--robust", "--intervals",
                 str(INTERVALS)]) == 0
    counts = re.findall(r"\| (\d+)/(\d+) \[", err.getvalue())
    done, total = map(int, counts[-1])
    assert 1 <= len(robust_runs) <= 2  # the polynomial start (and a warm one)
    assert done == total >= len(robust_runs) + 1
    capsys.readouterr()
