"""Shared fixtures and hypothesis strategies; how the suite shares two cores.

Under pytest-xdist (``-n 2``, the default in pyproject.toml) two tests run at a time, but
never a computing test beside one that runs against real time (marked ``real_time``: the
emulated rig at 1 kHz, signals sent after a delay, a cluster of processes with timeouts):
those two kinds take turns, each kind two at a time (two rig tests take about one core).
A test that must have the machine to itself (marked ``alone``: QEMU emulating the MCU, the
soak test that brings its own load, and the tests whose processes compute on both cores
against a clock: ``toggle plan``'s two planning processes signalled, a Dask cluster with
timeouts; beside a rig test they starved its rig) runs alone. The computing tests run
first, then the real-time ones, then those alone, so that the turns change rarely.
"""

from __future__ import annotations

import fcntl
import math
import os
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings
from hypothesis import strategies as st

from toggle.params import HalfDims, Mechanism, load_preset

# the suite compiles a planner's functions before it plans (as a benchmark does), not in a
# detached process that would outlive the run; tests/test_cold_plan.py tries the default
os.environ.setdefault("TOGGLE_COMPILE", "wait")

# no per-example deadline: a second worker or a compile of the planner's problem on the
# other core makes an example's time meaningless (the tests bound their work by counts)
settings.register_profile("suite", deadline=None)
settings.load_profile("suite")

KINDS = ("computing", "real_time", "alone")


def pytest_report_header() -> list[str]:
    """The hil tests that run ``hil run`` without --preset expect chang2021's FMU in the build
    folder; ``hil run`` takes the preset of the FMU ``toggle build-fmu`` wrote there last
    (issue 47), so another preset's FMU there is named at the start."""
    from fmu_src.build import build_folder, fmu_preset

    built = fmu_preset(build_folder() / "ToggleClamp.fmu")
    if built in (None, "chang2021"):
        return []
    return [f"warning: {build_folder() / 'ToggleClamp.fmu'} is built for {built}: hil run "
            "without --preset runs it, and the hil tests expect chang2021's; restore it "
            "with `toggle build-fmu --force`"]


def _kind(item: pytest.Item) -> str:
    """A test's kind: its (or its module's) mark ``real_time`` or ``alone``, else
    computing."""
    return next((kind for kind in ("alone", "real_time") if item.get_closest_marker(kind)),
                "computing")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The computing tests first, then the real-time ones, then those alone (each kind in
    its collected order)."""
    items.sort(key=lambda item: KINDS.index(_kind(item)))


def _flock(path: Path, mode: int) -> int:
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    fcntl.flock(fd, mode)
    return fd


@pytest.fixture(autouse=True)
def _turns(request: pytest.FixtureRequest,
           tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Under pytest-xdist: a test holds its kind's lock shared while it runs, having waited
    (behind the gate, which orders the entries) until no test of the other kind runs; a test
    alone holds the gate and both kinds' locks. The kernel drops a dead worker's locks."""
    if "PYTEST_XDIST_WORKER" not in os.environ:  # one process: nothing runs beside it
        yield
        return
    shared = tmp_path_factory.getbasetemp().parent  # the run's, above each worker's own
    lock = {name: shared / f"turns.{name}" for name in ("gate", *KINDS[:2])}
    kind = _kind(request.node)
    gate = _flock(lock["gate"], fcntl.LOCK_EX)
    if kind == "alone":
        held = [gate, *(_flock(lock[k], fcntl.LOCK_EX) for k in KINDS[:2])]
    else:
        held = [_flock(lock[kind], fcntl.LOCK_SH)]
        other = KINDS[1 - KINDS.index(kind)]
        os.close(_flock(lock[other], fcntl.LOCK_EX))  # waits for the other kind to end
        os.close(gate)
    try:
        yield
    finally:
        for fd in reversed(held):
            os.close(fd)


@pytest.fixture(scope="session")
def elf() -> Path:
    """The NUCLEO-F446RE image (built once, cached in build/) for the rehosted-board tests;
    skipped where the cross toolchain is missing."""
    from hil.emulators.firmware_qemu import qemu_available
    from hil.emulators.rehost.nucleo import build_nucleo_image

    missing = qemu_available(need_qemu=False)
    if missing:
        pytest.skip(f"needs the Debian packages: {' '.join(missing)}")
    return build_nucleo_image()


@pytest.fixture(scope="session")
def chang() -> Mechanism:
    return load_preset("chang2021")


@pytest.fixture(scope="session")
def chang_plan() -> tuple[Any, Any, Any, Any]:
    """chang2021's plan configuration, drive limits, planner and a cold-started plan of
    tests/planner_support.py's DURATION: the planner's tests (tests/test_planner*.py)
    start from it. Once a session: planner_for keeps the planner for every test anyway."""
    from planner_support import DURATION

    from controllers.limits import drive_limits
    from controllers.planner import planner_for
    from controllers.plans import plan_config

    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    planner = planner_for(cfg, limits)
    return cfg, limits, planner, planner.solve(DURATION, warm=False)


class SwallowedSigint:
    """A Ctrl-C as CasADi meets it during IPOPT: the handler's exception is raised and
    caught, and the solve returns as failed."""

    def __init__(self) -> None:
        self.solves = 0

    def __call__(self, caught: type[BaseException] = KeyboardInterrupt) -> None:
        """Send SIGINT and swallow what the handler raises (``caught``)."""
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.1)  # the handler runs here
        except caught:
            pass

    def before(self, solver: Callable[..., Any]) -> Callable[..., Any]:
        """``solver`` (a CasADi nlpsol) with a swallowed Ctrl-C before each solve, counted."""
        def solve(**kw: Any) -> Any:
            self.solves += 1
            self()
            return solver(**kw)
        solve.stats = solver.stats  # type: ignore[attr-defined]
        return solve


@pytest.fixture
def swallowed_sigint() -> Iterator[SwallowedSigint]:
    """:class:`SwallowedSigint`, with Python's own SIGINT handler installed meanwhile, as in
    a terminal (a shell's background job ignores SIGINT, and Python then installs none)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield SwallowedSigint()
    signal.signal(signal.SIGINT, previous)


@st.composite
def half_dims(draw: st.DrawFn) -> HalfDims:
    """Geometries near the chang2021 half: every length within +-12 %, any offset sign."""
    base = load_preset("chang2021").lower
    f = lambda: draw(st.floats(0.88, 1.12))  # noqa: E731
    r4a, r4b = base.r4a * f(), base.r4b * f()
    # keep link 4 a proper triangle by drawing its angle rather than r4c
    alpha = base.alpha4 * f()
    r4c = math.sqrt(r4a**2 + r4b**2 - 2 * r4a * r4b * math.cos(alpha))
    return HalfDims(r1=base.r1 * f(), r2=base.r2 * f(), r3=base.r3 * f(), r4a=r4a, r4b=r4b,
                    r4c=r4c, r5=base.r5 * f(), e=draw(st.floats(-0.02, 0.02)))
