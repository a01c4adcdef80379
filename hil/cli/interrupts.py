"""SIGINT and SIGTERM as an exception the run loop can act on, and cannot lose.

CasADi/IPOPT catch KeyboardInterrupt during a solve and return, so a Ctrl-C while
planning would be forgotten and the rig would then move. :class:`SignalGuard` raises
:class:`Interrupted` in the main thread at the first signal *and* remembers it, so
:meth:`SignalGuard.check` raises it again at the next safe point even when a library
swallowed the first. Later signals while the run is being stopped and recorded do not
interrupt that cleanup; they only print that it is under way.

An exception raised by a signal handler in the middle of an import can be lost or turned
into another: numpy's C extension imports datetime from C, which turns it into "ImportError:
PyCapsule_Import could not import module 'datetime'", and some imports clear it and carry
on. So no handler here raises inside an import (casadi, fmpy, matplotlib are imported
lazily, during a run): the signal is noted and delivered again, every REDELIVER s, until the
import is over.

The ``hil`` process gets its handlers from its first line (hil/__init__.py, before
hil.cli's heavy imports): :func:`install_exit_handlers` ends it at once with one line and
130/143 while it starts (nothing is open yet); from :func:`hil.cli.main` on,
:func:`exit_cleanly_on_signals` raises SystemExit instead, so ``with`` blocks close what
they opened (a rig's session); ``hil run`` then replaces both with a :class:`SignalGuard`.
"""

from __future__ import annotations

import signal
import sys
from types import FrameType, TracebackType

from toggle import interrupts
from toggle.interrupts import in_import, redeliver

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):  # noqa: N818 - a signal, like KeyboardInterrupt
    """The user or the system asked the run to stop (SIGINT or SIGTERM)."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(f"interrupted by {signal.Signals(signum).name}")

    @property
    def exit_code(self) -> int:
        """128 + the signal number: 130 for SIGINT, 143 for SIGTERM (shell convention)."""
        return 128 + self.signum


class SignalGuard:
    """Context manager: SIGINT/SIGTERM -> :class:`Interrupted`; restores the handlers."""

    SIGNALS = SIGNALS

    def __init__(self) -> None:
        self.received: int | None = None
        self.shield = False  # set once the run records: signals only get noted, check() acts
        self._deferred = False  # the first signal arrived inside an import: raise after it
        self._previous: dict[int, object] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self._deferred:  # delivered again (or another signal) after one inside an import
            if self.shield:
                self._deferred = False  # check() acts on it
            elif in_import(frame):
                redeliver(signum, lambda: self._deferred)
            else:
                self._deferred = False
                raise Interrupted(self.received)
            return
        if self.received is None:
            self.received = signum
            if not self.shield:
                if in_import(frame):
                    self._deferred = True
                    redeliver(signum, lambda: self._deferred)
                    return
                raise Interrupted(signum)
        print(f"{signal.Signals(signum).name}: stopping the run, please wait",
              file=sys.stderr)

    def check(self) -> None:
        """Raise :class:`Interrupted` if a signal arrived (even one a library swallowed)."""
        if self.received is not None:
            self._deferred = False
            raise Interrupted(self.received)

    def __enter__(self) -> SignalGuard:
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._deferred = False
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _exit_cleanly() -> interrupts.RaiseOutsideImports:
    """SIGINT/SIGTERM -> one line and SystemExit(130/143), never inside an import: it
    unwinds, ports close, sessions end; no traceback."""
    return interrupts.RaiseOutsideImports(lambda signum: SystemExit(128 + signum),
                                          announce="hil")


def install_exit_handlers() -> None:
    """SIGINT and SIGTERM end the process at once with one line and 130/143 (the ``hil``
    process while it starts: imports, before :func:`exit_cleanly_on_signals`)."""
    interrupts.install_exit_handlers("hil")


def exit_cleanly_on_signals() -> None:
    """In the ``hil`` process (start-up handlers installed), once main() runs: SIGINT and
    SIGTERM print one line and raise SystemExit(130/143), so ``with`` blocks close what they
    opened. Elsewhere (main() called in a test's process) nothing changes."""
    interrupts.unwind_on_signals(_exit_cleanly())


def started_as_hil(argv: list[str] | None = None, orig_argv: list[str] | None = None) -> bool:
    """True in the process of the ``hil`` command (:func:`toggle.interrupts.started_as`)."""
    return interrupts.started_as("hil", "hil.cli", argv, orig_argv)
