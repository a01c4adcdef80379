"""What the host watches in the telemetry stream (docs/rig-protocol-behaviour.md, section 7).

:func:`sample_distance` orders sample indices across the wrap of the MCU's u32 counter,
:class:`SilenceWatchdog` expires when telemetry stops arriving (not counting time in which
the host itself was not running), and :class:`LinkStats` keeps a session's counters and
its arrival-gap histogram. Kept apart from :mod:`hil.link.serial_link` so each can be
tested with an injected clock and no port.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

#: A host thread that wakes this much later than it asked was itself not running (a loaded
#: or paused machine, s): that time is not counted against the rig.
HOST_LATE = 0.025


def sample_distance(sample: int, ref: int) -> int:
    """Signed distance from telemetry index ``ref`` to ``sample`` in RFC 1982 serial-number
    arithmetic on 32 bits: positive when ``sample`` is after ``ref``, also across the wrap
    of the u32 counter (2**32 - 1 -> 0, after 49.7 days of MCU uptime at 1 kHz).

    Exactly 2**31 apart is undefined in RFC 1982; it counts as before (negative).
    """
    d = (sample - ref) & 0xFFFFFFFF
    return d - 0x100000000 if d >= 0x80000000 else d


class SilenceWatchdog:
    """The host's telemetry-silence watchdog (docs/rig-protocol-behaviour.md, section 7).

    It expires ``timeout`` s after its count started: at the last telemetry arrival
    (:meth:`restart`), or when the reader woke more than ``late`` s later than it asked
    (:meth:`woke`). Then the host itself was not running (a loaded or paused machine), so
    the silence it saw is not the rig's: the count restarts at that moment. ``clock`` is
    injectable for tests.
    """

    def __init__(self, timeout: float, clock: Callable[[], float] = time.monotonic,
                 late: float = HOST_LATE) -> None:
        self.timeout, self.clock, self.late = timeout, clock, late
        self.since = clock()  # start of the present count
        self.restarts = 0  # counts restarted by a late wake-up

    def restart(self, now: float | None = None) -> None:
        """Telemetry arrived (or a session opened): the count starts again."""
        self.since = self.clock() if now is None else now

    def woke(self, asked: float, before: float, now: float | None = None) -> bool:
        """The reader asked at ``before`` to wait ``asked`` s and woke at ``now``; True (and
        the count restarted at ``now``) if that was more than ``late`` s later than asked."""
        now = self.clock() if now is None else now
        if now - before <= asked + self.late:
            return False
        self.restarts += 1
        self.since = max(self.since, now)
        return True

    @property
    def deadline(self) -> float:
        """When the watchdog expires unless telemetry arrives, in ``clock`` time."""
        return self.since + self.timeout

    def expired(self, now: float | None = None) -> bool:
        return (self.clock() if now is None else now) >= self.deadline


@dataclass
class LinkStats:
    """Counters and timestamps of a link (times are time.monotonic())."""

    samples: int = 0
    lost_samples: int = 0  # gaps in the telemetry sample index
    duplicates: int = 0  # telemetry frames received twice (dropped)
    queue_dropped: int = 0  # samples dropped because nobody consumed them
    retransmissions: int = 0
    late_attempts: int = 0  # command attempts repeated, uncounted, because the host ran late
    bad_messages: int = 0  # valid frames with an unknown type or wrong length
    last_telemetry_rx: float = 0.0
    max_arrival_gap: float = 0.0  # longest host-side silence between samples, s
    max_clock_excess: float = 0.0  # largest MCU-clock excess between received samples, s
    arrival_gaps_ms: list[int] = dataclasses.field(default_factory=lambda: [0] * 101)
    host_late: int = 0  # times the reader woke more than HOST_LATE after it asked
    failed_at: float | None = None
    stop_sent_at: float | None = None

    def record_gap(self, gap: float) -> None:
        """Count one inter-arrival gap in 1 ms bins (the last bin holds >= 100 ms)."""
        self.max_arrival_gap = max(self.max_arrival_gap, gap)
        self.arrival_gaps_ms[min(int(gap * 1e3), 100)] += 1

    def gap_percentile(self, q: float) -> float:
        """Upper edge (s) of the 1 ms bin holding the q-quantile of the arrival gaps."""
        total = sum(self.arrival_gaps_ms)
        if not total:
            return 0.0
        acc = 0
        for ms, n in enumerate(self.arrival_gaps_ms):
            acc += n
            if acc >= q * total:
                return (ms + 1) * 1e-3
        return self.max_arrival_gap
