"""The rig's raw units in SI (docs/rig-protocol.md, HELLO_REPLY and CONFIG).

:class:`Scaling` converts step counts, encoder counts and raw load-cell readings to metres
and newtons, from the MCU's HELLO_REPLY and the load-cell calibration in use, so no caller
re-derives the conversion.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Scaling:
    """Raw units of the rig -> SI, from HELLO_REPLY and the load-cell calibration in use."""

    step_m: float
    enc_m: float
    load_offset: int
    load_gain_n: float
    period: float

    def x(self, steps: int, origin: float = 0.0) -> float:
        """Input-link position (m) of a step count; ``origin`` is the position at step 0."""
        return origin + steps * self.step_m

    def steps(self, x: float, origin: float = 0.0) -> int:
        """Nearest step count of input-link position ``x`` (m)."""
        return round((x - origin) / self.step_m)

    def platen(self, enc: int, origin: float = 0.0) -> float:
        """Platen position (m) of an encoder count; ``origin`` is the position at count 0."""
        return origin + enc * self.enc_m

    def counts(self, platen: float, origin: float = 0.0) -> int:
        """Nearest encoder count of platen position ``platen`` (m)."""
        return round((platen - origin) / self.enc_m)

    def force(self, load_raw: int) -> float:
        """Input force (N) of a raw load-cell reading."""
        return (load_raw - self.load_offset) * self.load_gain_n

