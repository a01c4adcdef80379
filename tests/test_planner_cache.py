"""The planner's compiled problem: compiled functions cached under their key (a corrupt
library rebuilt, no compiler: interpreted), what the key covers, which changes reuse the
compiled problem (v_max, friction, the drive, the masses) and the interpreted problem
planning the same stroke."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from planner_support import DURATION, STEEP

from controllers.compiled import code_digest, code_modules, compiled
from controllers.compiled import compiled as _real_compiled
from controllers.limits import drive_limits
from controllers.planner import ClampPlanner, planner_for
from controllers.plans import plan_config
from controllers.stroke_problem import StrokeProblem, neutral, problem_key


def _check_function() -> ca.Function:
    z = ca.SX.sym("z", 3)
    return ca.Function("jet_check", [z], [ca.vertcat(ca.sin(z[0]) * z[1], ca.tanh(z[2]))])


class _Builds:
    """A ``build`` callback for :func:`compiled` that counts its calls."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self) -> list:
        self.calls += 1
        return [(("-O1",), [_check_function()])]


POINT = [0.3, -1.2, 2.0]


def test_compiled_functions_are_cached_under_their_key(tmp_path, monkeypatch):
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(tmp_path))
    build = _Builds()
    (fast,) = compiled("check", "key 1", ["jet_check"], build)
    assert fast.class_name() == "External" and build.calls == 1
    expected = np.asarray(_check_function()(POINT))
    np.testing.assert_allclose(np.asarray(fast(POINT)), expected, rtol=1e-14)
    (again,) = compiled("check", "key 1", ["jet_check"], build)
    assert again.class_name() == "External" and build.calls == 1  # loaded, not built
    compiled("check", "key 2", ["jet_check"], build)  # another key: built and compiled again
    assert build.calls == 2 and len(list(tmp_path.glob("check_*.so"))) == 2


def test_a_corrupt_cached_library_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(tmp_path / "good"))
    compiled("check", "corrupt", ["jet_check"], _Builds())
    (library,) = (tmp_path / "good").glob("check_*.so")
    bad = tmp_path / "bad" / library.name  # the same library in another cache, truncated
    bad.parent.mkdir()
    bad.write_bytes(library.read_bytes()[:1000])  # loading this would crash the process
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(bad.parent))
    build = _Builds()
    (fast,) = compiled("check", "corrupt", ["jet_check"], build)
    assert build.calls == 1 and fast.class_name() == "External"
    (rebuilt,) = bad.parent.glob("check_*.so")  # the truncated file deleted, a whole one built
    assert rebuilt.stat().st_size == library.stat().st_size
    np.testing.assert_allclose(np.asarray(fast(POINT)), np.asarray(_check_function()(POINT)))


def test_without_a_compiler_the_functions_stay_interpreted(tmp_path, monkeypatch):
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    (fn,) = compiled("check", "no compiler", ["jet_check"], _Builds())
    assert fn.class_name() == "SXFunction" and not list(tmp_path.glob("*.so"))
    np.testing.assert_allclose(np.asarray(fn(POINT)), np.asarray(_check_function()(POINT)))


def test_the_cache_key_covers_the_plant_and_the_code_it_uses(tmp_path):
    cfg = plan_config("chang2021").with_(x_contact=None)
    key = problem_key(cfg, 200)
    changed = [problem_key(cfg.with_(velocity_epsilon=2e-4), 200), problem_key(cfg, 100),
               problem_key(cfg.with_(mechanism=cfg.mechanism.with_error("upper", "r5", 1e-4)),
                            200)]
    assert key == problem_key(cfg, 200) and key not in changed
    assert len(set(changed)) == len(changed)
    # mold height, friction, masses and the drive are parameters of the problem, not part of
    # the key
    assert problem_key(cfg.with_(mu=0.06, x_contact=0.04), 200) == key
    assert problem_key(replace(cfg, mechanism=replace(
        cfg.mechanism, dynamics=replace(cfg.dynamics, platen=2.6))), 200) == key
    other_drive = replace(cfg.mechanism.drive, rotor_inertia=1e-4, lead=4e-3,
                          torque_speed=((0.0, 0.2), (40.0, 0.1)))
    assert problem_key(cfg.with_(mechanism=replace(cfg.mechanism, drive=other_drive)),
                        200) == key
    package = tmp_path / "fakepkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "model.py").write_text("from fakepkg import helper\nGAIN = 1.0\n")
    (package / "helper.py").write_text("K = 1\n")
    (package / "plots.py").write_text("STYLE = 1\n")
    import sys
    sys.path.insert(0, str(tmp_path))
    try:
        before = code_digest("fakepkg.model", roots=("fakepkg",))
        (package / "plots.py").write_text("STYLE = 2\n")  # not imported by the model
        assert code_digest("fakepkg.model", roots=("fakepkg",)) == before
        (package / "helper.py").write_text("K = 2\n")  # imported by the model
        assert code_digest("fakepkg.model", roots=("fakepkg",)) != before
    finally:
        sys.path.remove(str(tmp_path))


def test_the_planners_key_covers_the_plant_it_compiles_and_nothing_else():
    """The compiled problem holds the plant's equations: editing toggle/plant.py (or what it
    imports) must recompile; the key once followed only controllers/ and kept a stale plant."""
    used = code_modules("controllers.planner")
    assert {"toggle.plant", "toggle.kinematics", "toggle.statics", "toggle.asymmetry",
            "controllers.profiles"} <= set(used)
    assert not {"toggle.plots", "toggle.press", "toggle_cli", "hil.cli"} & set(used)


def test_the_compiled_problems_key_hashes_its_declaration_not_the_solving():
    """The key's code digest is taken in controllers.stroke_problem (the declaration of the
    compiled functions): it must follow the plant, and editing the solving, the reports or
    the plans (none of them compiled) must not recompile."""
    used = set(code_modules("controllers.stroke_problem"))
    assert {"controllers.stroke_problem", "toggle.plant", "toggle.kinematics",
            "toggle.statics", "toggle.drive"} <= used
    assert not {"controllers.planner", "controllers.stroke_reports", "controllers.plans"} & used


@pytest.fixture(scope="module")
def own_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A disk cache of its own (other processes prune the shared one) holding chang2021's
    8-interval problem and its torque sibling, compiled once (seconds each) for the tests
    that load them: another plant's new problem (no compile allowed), the machine code an
    interpreted problem is compared with."""
    cache = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("TOGGLE_CACHE_DIR", str(cache))
        cfg = plan_config("chang2021")
        ClampPlanner(cfg, drive_limits(cfg.mechanism), intervals=8).problem.with_torque  # noqa: B018
    return cache


def test_a_change_of_v_max_or_mu_reuses_the_compiled_problem(chang_plan, own_cache,
                                                               monkeypatch):
    cfg, limits, planner, plan = chang_plan
    faster = planner_for(cfg, replace(limits, velocity=0.05))
    rougher = planner_for(cfg.with_(mu=cfg.friction * 1.5), limits)
    assert faster.problem is planner.problem and rougher.problem is planner.problem
    quick = faster.solve(DURATION, start=plan)
    assert quick.samples.velocity.max() <= 0.05 * (1 + 1e-3)
    slow = planner_for(cfg.with_(mu=cfg.friction * 1.5), replace(limits, velocity=0.03)
                       ).solve(DURATION, start=plan)
    assert plan.samples.velocity.max() > 0.031  # the new limit binds
    assert slow.samples.velocity.max() <= 0.03 * (1 + 1e-3)
    assert slow.peak_force > plan.peak_force  # more pin friction, more thrust
    # a new process (a new problem) loads the compiled functions another v_max and mu left
    # in the disk cache (its own here: other processes prune the shared one), no compile
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(own_cache))
    monkeypatch.setattr("controllers.stroke_problem.compiled", _no_compile)
    other = ClampPlanner(cfg.with_(mu=cfg.friction * 1.5), replace(limits, velocity=0.03),
                         intervals=8)
    assert other.problem._force.class_name() == "External"
    assert other.solve(DURATION).profile.v.max() <= 0.03 * (1 + 1e-6)  # at the nodes


def test_a_change_of_the_drive_reuses_the_compiled_problem(chang_plan, own_cache, monkeypatch):
    """Rotor inertia, torque-speed curve and masses are parameters of the compiled problem:
    another rotor, curve or platen neither rebuilds the problem in this process nor
    recompiles in a new one; the masses count (a heavier platen, more inertia force)."""
    cfg, limits, planner, plan = chang_plan
    heavy = cfg.with_(mechanism=replace(
        cfg.mechanism, drive=replace(cfg.mechanism.drive, rotor_inertia=2e-4),
        dynamics=replace(cfg.dynamics, platen=25.0)))
    steep = replace(limits, torque=0.03, torque_speed=STEEP)
    assert planner_for(heavy, steep).problem is planner.problem
    heavier = planner_for(heavy, limits).solve(DURATION, start=plan)
    assert heavier.peak_force > plan.peak_force
    np.testing.assert_allclose(  # the planner's compiled force is the plant's
        planner_for(heavy, limits)._force(heavier.samples.position, heavier.samples.velocity,
                                          heavier.samples.acceleration),
        heavier.samples.input_force, rtol=1e-9, atol=1e-9)
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(own_cache))  # both problems, nominal plant
    monkeypatch.setattr("controllers.stroke_problem.compiled", _no_compile)
    other = ClampPlanner(heavy, steep, intervals=8)
    assert other.problem._force.class_name() == "External"
    assert other.solve(DURATION).duration == pytest.approx(DURATION)


def _no_compile(name, key, names, build, machine_code=True, first=0):
    """Stands in for :func:`compiled` where the cache must hold the problem: loads only."""
    assert machine_code
    return _real_compiled(name, key, names, _fail_build, first=first)


def test_a_problem_without_machine_code_is_interpreted_and_plans_alike(chang_plan, tmp_path,
                                                                      own_cache, monkeypatch):
    """A problem without machine code, what a design's duty takes: no compile and
    nothing in the cache (an empty one here), CasADi's own functions, and the plan the
    compiled problem finds."""
    cfg, limits, _, _ = chang_plan
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(tmp_path))
    # its own problem: planner_for's and problem_for's caches keep the other tests' problems
    problem = StrokeProblem(neutral(cfg), 8, machine_code=False)
    interpreted = ClampPlanner(cfg, limits, intervals=8, problem=problem)
    assert problem._force.class_name() == "SXFunction"
    assert problem.with_torque._force.class_name() == "SXFunction"
    assert not problem.with_torque.machine_code  # a sibling of its own, interpreted too
    plan = interpreted.solve(DURATION, warm=False)
    assert list(tmp_path.iterdir()) == []  # nothing compiled, nothing cached
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(own_cache))  # the compiled one, loaded
    compiled_planner = ClampPlanner(cfg, limits, intervals=8)
    assert compiled_planner.problem._force.class_name() == "External"
    machine = compiled_planner.solve(DURATION, warm=False)
    assert machine.peak_force == pytest.approx(plan.peak_force, rel=1e-8)
    np.testing.assert_allclose(machine.profile.v, plan.profile.v, rtol=1e-6, atol=1e-9)


def _fail_build():
    raise AssertionError("the problem was rebuilt: a cache miss")


def test_interpreted_fallback_plans_the_same_stroke(tmp_path, monkeypatch):
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    compiled_planner = ClampPlanner(cfg, limits, intervals=20)
    fast = compiled_planner.solve(DURATION, warm=False)
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    interpreted = ClampPlanner(cfg, limits, intervals=20)
    slow = interpreted.solve(DURATION, warm=False)
    assert compiled_planner.problem._force.class_name() == "External"
    assert interpreted.problem._force.class_name() == "SXFunction"
    assert slow.iterations == fast.iterations
    assert slow.peak_force == pytest.approx(fast.peak_force, rel=1e-9)
