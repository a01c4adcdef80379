"""A cold first answer (issue 45): on an empty compile cache a plan uses the functions
interpreted and a detached, niced process compiles them for the next run; the answers are
the same to the printed digits. Every test has its own TOGGLE_CACHE_DIR."""

from __future__ import annotations

import contextlib
import fcntl
import io
import os
import re
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from controllers import compiled as compiled_module
from controllers.compiled import (
    FIRST_ANSWER_MAX_BYTES,
    compile_in_background,
    compiled,
    first_answer_flags,
)
from controllers.planner import planner_for
from controllers.stroke_problem import StrokeProblem, problem_for
from toggle.params import ParameterError
from toggle_cli import main


def _check_units() -> list:
    z = ca.SX.sym("z", 3)
    return [(("-O1",), [ca.Function("jet_check", [z], [ca.sin(z[0]) * z[1] + z[2]])])]


def _wait_for_library(cache: Path, name: str, timeout: float = 300.0) -> None:
    """Until the detached compiles are done: the library ``name`` there, no job left."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if list(cache.glob(f"{name}_*.so")) and not list(cache.glob("job-*.json")):
            return
        time.sleep(0.2)
    pytest.fail(f"no library compiled in {timeout:g} s: {sorted(p.name for p in cache.iterdir())}")


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "cache"
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(folder))
    monkeypatch.setenv("TOGGLE_COMPILE", "background")
    return folder


def test_a_miss_is_interpreted_now_and_compiled_detached_for_the_next_time(cache):
    (first,) = compiled("check", "key", ["jet_check"], _check_units)
    assert first.class_name() == "SXFunction"  # not waiting for the compiler
    _wait_for_library(cache, "check")
    (second,) = compiled("check", "key", ["jet_check"], lambda: pytest.fail("rebuilt"))
    assert second.class_name() == "External"
    point = [0.3, -1.2, 2.0]
    np.testing.assert_allclose(np.asarray(second(point)), np.asarray(first(point)), rtol=1e-15)


def test_the_compile_is_detached_niced_and_not_started_twice(cache):
    job = compiled_module._job_path("check", "held")  # noqa: SLF001
    cache.mkdir()
    with open(job, "w") as held:  # a compile of the same library on its way
        fcntl.flock(held, fcntl.LOCK_EX)
        assert compile_in_background("check", "held", ["jet_check"], _check_units()) is None
    pid = compile_in_background("check", "other", ["jet_check"], _check_units())
    assert pid is not None
    try:
        assert os.getsid(pid) == pid  # its own session: no terminal's Ctrl-C reaches it
        niced = min(19, os.nice(0) + 1)
        end = time.monotonic() + 10.0  # until nice(1) has set it and exec'd Python
        while os.getpriority(os.PRIO_PROCESS, pid) < niced and time.monotonic() < end:
            time.sleep(0.01)
        assert os.getpriority(os.PRIO_PROCESS, pid) >= niced
        # and its session's scheduling group (Linux autogroups: nice counts only within
        # one; without this the compile took a third of two cores beside a CPU hog)
        group = Path(f"/proc/{pid}/autogroup")
        if Path("/proc/self/autogroup").exists():
            assert group.read_text().split()[-1] == "19"
    finally:
        _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    assert len(list(cache.glob("check_*.so"))) == 1 and job.exists()


def test_a_bad_compile_mode_is_refused(monkeypatch):
    monkeypatch.setenv("TOGGLE_COMPILE", "later")
    with pytest.raises(ParameterError, match="TOGGLE_COMPILE"):
        compiled("check", "key", ["jet_check"], _check_units)


def _plan_text(argv: list[str]) -> str:
    """``toggle plan`` in this process on fresh planners (the shared ones forgotten), its
    output without the solve's time (the one figure a compile changes)."""
    planner_for.cache_clear()
    problem_for.cache_clear()
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        assert main(argv) == 0, err.getvalue()
    return re.sub(r"solved in [0-9.]+ ms", "solved in - ms", out.getvalue())


def test_interpreted_and_compiled_plans_print_the_same_answer(cache, monkeypatch):
    argv = ["plan", "--intervals", "24"]
    first = compiled_module._first_answer  # noqa: SLF001
    answered = []

    def spied(*args, **kwargs):
        functions = first(*args, **kwargs)
        answered.append(sorted({fn.class_name() for fn in functions}))
        return functions

    monkeypatch.setattr(compiled_module, "_first_answer", spied)
    try:
        cold = _plan_text(argv)
        # a first answer: the jets compiled (External), the rest interpreted
        assert answered == [["External", "SXFunction"]]
        assert list(cache.glob("stroke-first_*.so"))
        _wait_for_library(cache, "stroke")
        monkeypatch.setattr(StrokeProblem, "_symbolic",
                            lambda self: pytest.fail("built again: not loaded compiled"))
        warm = _plan_text(argv)
    finally:
        planner_for.cache_clear()
        problem_for.cache_clear()
    assert "fixed duration stroke" in cold and "solved in - ms" in cold
    assert warm == cold


def test_without_a_compiler_no_job_is_written(cache, monkeypatch, tmp_path):
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    (fn,) = compiled("check", "key", ["jet_check"], _check_units)
    assert fn.class_name() == "SXFunction" and not cache.exists()


def test_a_first_answer_compiles_a_large_unit_without_optimisation(tmp_path):
    """gcc -O1 on a robust plan's erroneous clamp (1.4 MB of jets) took 10 s of CPU
    against 1.7 s at -O0: a first answer compiles so large a unit at -O0."""
    small, large = tmp_path / "small.c", tmp_path / "large.c"
    small.write_bytes(b" " * FIRST_ANSWER_MAX_BYTES)
    large.write_bytes(b" " * (FIRST_ANSWER_MAX_BYTES + 1))
    assert first_answer_flags(("-O1",), small) == ("-O1",)
    assert first_answer_flags(("-O1", "-fno-math-errno"), large) == ("-fno-math-errno", "-O0")


def test_a_robust_problem_loads_its_nominal_clamps_jets_compiled_for_the_nominal_one(cache):
    """The jets are compiled one unit per plant, each keyed by its plant alone: the
    nominal problem's first answer compiles the nominal clamp's; the robust problem (the
    nominal clamp and an erroneous one) compiles only the erroneous clamp's."""
    from controllers.plans import plan_config
    from toggle.plant import with_errors

    cfg = plan_config("chang2021")
    erroneous = cfg.with_(mechanism=with_errors(cfg.mechanism, {"r8": 0.25e-3})[0])
    compiles = []
    real = compiled_module.shared_library

    def counted(name, key, *args, **kwargs):
        found = compiled_module.cached_library(name, key, lambda library: library)
        compiles.append((name, found is None))
        return real(name, key, *args, **kwargs)

    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(compiled_module, "shared_library", counted)
            nominal = problem_for(cfg, 8)
            robust = problem_for(cfg, 8, (erroneous,))
    finally:
        problem_for.cache_clear()
    assert compiles == [("stroke-first", True), ("stroke-first", False),
                        ("stroke-first", True)]
    assert not nominal.loaded and not robust.loaded  # the models interpreted meanwhile
    assert len(list(cache.glob("stroke-first_*.so"))) == 2
