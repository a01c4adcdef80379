"""Trivial slave for testing the FMU tooling: y = gain * u, x = integral of u dt.

The integral lives in an unregistered attribute (``_position``), so state
rollback is tested on internal state, not only on registered variables.
"""

from pythonfmu import DefaultExperiment

from fmu_src import state as fmu_state
from fmu_src.slave import DeclaredSlave, Var

U_MAX = 1.0  # m/s, the input range the trivial model accepts


class TrivialGain(DeclaredSlave):
    """y = gain * u and x = integral of u, both updated at the end of each step."""

    description = "Trivial test slave of the toggle-clamp FMU tooling"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=1e-3)
    VARIABLES = (
        Var("gain", "parameter", "1", "Gain from u to y", start=2.0, min=0.0, max=1e3),
        Var("u", "input", "m/s", "Input velocity", start=0.0, min=-U_MAX, max=U_MAX),
        # Outputs are computed in doStep (pythonfmu has no other hook), so they
        # do not depend directly on the inputs: depends_on=().
        Var("y", "output", "m/s", "Scaled input, gain * u", depends_on=()),
        Var("x", "output", "m", "Integral of u over time", depends_on=()),
    )

    def initialize(self) -> None:
        if not self.gain >= 0.0:
            raise ValueError(f"parameter gain must be >= 0, got {self.gain}")
        self._position = 0.0
        self._publish()

    def step(self, current_time: float, step_size: float) -> None:
        if not -U_MAX <= self.u <= U_MAX:
            raise ValueError(f"input u = {self.u} m/s is outside [-{U_MAX}, {U_MAX}] m/s")
        self._position += self.u * step_size
        self._publish()

    def model_state(self) -> dict:
        return {"position": getattr(self, "_position", 0.0)}

    def restore_model_state(self, state: object) -> None:
        state = fmu_state.keys(state, frozenset({"position"}), "the model state")
        self._position = fmu_state.finite(state["position"], "position")

    def _publish(self) -> None:
        self.y = self.gain * self.u
        self.x = self._position
