"""Best-effort real-time scheduling for the threads whose timing the protocol relies on."""

from __future__ import annotations

import os

REALTIME_PRIORITY = 20  # SCHED_FIFO priority: above ordinary processes, below kernel threads


def set_realtime(priority: int = REALTIME_PRIORITY) -> bool:
    """Make the calling thread SCHED_FIFO; False when the OS does not permit it.

    Used by the emulator's serving thread (a firmware's timer interrupt is hard real time)
    and optionally by the host's reader thread (its 3 ms telemetry watchdog). Both threads
    block in select() between events, so they cannot starve the machine.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError, AttributeError):
        return False
    return True
