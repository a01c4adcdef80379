"""Rig motions that are not experiments: referencing (homing) and moving to a start position.

Both run before a recorded run, at safe speeds, with the encoder check off; neither is
recorded. The reference is the rig's home switch, active while the table is at or
behind the open position x_open (docs/rig-protocol-behaviour.md, section 10): after homing, step
count 0 is x_open and encoder count 0 is the platen there.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import overload

from controllers.limits import DriveLimits
from hil.host.experiment import stroke_positions
from hil.link import protocol as p
from hil.link.errors import RigError
from hil.link.serial_link import SerialLink

#: Speed of the search for the home switch, m/s.
SEARCH_SPEED = 5e-3
#: Speed of the slow pass that latches the switch edge, m/s (0.5 um per period).
FINE_SPEED = 0.5e-3
#: Longest distance searched for the switch, m (the whole stroke and margin).
SEARCH_RANGE = 0.12
#: Default speed of the move to a run's start position, m/s.
APPROACH_SPEED = 5e-3
#: A rig within this distance of the start position does not move to it first, m.
START_TOLERANCE = 10e-6


class HomingError(RigError):
    """The home switch was not found, or the rig faulted while referencing."""


def _unrecorded(link: SerialLink, points: Sequence[tuple[int, int]],
                until: Callable[[p.Telemetry], bool]) -> p.Telemetry | None:
    """Stream ``points`` until ``until(sample)`` holds (that sample) or they end (None).

    On every exit the rig is stopped if it still moves and the rest of the run is read,
    so the link is ready for the next command.
    """
    run = link.run_trajectory(points)
    try:
        return next((tel for tel in run if until(tel)), None)
    finally:
        run.close()  # stops the rig if it is still moving
        link.finish_run()


class ConstantSpeed(Sequence[tuple[int, int]]):
    """The points of a constant-speed move, made as they are streamed.

    A search over SEARCH_RANGE at FINE_SPEED is 240 000 points: built as a list it held the
    host's interpreter lock for hundreds of ms on a loaded machine, and the host's
    heartbeats to the MCU waited behind it (HEARTBEAT_LOST while homing)."""

    def __init__(self, start: int, per_period: float, count: int) -> None:
        self.start, self.per_period, self.count = start, per_period, count

    def __len__(self) -> int:
        return self.count

    def _point(self, i: int) -> tuple[int, int]:
        return self.start + round(self.per_period * (i + 1)), p.NO_CHECK

    @overload
    def __getitem__(self, i: int) -> tuple[int, int]: ...
    @overload
    def __getitem__(self, i: slice) -> list[tuple[int, int]]: ...

    def __getitem__(self, i: int | slice) -> tuple[int, int] | list[tuple[int, int]]:
        if isinstance(i, slice):
            return [self._point(k) for k in range(*i.indices(self.count))]
        if not -self.count <= i < self.count:
            raise IndexError(i)
        return self._point(i % self.count)


def _move_until(link: SerialLink, direction: int, speed: float, switch: bool) -> p.Telemetry:
    """Move at constant ``speed`` (m/s) until the home switch reads ``switch``; then stop.

    Returns the first sample that showed it; the rig is at a standstill afterwards.
    """
    sc = link.scaling
    start = link.status.steps
    per_period = direction * speed * sc.period / sc.step_m
    count = math.ceil(SEARCH_RANGE / (speed * sc.period))
    hit = _unrecorded(link, ConstantSpeed(start, per_period, count),
                       lambda tel: bool(tel.flags & p.TelemetryFlag.HOME_SWITCH) == switch)
    if hit is None:
        state = "active" if switch else "inactive"
        raise HomingError(f"the home switch did not become {state} within "
                          f"{SEARCH_RANGE * 1e3:g} mm")
    return hit


def home(link: SerialLink) -> float:
    """Reference the rig at its home switch; return the distance moved to find it, m.

    Back at SEARCH_SPEED until the switch is active, then forward at FINE_SPEED until it
    releases; that edge becomes step 0 and encoder count 0 (SET_POSITION). The travel
    limits are widened around the unreferenced position for the search (with the session's
    heartbeat timeout, :meth:`SerialLink.config_for`); configure the run's limits
    afterwards.
    """
    sc, status = link.scaling, link.status
    span = round(SEARCH_RANGE / sc.step_m)
    enc_span = round(SEARCH_RANGE / sc.enc_m)
    link.configure(link.config_for(steps_min=status.steps - span, steps_max=status.steps + span,
                                   enc_min=status.enc - enc_span, enc_max=status.enc + enc_span,
                                   following_error_counts=enc_span))
    origin = status.steps
    if not status.flags & p.TelemetryFlag.HOME_SWITCH:
        _move_until(link, -1, SEARCH_SPEED, switch=True)
    edge = _move_until(link, +1, FINE_SPEED, switch=False)
    now = link.status
    link.set_position(now.steps - edge.steps, now.enc - edge.enc)
    return abs(edge.steps - origin) * sc.step_m


def move_to(link: SerialLink, x_target: float, x_origin: float, limits: DriveLimits,
            speed: float = APPROACH_SPEED, check: Callable[[], None] = lambda: None) -> float:
    """Move the table to ``x_target`` (m) with an S-curve at ``speed`` under the drive's
    ``limits``; not recorded.

    ``x_origin`` is the input position at step 0; ``check`` is called every sample and may
    raise to abandon the move (the rig then stops). Returns the distance moved (0 when
    the rig is already within START_TOLERANCE).
    """
    sc = link.scaling
    x_now = sc.x(link.status.steps, x_origin)
    if abs(x_now - x_target) <= START_TOLERANCE:
        return 0.0
    x = stroke_positions(x_now, x_target, speed, sc.period, limits)[1:]
    points = [(sc.steps(float(xi), x_origin), p.NO_CHECK) for xi in x]
    _unrecorded(link, points, lambda _tel: check() or False)
    return abs(x_target - x_now)
