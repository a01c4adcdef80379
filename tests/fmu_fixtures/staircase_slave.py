"""Staircase setpoint source for testing the clamp FMUs in a master (issue 28).

x = x0 + height * min(floor(t / period), count): the position setpoint a supervisory
FMU sends as a staircase, jumping ``height`` every ``period`` seconds, ``count`` times.
"""

import math

from pythonfmu import DefaultExperiment

from fmu_src.slave import DeclaredSlave, Var


class Staircase(DeclaredSlave):
    """A setpoint that jumps by ``height`` every ``period``, ``count`` times, then holds."""

    description = "Staircase setpoint source of the toggle-clamp tests"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=1e-3)
    ATOMIC_STEP = True
    VARIABLES = (
        Var("x0", "parameter", "m", "First step", start=0.0, min=-1.0, max=1.0),
        Var("height", "parameter", "m", "Height of each jump", start=0.01, min=-1.0, max=1.0),
        Var("period", "parameter", "s", "Time between jumps", start=0.1, min=1e-6, max=100.0),
        Var("count", "parameter", "1", "Number of jumps", start=4.0, min=0.0, max=1e6),
        Var("x", "output", "m", "Setpoint", depends_on=()),
    )

    def initialize(self) -> None:
        self.x = self.x0

    def step(self, current_time: float, step_size: float) -> None:
        jumps = min(math.floor((current_time + step_size) / self.period + 1e-9), self.count)
        self.x = self.x0 + self.height * jumps
