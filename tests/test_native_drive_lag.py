"""The native FMU's drive lag over the whole declared range of drive_bandwidth and
drive_damping: exp(A h) against a 60-digit reference, and the FMU at rest at the corners.

The overdamped lag once overflowed (cosh(q) e^(-zeta w h) taken apart, q above ~710: 20 Hz
with damping 10 at a 1 s step, 1000 Hz with damping 2 at 0.1 s) and rejected every step.
"""

from __future__ import annotations

import math
import subprocess
from decimal import Decimal, localcontext
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract
from fmu_support import close_slave
from native_support import native_build, native_sources

from fmu_src.host import start_slave
from fmu_src.native_build import slave_variables

VARIABLES = {v.name: v for v in slave_variables()[0]}
BANDWIDTHS = (1e-3, 1.0, 20.0, VARIABLES["drive_bandwidth"].max)  # Hz
DAMPINGS = (VARIABLES["drive_damping"].min, 0.5, 0.7, 0.999, 1.0, 1.001, 1.05, 2.0,
            VARIABLES["drive_damping"].max)
STEPS = tuple(10.0**k for k in range(-6, 1))  # s: 1 us .. 1 s
#: |native - reference| on the balanced matrix diag(w, 1) exp(A h) diag(1/w, 1), whose
#: entries are at most ~1 (the worst case measured: 3.3e-14, an undamped 1000 Hz lag over
#: 0.1 s, 628 rad of phase)
TOLERANCE = 1e-13


def _reference(w: float, zeta: float, h: float) -> list[float]:
    """exp(B) for B = w h [[0, 1], [-1, -2 zeta]] (the balanced lag matrix) by scaling
    and squaring with a Taylor series, in 60-digit decimal arithmetic."""
    with localcontext() as ctx:
        ctx.prec = 60
        wh, z = Decimal(w) * Decimal(h), Decimal(zeta)
        b = [[Decimal(0), wh], [-wh, -2 * z * wh]]
        norm = float(wh * (1 + 2 * z))
        s = max(0, math.ceil(math.log2(norm)) + 8) if norm > 0 else 0
        b = [[x / (2**s) for x in row] for row in b]
        mul = lambda p, q: [[sum(p[i][k] * q[k][j] for k in range(2)) for j in range(2)]  # noqa: E731
                            for i in range(2)]
        e = [[Decimal(1), Decimal(0)], [Decimal(0), Decimal(1)]]
        term = [row[:] for row in e]
        for n in range(1, 40):
            term = [[x / n for x in row] for row in mul(term, b)]
            e = [[e[i][j] + term[i][j] for j in range(2)] for i in range(2)]
        for _ in range(s):
            e = mul(e, e)
        return [float(e[0][0]), float(e[0][1]), float(e[1][0]), float(e[1][1])]


def test_the_lag_transition_matches_a_high_precision_reference(tmp_path: Path):
    src = native_sources()
    probe = tmp_path / "probe"
    subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-I", str(src),
                    str(Path(__file__).with_name("native_lag_probe.c")), str(src / "drive_lag.c"),
                    "-o", str(probe), "-lm"], check=True, capture_output=True)
    cases = [(2 * math.pi * bw, zeta, h) for bw in BANDWIDTHS for zeta in DAMPINGS
             for h in STEPS]
    run = subprocess.run([str(probe)], input="".join(f"{w!r} {z!r} {h!r}\n" for w, z, h in cases),
                         capture_output=True, text=True, check=True)
    got = np.array([[float(v) for v in line.split()] for line in run.stdout.splitlines()])
    want = np.array([_reference(*case) for case in cases])
    assert np.isfinite(got).all()
    error = np.abs(got - want).max(axis=1)
    worst = int(np.argmax(error))
    assert error[worst] <= TOLERANCE, (cases[worst], got[worst], want[worst])


@pytest.fixture(scope="module")
def unzipped(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return Path(extract(str(native_build()), str(tmp_path_factory.mktemp("lag"))))


@pytest.mark.parametrize("bandwidth", [VARIABLES["drive_bandwidth"].min, 1e-3,
                                       VARIABLES["drive_bandwidth"].max])
@pytest.mark.parametrize("damping", [VARIABLES["drive_damping"].min,
                                     VARIABLES["drive_damping"].max])
def test_the_fmu_at_rest_accepts_every_step_at_the_corners(unzipped: Path, bandwidth: float,
                                                           damping: float):
    """At the corners of the declared ranges (and the smallest positive bandwidth tried),
    steps of 1 us to 1 s at rest, then a slow move: no rejection, outputs finite and at
    rest exactly where the drive stands. (A staircase, x_cmd held, would ring an undamped
    1000 Hz drive up to its acceleration bound: a held input is a staircase.)"""
    x0 = VARIABLES["x_cmd"].start
    slave, refs = start_slave(unzipped, "corner", {"drive_bandwidth": bandwidth,
                                                   "drive_damping": damping})
    outputs = [refs[n] for n in ("x", "velocity", "acceleration", "input_force")]
    t = 0.0
    for h in (*STEPS, *reversed(STEPS)):
        slave.setReal([refs["x_cmd"]], [x0])
        slave.doStep(t, h)
        t += h
        x, v, a, force = slave.getReal(outputs)
        assert (x, v, a) == (x0, 0.0, 0.0) and math.isfinite(force)
    for k in range(49):  # 1 mm in 49 ms, a ramp: x_cmd at t and its velocity
        slave.setReal([refs["x_cmd"]], [x0 + 1e-3 * k / 49])
        slave.setRealInputDerivatives([refs["x_cmd"]], [1], [1e-3 / 49e-3])
        slave.doStep(t, 1e-3)
        t += 1e-3
        assert all(map(math.isfinite, slave.getReal(outputs)))
    close_slave(slave)
