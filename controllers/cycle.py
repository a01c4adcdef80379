"""The whole molding cycle: close, clamp-up, hold, open, eject, and the next close.

A molding machine sells its cycle time: the closing stroke (the approach to mold
contact, then the clamp-up to the locked toggle: one plan of
:class:`controllers.planner.ClampPlanner`), the hold with the mold locked while the
part is injected and cools (a dwell the user gives), the opening (break-away) stroke
back to the open position (``planner_for(..., opening=True)``) and the ejection of the
part at the open position (another dwell), after which the next close begins. A
:class:`MoldingCycle` joins them into one profile sampled every period through the
plant (the dwells at rest: the input force the plant needs there), which
``toggle plan --cycle --out`` writes and ``hil run --profile`` replays, and gives the
motor's duty over it (:mod:`controllers.duty`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.duty import Duty, motor_duty
from controllers.plans import Plan
from controllers.profiles import ProfileSamples, sample_times
from toggle.params import ParameterError
from toggle.plant import PlantConfig, plant_outputs

#: The phases of a cycle, in order.
PHASES = ("close", "clamp_up", "hold", "open", "eject")


def _rest(x: float, duration: float, period: float, cfg: PlantConfig) -> ProfileSamples:
    """A dwell of ``duration`` s at rest at ``x``: its samples after time 0 (none for 0 s)."""
    if duration <= 0:
        return ProfileSamples(*(np.zeros(0),) * 6)
    t = sample_times(duration, period)[1:]
    out = plant_outputs(np.full(t.size, x), 0.0 * t, 0.0 * t, cfg)
    return ProfileSamples(t, np.full(t.size, x), 0.0 * t, 0.0 * t,
                          np.asarray(out.input_force, float) * np.ones_like(t),
                          np.asarray(out.platen_position, float) * np.ones_like(t))


def _join(parts: list[ProfileSamples]) -> ProfileSamples:
    """Samples one after the other, each part's time shifted to follow the last (a
    stroke's first sample, at its time 0, is the last part's end and is left out)."""
    out = [parts[0]]
    for part in (p for p in parts[1:] if p.time.size):  # a dwell of 0 s has no samples
        first = int(part.time[0] == 0.0)
        end = float(out[-1].time[-1])
        out.append(ProfileSamples(*(c[first:] for c in (part.time + end, *part[1:]))))
    return ProfileSamples(*(np.concatenate(c) for c in zip(*out)))


@dataclass(frozen=True)
class MoldingCycle:
    """One machine cycle from the open position back to it: the closing plan, a hold of
    ``hold`` s, the opening plan and an ejection dwell of ``eject`` s."""

    closing: Plan
    opening: Plan
    hold: float
    eject: float

    def __post_init__(self) -> None:
        for name in ("hold", "eject"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= 3600):
                raise ParameterError(f"{name} dwell must be 0 to 3600 s, got {value!r}")

    @property
    def phases(self) -> dict[str, float]:
        """Each phase's duration, s (:data:`PHASES`)."""
        c, o = self.closing, self.opening
        return {"close": c.t_contact, "clamp_up": c.duration - c.t_contact,
                "hold": self.hold, "open": o.duration, "eject": self.eject}

    @property
    def cycle_time(self) -> float:
        return sum(self.phases.values())

    def samples(self, period: float = 1e-3) -> ProfileSamples:
        """The cycle every ``period`` s through the plant (the strokes at 1 ms)."""
        c, o = self.closing, self.opening
        x_final, x_open = float(c.samples.position[-1]), float(o.samples.position[-1])
        return _join([c.samples, _rest(x_final, self.hold, period, c.config),
                      o.samples, _rest(x_open, self.eject, period, o.config.with_(
                          x_contact=None))])

    def duty(self) -> Duty:
        """The motor's duty over the cycle."""
        s = self.samples()
        return motor_duty(s.time, s.velocity, s.acceleration, s.input_force,
                          self.closing.config.mechanism.drive)
