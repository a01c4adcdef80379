"""The host's timeouts, measured from the link at the start of a session (issue 35).

A rig's MCU answers a command within about 4 ms and streams telemetry on a clock that
keeps wall time, so the protocol's timeouts fit it: 20 ms for an ACK, 100 ms of telemetry
silence, 250 ms of heartbeat silence at the MCU (docs/rig-protocol-behaviour.md, sections 6 and 7).
An emulated MCU on a loaded machine (QEMU, a rehosted image) answers in tens or hundreds of
milliseconds and its clock runs slower than the wall clock: each tick it cannot run in
time is lost, and its ``t_us`` reports its own time. The host measures both when it opens
the session (:class:`LinkTiming`: HELLO round trips, and the MCU's clock against the wall
clock over a window of telemetry) and sets its three timeouts from them, never below the
protocol's and never above the bounds here. :class:`AckTimer` then follows the round
trips of the session's commands, so an ACK timeout that a slower link outgrows grows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Bounds of the ACK timeout, s: the protocol's 20 ms, and the most a command may wait
#: per attempt (6 attempts: 3 s before a command fails; a full chunk took 250 ms and more
#: through QEMU's one-byte-at-a-time UART on a machine at load 19).
ACK_TIMEOUT_MIN, ACK_TIMEOUT_MAX = 0.02, 0.5
#: Bounds of the host's telemetry-silence watchdog, s.
WATCHDOG_MIN, WATCHDOG_MAX = 0.1, 1.0
#: Bounds of the MCU's heartbeat watchdog, ms of the MCU's clock (the CONFIG field).
HEARTBEAT_MIN_MS, HEARTBEAT_MAX_MS = 250, 1000
#: An ACK timeout is this many times the longest measured round trip.
ACK_PER_ROUND_TRIP = 4.0
#: The watchdog is at least this many times the longest measured telemetry gap...
WATCHDOG_PER_GAP = 8.0
#: ... and this many ACK timeouts.
WATCHDOG_PER_ACK = 4.0
#: The MCU waits for the host this many times as long as the host waits for the MCU: the
#: two watchdogs judge the same stalls of one loaded machine, and the host's own stalls
#: (a Python process) are the longer.
HEARTBEAT_PER_WATCHDOG = 2.5
#: The slowest MCU clock the host adapts to (MCU seconds per wall second); slower still is
#: taken as this.
SLOWEST_CLOCK = 0.05
#: A measured clock rate above this is the wall clock's: the first and last arrival of a
#: 0.25 s window are each late by a few ms of the host's scheduling.
WALL_CLOCK_RATE = 0.9


def _clamp(value: float, lo: float, hi: float) -> float:
    return min(max(value, lo), hi)


@dataclass(frozen=True)
class LinkTiming:
    """What the host measured when it opened the session, and the timeouts that follow.

    round_trips: HELLO -> HELLO_REPLY, s (each sent once; a HELLO left unanswered counts
    as the time waited for it, a lower bound); clock_rate: the MCU's clock
    (``t_us``) against the host's over the window, MCU s per wall s (1 for a rig, below 1
    for an emulator that runs slow); max_gap: the longest wait between two telemetry
    arrivals in the window, s; window: its length, s; samples: telemetry in it.
    """

    round_trips: tuple[float, ...]
    clock_rate: float
    max_gap: float
    window: float
    samples: int

    @property
    def rate(self) -> float:
        """The clock rate the timeouts use: 1 above WALL_CLOCK_RATE (the measurement's own
        error; an MCU clock that runs fast gets no more time), at least SLOWEST_CLOCK."""
        if self.clock_rate > WALL_CLOCK_RATE:
            return 1.0
        return max(self.clock_rate, SLOWEST_CLOCK)

    @property
    def ack_timeout(self) -> float:
        """ACK_PER_ROUND_TRIP times the longest round trip, within the bounds, s."""
        longest = max(self.round_trips, default=0.0)
        return _clamp(ACK_PER_ROUND_TRIP * longest, ACK_TIMEOUT_MIN, ACK_TIMEOUT_MAX)

    @property
    def telemetry_timeout(self) -> float:
        """The protocol's 100 ms of the MCU's clock (so longer on the wall clock when that
        runs slow), and enough for the gaps and ACK timeouts seen, within the bounds, s."""
        return _clamp(max(WATCHDOG_MIN / self.rate, WATCHDOG_PER_GAP * self.max_gap,
                          WATCHDOG_PER_ACK * self.ack_timeout), WATCHDOG_MIN, WATCHDOG_MAX)

    @property
    def heartbeat_timeout_ms(self) -> int:
        """HEARTBEAT_PER_WATCHDOG times the host's watchdog, within the bounds, ms of the
        MCU's clock (which is at least as long on the wall clock, the clock running no
        faster than it)."""
        ms = HEARTBEAT_PER_WATCHDOG * self.telemetry_timeout * 1e3
        return math.ceil(_clamp(ms, HEARTBEAT_MIN_MS, HEARTBEAT_MAX_MS))

    @property
    def is_nominal(self) -> bool:
        """The measurement gives the protocol's timeouts (a rig on an idle link)."""
        return (self.ack_timeout == ACK_TIMEOUT_MIN and self.telemetry_timeout == WATCHDOG_MIN
                and self.heartbeat_timeout_ms == HEARTBEAT_MIN_MS)

    def describe(self) -> dict[str, object]:
        """The measurement (JSON-ready, SI)."""
        return {"hello_round_trips_s": list(self.round_trips), "mcu_clock_rate": self.clock_rate,
                "telemetry_gap_max_s": self.max_gap, "window_s": self.window,
                "window_samples": self.samples}

    def text(self) -> str:
        """One line: what was measured."""
        return (f"HELLO round trip up to {max(self.round_trips, default=0.0) * 1e3:.1f} ms, "
                f"the MCU's clock at {self.clock_rate * 100:.0f} % of the host's, telemetry "
                f"gaps up to {self.max_gap * 1e3:.1f} ms")


class AckTimer:
    """The ACK timeout of a session: the measured one, raised when commands take longer.

    Each acknowledged command gives a round trip, measured from its first attempt (for a
    command that was retransmitted that is an upper bound: it can only raise the timeout);
    the timeout is the smoothed round trip plus four times its mean deviation (RFC 6298),
    never below the measured timeout and never above ACK_TIMEOUT_MAX.
    """

    def __init__(self, floor: float) -> None:
        self.floor = floor
        self.timeout = floor
        self._srtt: float | None = None
        self._rttvar = 0.0

    def add(self, round_trip: float) -> None:
        """Count one command's round trip, s."""
        if self._srtt is None:
            self._srtt, self._rttvar = round_trip, round_trip / 2
        else:
            self._rttvar = 0.75 * self._rttvar + 0.25 * abs(self._srtt - round_trip)
            self._srtt = 0.875 * self._srtt + 0.125 * round_trip
        self.timeout = _clamp(self._srtt + 4 * self._rttvar, self.floor, ACK_TIMEOUT_MAX)
