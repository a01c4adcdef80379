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
from contextlib import contextmanager
from types import FrameType

SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: Interval at which a signal that arrived inside an import is delivered again, s.
REDELIVER = 0.005


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


def in_import(frame: FrameType | None) -> bool:
    """The main thread, interrupted at ``frame``, is importing a module (an exception raised
    there may be swallowed or turned into an ImportError by the C code that imports)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def redeliver(signum: int, still_pending: Callable[[], bool]) -> None:
    """Send ``signum`` to the main thread again after REDELIVER s if ``still_pending()``."""
    def again() -> None:
        if still_pending():
            signal.pthread_kill(threading.main_thread().ident, signum)
    timer = threading.Timer(REDELIVER, again)
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
    finds it, but never inside an import: there it is delivered again after the import.
    ``announce``: the command that says ``interrupted by SIGNAME`` at the first signal."""

    def __init__(self, exception: Callable[[int], BaseException] = signal_exception,
                 announce: str | None = None) -> None:
        self.exception, self.announce = exception, announce
        self.pending: int | None = None

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.pending is None:
            self.pending = signum
            if self.announce is not None:
                say_interrupted(self.announce, signum)
        if in_import(frame):
            redeliver(signum, lambda: self.pending is not None)
            return
        signum, self.pending = self.pending, None
        raise self.exception(signum)


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
    stops them); one that arrives meanwhile is delivered here on leaving.

    multiprocessing's resource tracker, started with the first child process, unblocks
    SIGINT and SIGTERM whatever the mask was: it is started first.
    """
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, set(signums))
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
