"""Setpoints as masters send them (issue 28): a staircase from a second FMU, at 10 ms and
1 ms communication steps, in libcosim, with the clamp FMUs' default parameters.

The staircase climbs chang2021's stroke (x_open to the toggle, 55.0 mm) in 4 jumps of
13.75 mm, one every 0.1 s, then holds. With the default drive_bandwidth (the preset's
drive, 2.27 Hz, docs/fmu.md) both builds follow it at either step; with the ideal drive
(drive_bandwidth = 0) the 1 ms run stops at the first jump (13.75 mm in 1 ms asks for
20.6 m/s), and the message names drive_bandwidth.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from fmu_support import built_fmu, run_libcosim

from toggle.kinematics import stroke_limits
from toggle.plant import configure

X_OPEN, X_TOGGLE = stroke_limits(configure("chang2021").mechanism.lower)
JUMPS, PERIOD, STOP = 4, 0.1, 1.2  # jumps of the staircase, s between them, s simulated

pytestmark = pytest.mark.skipif(pytest.importorskip("libcosimpy") is None, reason="libcosim")


@pytest.fixture(scope="module")
def fmus() -> dict[str, Path]:
    return {"stairs": built_fmu("staircase"), "python": built_fmu("clamp"),
            "native": built_fmu("native")}


def _staircase(fmus: dict[str, Path], build: str, step: float, tmp_path: Path,
               start: tuple = ()) -> dict:
    stairs = [("stairs", "x0", X_OPEN), ("stairs", "height", (X_TOGGLE - X_OPEN) / JUMPS),
              ("stairs", "period", PERIOD), ("stairs", "count", float(JUMPS))]
    return run_libcosim(
        tmp_path, slaves={"stairs": fmus["stairs"], "clamp": fmus[build]},
        observe={"stairs": ["x"], "clamp": ["x", "velocity", "acceleration", "input_force"]},
        initial=[*stairs, ("clamp", "x_cmd", X_OPEN), *start],
        connections=[("stairs", "x", "clamp", "x_cmd")], step_size=step, stop_time=STOP)


@pytest.mark.parametrize("build", ["python", "native"])
@pytest.mark.parametrize("step", [10e-3, 1e-3])
def test_a_staircase_from_another_fmu_completes_with_the_defaults(fmus, build, step,
                                                                  tmp_path: Path):
    result = _staircase(fmus, build, step, tmp_path)
    assert result["ok"]
    stairs, clamp = result["last"]["stairs"], result["last"]["clamp"]
    assert stairs["x"] == pytest.approx(X_TOGGLE, abs=1e-12)
    # settled on the last step 0.8 s after the last jump: e^(-zeta w 0.8 s) of 13.75 mm
    assert clamp["x"] == pytest.approx(X_TOGGLE, abs=1e-5)
    assert abs(clamp["velocity"]) < 1e-3


def test_the_ideal_drive_stops_at_the_first_jump_at_1_ms(fmus, tmp_path: Path):
    result = _staircase(fmus, "python", 1e-3, tmp_path, start=(("clamp", "drive_bandwidth", 0.0),))
    assert not result["ok"]
