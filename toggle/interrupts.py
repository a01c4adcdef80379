"""Ctrl-C and SIGTERM that survive an IPOPT solve.

CasADi checks for signals during IPOPT's iterations: the Python handler runs and raises
(KeyboardInterrupt, or hil's Interrupted), CasADi catches the exception, stops the solve
and returns it as failed (return status NonIpopt_Exception_Thrown). A planner that then
tries another start, or the next force limit, has forgotten the signal: ``toggle plan
--trade-off`` went on for 25 s and exited 0 after a Ctrl-C, and ``toggle synthesize``
reported a failed allocation. Both solve inside :func:`signals_survive`, which
remembers a signal that arrives during the solve and hands it to the program's own
handler again once the solver has returned.

The commands' start-up (``toggle`` and ``hil``): their packages' first lines install
:func:`install_exit_handlers` in the command's own process (:func:`started_as`), so a
Ctrl-C or SIGTERM during the seconds of imports ends it with one line and 130/143 instead
of a KeyboardInterrupt traceback; ``main()`` then installs handlers that unwind. No
handler raises inside an import (:func:`in_import`): numpy's C code turned that exception
into an ImportError traceback, and some imports swallowed it; the signal is delivered
again after the import (:func:`redeliver`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from types import FrameType

SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: Interval at which a signal that arrived inside an import is delivered again, s.
REDELIVER = 0.005


class Terminated(KeyboardInterrupt):
    """SIGTERM turned into an exception (:class:`controllers.background.Background` does,
    so that its child process is stopped): unwinds like Ctrl-C; ``toggle`` exits 143."""


class _InFront:
    """A handler put in front of the program's own (``__wrapped__``) for a block: it notes
    each signal and, if ``passes``, hands it on at once."""

    def __init__(self, wrapped: Callable[[int, FrameType | None], object], passes: bool,
                 received: list[int]) -> None:
        self.__wrapped__, self.passes, self.received = wrapped, passes, received

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        self.received.append(signum)
        if self.passes:
            self.__wrapped__(signum, frame)


@contextmanager
def _in_front(passes: bool, signums: tuple[int, ...] = SIGNALS) -> Iterator[None]:
    """A block during which :class:`_InFront` notes ``signums`` (those with a Python
    handler); after it, the first one noted goes to the program's handler again. Only the
    main thread can set handlers; elsewhere the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous: dict[int, Callable[[int, FrameType | None], object]] = {}
    received: list[int] = []
    for sig in signums:
        handler = signal.getsignal(sig)
        if callable(handler):  # Python's own for SIGINT, or the program's (hil's guard)
            previous[sig] = handler
            signal.signal(sig, _InFront(handler, passes, received))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if received:  # held back, or passed on and swallowed by the block
        previous[received[0]](received[0], None)


def signals_survive() -> AbstractContextManager[None]:
    """Run a block (a CasADi solve) so that SIGINT or SIGTERM, if a Python handler takes
    it, reaches that handler at once (its exception stops IPOPT) and again after the block,
    where the block swallowed the exception."""
    return _in_front(passes=True)


def in_import(frame: FrameType | None) -> bool:
    """The main thread, interrupted at ``frame``, is importing a module (an exception raised
    there may be swallowed or turned into an ImportError by the C code that imports)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def redeliver(signum: int, still_pending: Callable[[], bool],
              after: float = REDELIVER) -> None:
    """Send ``signum`` to the main thread again after ``after`` s if ``still_pending()``."""
    def again() -> None:
        if still_pending():
            signal.pthread_kill(threading.main_thread().ident, signum)
    timer = threading.Timer(after, again)
    timer.daemon = True
    timer.start()


def say_interrupted(command: str, signum: int) -> None:
    """``COMMAND: interrupted by SIGNAME`` on stderr (os.write, not print: the signal may
    have interrupted a print to stderr, a reentrant call)."""
    os.write(2, f"{command}: interrupted by {signal.Signals(signum).name}\n".encode())


class ExitAtOnce:
    """The start-up handler of a command: one line, then exit 130/143 at once (nothing is
    open yet, nothing to flush)."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __call__(self, signum: int, _frame: FrameType | None) -> None:
        say_interrupted(self.command, signum)
        os._exit(128 + signum)


def install_exit_handlers(command: str) -> None:
    """SIGINT and SIGTERM end the process at once with one line and 130/143 (the command's
    process while it starts: imports, before its main() installs handlers that unwind)."""
    handler = ExitAtOnce(command)
    for sig in SIGNALS:
        signal.signal(sig, handler)


def exiting_at_once() -> bool:
    """The start-up handlers are installed (this is the command's own process)."""
    return all(isinstance(signal.getsignal(sig), ExitAtOnce) for sig in SIGNALS)


def started_as(command: str, module: str, argv: list[str] | None = None,
               orig_argv: list[str] | None = None) -> bool:
    """True in the process of ``command``: its console script (``sys.argv[0]`` is
    .../COMMAND) or ``python -m MODULE`` (``sys.orig_argv``: while a ``-m`` package is
    being imported, ``sys.argv[0]`` is only '-m'); never in a process that multiprocessing
    spawned from it (a planning or Dask process, which its parent stops silently)."""
    argv = sys.argv if argv is None else argv
    orig = getattr(sys, "orig_argv", []) if orig_argv is None else orig_argv
    if "--multiprocessing-fork" in orig:
        return False  # a process multiprocessing spawned: it copied its parent's sys.argv
    scripts = (command, f"{command}.exe", f"{command}-script.py")
    if argv and os.path.basename(argv[0]) in scripts:
        return True
    args = iter(orig[1:])
    for arg in args:
        if arg == "-m":
            return next(args, None) == module
        if arg.startswith("-m"):
            return arg == f"-m{module}"
        if arg in ("-X", "-W"):
            next(args, None)  # the option's value
        elif arg.startswith("-c") or not arg.startswith("-"):
            return False  # -c or a script: not the command
    return False


def signal_exception(signum: int) -> KeyboardInterrupt:
    """What a signal raises in ``toggle``: KeyboardInterrupt, :class:`Terminated` for
    SIGTERM."""
    return Terminated(f"signal {signum}") if signum == signal.SIGTERM else KeyboardInterrupt()


class RaiseOutsideImports:
    """A signal handler: ``exception(signum)`` raised in the main thread where the signal
    finds it, never inside an import (there it is delivered again after the import), and
    kept until the program takes it (:meth:`taken`).

    Kept, because a raised exception can be lost: CasADi's Python type checks (``size1``,
    ``DM_from_csc``, ``vertcat``), called from its C code while a problem is built, clear
    any exception their Python raised, so a Ctrl-C 0.8 s into ``toggle plan`` was dropped
    there and the plan finished with exit 0. Until it is taken the signal is delivered
    again every KEEP s, and raised again unless its exception is on its way up (being
    handled by a ``finally`` or an ``__exit__`` on the stack): cleanup is not interrupted.
    ``announce``: the command that says ``interrupted by SIGNAME`` at the first signal."""

    #: Interval at which a raised signal not yet taken is delivered again, s.
    KEEP = 0.05

    def __init__(self, exception: Callable[[int], BaseException] = signal_exception,
                 announce: str | None = None) -> None:
        self.exception, self.announce = exception, announce
        self.pending: int | None = None  # to be raised (the first signal, or one lost)
        self.raised: BaseException | None = None  # raised and not yet taken
        self.signum = 0  # the signal raised
        self._late = False  # a delivery again was sent: it may arrive after taken()

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        late, self._late = self._late, False
        if self.pending is None:
            if self.raised is None and late:
                return  # delivered again just as the program took the signal
            if self.raised is None:
                self.pending = signum
                if self.announce is not None:
                    say_interrupted(self.announce, signum)
            elif self._on_its_way():
                redeliver(signum, self._again, self.KEEP)
                return
            else:  # swallowed on the way: raised again
                self.pending = self.signum
        if in_import(frame):
            redeliver(signum, lambda: self.pending is not None)
            return
        self.signum, self.pending = self.pending, None
        self.raised = self.exception(self.signum)
        redeliver(self.signum, self._again, self.KEEP)
        raise self.raised

    def _again(self) -> bool:
        """Whether to deliver the raised signal again: not taken yet, and this handler still
        the signal's (one that replaced it, or the one restored, decides)."""
        self._late = self.raised is not None and self._in_charge()
        return self._late

    def _in_charge(self) -> bool:
        """This handler takes the signal: it is installed, or behind a block's
        :class:`_InFront`."""
        return _handler(self.signum) is self

    def _on_its_way(self) -> bool:
        """The raised exception (or one it caused) is being handled on the stack."""
        seen = sys.exc_info()[1]
        while seen is not None:
            if seen is self.raised:
                return True
            seen = seen.__cause__ or seen.__context__
        return False

    def taken(self) -> None:
        """The program has the signal (its exception reached the command's last handler):
        no more deliveries."""
        self.pending = self.raised = None


def _handler(signum: int) -> object:
    """The program's handler of ``signum``: the installed one, or the one behind a block's
    :class:`_InFront`."""
    handler = signal.getsignal(signum)
    while isinstance(handler, _InFront):
        handler = handler.__wrapped__
    return handler


def _keeping() -> list[RaiseOutsideImports]:
    """The program's :class:`RaiseOutsideImports` handlers (SIGINT's, SIGTERM's)."""
    return [h for h in map(_handler, SIGNALS) if isinstance(h, RaiseOutsideImports)]


def signal_taken() -> None:
    """The command's process has acted on the signal that is being raised (its main()
    caught the exception): the installed :class:`RaiseOutsideImports` stops delivering it."""
    for handler in _keeping():
        handler.taken()


def raised_signal() -> BaseException | None:
    """The exception of a signal that the installed :class:`RaiseOutsideImports` raised and
    the program has not taken: it was swallowed on the way, and what the code that
    swallowed it did next (CasADi: "Wrong number or type of arguments") is its
    consequence, not an error of its own."""
    return next((h.raised for h in _keeping() if h.raised is not None), None)


def unwind_on_signals(handler: RaiseOutsideImports | None = None) -> None:
    """In a command's process (start-up handlers installed), once its main() runs: SIGINT
    and SIGTERM raise through ``handler`` (default: KeyboardInterrupt and
    :class:`Terminated`, which ``toggle``'s main() turns into one line and 130/143) after
    ``with`` blocks closed what they opened. Elsewhere (main() called in a test's process)
    nothing changes."""
    if exiting_at_once():
        handler = handler or RaiseOutsideImports()
        for sig in SIGNALS:
            signal.signal(sig, handler)


@contextmanager
def signals_held(*signums: int) -> Iterator[None]:
    """``signums`` held back from this thread, and from the threads and processes started
    meanwhile, which inherit the mask and keep it: a planning process, a Dask cluster's
    event loop and workers then never see the terminal's Ctrl-C (their parent decides, and
    stops them); one that arrives meanwhile is delivered here on leaving (also one that a
    thread which does not block it received: Python runs its handler in this thread).

    multiprocessing's resource tracker, started with the first child process, unblocks
    SIGINT and SIGTERM whatever the mask was: it is started first.
    """
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    with _in_front(passes=False, signums=signums):  # a thread that does not block it got it
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, set(signums))
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)
