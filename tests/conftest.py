"""Shared fixtures and hypothesis strategies."""

from __future__ import annotations

import math
import os
import signal
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from hypothesis import strategies as st

from toggle.params import HalfDims, Mechanism, load_preset


@pytest.fixture(scope="session")
def chang() -> Mechanism:
    return load_preset("chang2021")


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
