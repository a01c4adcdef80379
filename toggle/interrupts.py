"""Ctrl-C and SIGTERM that survive an IPOPT solve.

CasADi checks for signals during IPOPT's iterations: the Python handler runs and raises
(KeyboardInterrupt, or hil's Interrupted), CasADi catches the exception, stops the solve
and returns it as failed (return status NonIpopt_Exception_Thrown). A planner that then
tries another start, or the next force limit, has forgotten the signal: ``toggle plan
--trade-off`` went on for 25 s and exited 0 after a Ctrl-C, and ``toggle synthesize``
reported a failed allocation. Both solve inside :func:`signals_survive`, which
remembers a signal that arrives during the solve and hands it to the program's own
handler again once the solver has returned.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Terminated(KeyboardInterrupt):
    """SIGTERM turned into an exception (:class:`controllers.background.Background` does,
    so that its child process is stopped): unwinds like Ctrl-C; ``toggle`` exits 143."""


@contextmanager
def signals_survive() -> Iterator[None]:
    """Run a block (a CasADi solve) so that SIGINT or SIGTERM, if a Python handler takes
    it, reaches that handler after the block even when the block swallowed the exception.

    Only the main thread can set handlers; elsewhere the block runs as it is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous: dict[int, Callable[[int, FrameType | None], object]] = {}
    received: list[int] = []

    def note(signum: int, frame: FrameType | None) -> None:
        received.append(signum)
        previous[signum](signum, frame)  # raises what the program expects, to stop IPOPT

    for sig in SIGNALS:
        handler = signal.getsignal(sig)
        if callable(handler):  # Python's own for SIGINT, or the program's (hil's guard)
            previous[sig] = handler
            signal.signal(sig, note)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if received:  # the block returned: the exception was swallowed on the way
        previous[received[0]](received[0], None)
