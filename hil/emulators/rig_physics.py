"""The emulated rig's mechanics: the plant model of :mod:`toggle.plant`, not a copy.

Implements :class:`hil.emulators.rig_hardware.RigPhysics` for the emulator: the MCU model
passes the commanded input position once per telemetry period; velocity and
acceleration follow by backward differences over that period, as in the FMU's
ideal drive; the rig's dimensional errors are those of the simulated rig
(:func:`toggle.rig_tables.rig_errors`: its as-built ones plus delta_r8) and its platen's
friction (:func:`toggle.rig_tables.rig_dynamics`); the plant
carries the hysteretic slip state of the friction (:class:`toggle.plant.HystereticPlant`).
The MCU's trajectory clock, not the host's jittery wall clock, is what the drive follows,
so the differences use the nominal period.
Picklable (the model is compiled on first use), so the emulator can run it in
its own process.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from toggle.plant import DriveState, HystereticPlant, configure, follow
from toggle.rig_tables import rig_dynamics, rig_errors


@dataclass
class ClampPhysics:
    """True platen position (m) and input force (N) of the clamp at commanded x."""

    preset: str = "chang2021"
    delta_r8: float = 0.0
    mu: float | None = None
    x_contact: float | None = None
    period: float = 1e-3
    _plant: Any = field(default=None, init=False, repr=False, compare=False)
    _state: DriveState | None = field(default=None, init=False, repr=False, compare=False)

    def __getstate__(self) -> dict[str, Any]:
        return {"preset": self.preset, "delta_r8": self.delta_r8, "mu": self.mu,
                "x_contact": self.x_contact, "period": self.period}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state)

    def __call__(self, x: float, t: float) -> tuple[float, float]:
        if self._plant is None:
            cfg = configure(self.preset, mu=self.mu, x_contact=self.x_contact,
                            errors=rig_errors(self.preset, self.delta_r8),
                            masses=rig_dynamics(self.preset))
            self._plant = HystereticPlant(cfg)
        if self._state is None:
            self._state = DriveState.at_rest(x)
        else:
            self._state = follow(self._state, x, self.period)
        out = self._plant(self._state)
        return out.platen_position, out.input_force
