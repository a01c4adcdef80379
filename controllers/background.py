"""A planning job in a second process: two independent IPOPT runs at once on two cores.

A trade-off's two curves (with the mold, and the dry cycle) and a robust plan's nominal twin
are independent solves, each seconds of IPOPT, which holds the GIL; the second runs in a
child process while the parent computes the first. The child is spawned (a fresh
interpreter: forking a process that holds CasADi, IPOPT and a progress bar's thread is not
safe), loads the compiled problem from the disk cache, and sends back progress ticks and its
result (or its exception) over a pipe.

The parent owns the child: leaving the ``with`` block any way (the result, an error, Ctrl-C)
terminates it, a SIGTERM to a parent that has no handler for it is turned into
:class:`Terminated` for that (instead of ending the parent with the child left running; a
command's own handler, :class:`toggle.interrupts.RaiseOutsideImports`, is kept), and the
kernel kills the child if the parent dies without a word (``PR_SET_PDEATHSIG``, Linux). The
child ignores Ctrl-C from the terminal from its first instruction: it is spawned with SIGINT
blocked (the mask is inherited across exec; a Ctrl-C during the child's seconds of imports
ended it with a traceback, and the parent with exit status 1), then ignores it and unblocks;
the parent decides, and stops it. With one core for this process, or in a job's process
itself (:func:`parallel`), the job runs in this process when its result is asked for, as
before.

The job's ``progress`` is a :class:`controllers.progress.Relay`: called, it counts one step;
as a :class:`~controllers.progress.Progress` (``reporting(progress)``) it counts the
planner's solves. Its counts reach :meth:`Background.ticks` and, where the block runs in a
``reporting()`` context, that progress (count and total: a robust plan's bar counts its
nominal twin's solves too), drained whenever that progress counts.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Callable
from multiprocessing.connection import Connection
from types import FrameType, TracebackType
from typing import Any

from controllers import progress as solves
from controllers.progress import Relay
from toggle.interrupts import Terminated, signals_held

_PR_SET_PDEATHSIG = 1


def parallel() -> bool:
    """Whether a second process would run beside this one: two cores or more for it, and
    this process not a job's itself (a daemonic process has no children)."""
    if multiprocessing.current_process().daemon:
        return False
    return len(os.sched_getaffinity(0)) >= 2 if hasattr(os, "sched_getaffinity") else (
        (os.cpu_count() or 1) >= 2)


def _die_with_parent() -> None:
    """Ask the kernel to kill this process when its parent ends (Linux; elsewhere the
    parent's ``with`` block is the only guard)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)


def _child(conn: Connection, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
    """The child's body: ``fn(*args, progress=tick)``, its result or exception sent back."""
    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # a pending one is dropped
    try:
        result = ("result", fn(*args, progress=Relay(lambda *count: conn.send(count))))
    except Exception as exc:  # noqa: BLE001 - handed to the parent, which raises it
        result = ("error", exc)
    conn.send(result)
    conn.close()


class Background:
    """``fn(*args, progress=callable)`` running in a child process; use as a context
    manager, then :meth:`result`. :meth:`ticks` counts the progress calls seen so far.
    ``here``: in this process when the result is asked (the caller knows the child would
    only repeat this process's work first). ``expected``: the job's solves, announced on
    the parent's progress now with their ``weight`` (so that its ETA covers them from the
    start), the job's own announcements counted against them."""

    def __init__(self, fn: Callable[..., Any], *args: Any, here: bool = False,
                 expected: int = 0, weight: float = 1.0) -> None:
        self._job, self._done = (fn, args), None
        self._ticks = 0
        self._receiving = False
        self._target = solves.current()  # the parent's progress the job's counts join
        self._ahead = expected if self._target is not None else 0
        self._weight = weight
        if self._target is not None:
            if expected:
                self._target.expect(expected, weight)
            self._target.add_source(self._drain)
        self._previous_term: Any = None
        self._process: Any = None
        if parallel() and not here:
            context = multiprocessing.get_context("spawn")
            self._conn, child_end = context.Pipe(duplex=False)
            self._process = context.Process(target=_child, args=(child_end, fn, args),
                                            daemon=True)
            with signals_held(signal.SIGINT):
                self._process.start()
            child_end.close()

    def __enter__(self) -> Background:
        if (threading.current_thread() is threading.main_thread()
                and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL):
            self._previous_term = signal.signal(signal.SIGTERM, self._terminate)
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    @staticmethod
    def _terminate(signum: int, frame: FrameType | None) -> None:
        raise Terminated(f"signal {signum}")

    def _count(self, kind: str, steps: int, weight: float = 1.0) -> None:
        """A count of the job's: its ticks, and the parent's progress."""
        if kind == "tick":
            self._ticks += steps
            if self._target is not None:
                self._target.advance(steps, weight)
        elif self._target is not None:  # in place of what was announced ahead
            taken = min(steps, self._ahead)
            self._ahead -= taken
            self._target.expect(steps, weight)  # first: the total never dips below n
            self._target.expect(-taken, self._weight)

    def _drain(self) -> None:
        self._receive(block=False)

    def _receive(self, block: bool) -> None:
        if self._receiving:  # the parent's progress drains while a count is handed to it
            return
        self._receiving = True
        try:
            self._receive_now(block)
        finally:
            self._receiving = False

    def _receive_now(self, block: bool) -> None:
        if self._process is None:  # in this process, when asked
            if block and self._done is None:
                fn, args = self._job
                relay = Relay(self._count)
                self._done = ("result", fn(*args, progress=relay))
            return
        while self._done is None and (block or self._conn.poll()):
            try:
                kind, *value = self._conn.recv()
            except EOFError:
                self._process.join()
                raise RuntimeError(f"the planning process ended without an answer "
                                   f"(exit status {self._process.exitcode})") from None
            if kind in ("tick", "expect"):
                self._count(kind, *value)
            else:
                self._done = (kind, value[0])

    def ticks(self) -> int:
        """The child's progress calls received so far (without waiting)."""
        self._receive(block=False)
        return self._ticks

    def result(self) -> Any:
        """Wait for the child; its result, or its exception raised here."""
        self._receive(block=True)
        assert self._done is not None
        kind, value = self._done
        if kind == "error":
            raise value
        return value

    def close(self) -> None:
        """Stop the child if it still runs, and restore SIGTERM's handler."""
        if self._target is not None:
            self._target.remove_source(self._drain)
            if self._ahead:
                self._target.expect(-self._ahead, self._weight)  # announced, never came
            self._target = None
        if self._process is not None:
            if self._process.is_alive():
                self._process.terminate()
            self._process.join()
            self._conn.close()
        if self._previous_term is not None:
            signal.signal(signal.SIGTERM, self._previous_term)
            self._previous_term = None
