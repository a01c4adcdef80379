"""Best-effort real-time scheduling for the threads whose timing the protocol relies on."""

from __future__ import annotations

import contextlib
import gc
import os
import threading
from collections.abc import Callable

REALTIME_PRIORITY = 20  # SCHED_FIFO priority: above ordinary processes, below kernel threads
#: The nice value of the thread that runs a rig session: its commands and the samples it
#: takes hold the interpreter lock that the SCHED_FIFO reader needs for each heartbeat, so
#: behind a CPU hog at nice 0 the reader waited behind it for 150-400 ms (HEARTBEAT_LOST).
SESSION_NICE = -10


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


def raise_thread_priority(nice: int = SESSION_NICE) -> Callable[[], None]:
    """Give the calling thread the nice value ``nice`` if the OS permits it (root or
    CAP_SYS_NICE; otherwise nothing changes); returns what puts its old value back."""
    tid = threading.get_native_id()
    try:
        old = os.getpriority(os.PRIO_PROCESS, tid)
        if nice >= old:
            return lambda: None
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except (PermissionError, OSError, AttributeError):
        return lambda: None

    def restore() -> None:
        with contextlib.suppress(OSError):  # the thread has ended
            os.setpriority(os.PRIO_PROCESS, tid, old)

    return restore


def freeze_collections() -> Callable[[], None]:
    """Collect now, then keep the objects that exist out of later collections until the
    returned call: a full collection of a large heap holds the interpreter lock for
    hundreds of ms, and the reader's heartbeats wait behind it (a rig session in a test
    process that had run a thousand tests lost its heartbeat at 302 ms of silence). The
    session's own objects are still collected."""
    gc.collect()
    gc.freeze()
    return gc.unfreeze
