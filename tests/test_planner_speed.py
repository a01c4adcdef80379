"""The planner's speed-ups of issue 37 give the answers the plain way gives: the
trade-off's least peak computed ahead in a second process, the robust plan's nominal twin
given the bound. (Their times are benchmarks/bench_planner_speed.py's, not asserted.)"""

from __future__ import annotations

import pytest

from controllers import background, planner
from controllers.limits import drive_limits
from controllers.planner import ClampPlanner, best_plan, planner_for
from controllers.plans import NO_PROTECTION, plan_config
from toggle.plant import with_errors

INTERVALS = 60  # a coarse problem: the same code paths in a fraction of the time


def _fresh(cfg, limits):
    """A planner with no history (planner_for keeps its planners, their problem its last
    plan): both ways start from the same state."""
    fresh = planner_for.__wrapped__(cfg, limits, intervals=INTERVALS)
    fresh.problem.last = None
    return fresh


@pytest.mark.parametrize("margin", [planner._LEAST_MARGIN, -0.01])
def test_the_trade_off_with_the_least_peak_ahead_is_the_plain_one(monkeypatch, margin):
    """``ClampPlanner.trade_off`` with the least peak computed in a second process while the
    points go on: the same points (peaks and times to 1e-4 relative, in fact the same
    solves), the same least peak, the planner left in the same state (its latest plan, its
    torque rows), as when it is computed in this process where a point first asks for it.
    With a margin of -1 % the least peak refuses the last point: the curve ends there both
    ways."""
    monkeypatch.setattr(planner, "_LEAST_MARGIN", margin)
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    answers = {}
    for ahead in (False, True):
        monkeypatch.setattr(background, "parallel", lambda ahead=ahead: ahead)
        fresh = _fresh(cfg, limits)
        plans = fresh.trade_off(3)
        answers[ahead] = ([(p.peak_force, p.duration) for p in plans],
                          fresh.worst_peak(fresh._least), fresh._torque,
                          fresh.problem.last and fresh.problem.last.duration)
    assert len(answers[True][0]) == len(answers[False][0]) == (3 if margin > 0 else 2)
    for (peak, time), (plain_peak, plain_time) in zip(answers[True][0], answers[False][0]):
        assert peak == pytest.approx(plain_peak, rel=1e-4)
        assert time == pytest.approx(plain_time, rel=1e-4)
    assert answers[True][1] == pytest.approx(answers[False][1], rel=1e-4)
    assert answers[True][2:] == answers[False][2:]


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
