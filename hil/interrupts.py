"""SIGINT and SIGTERM as an exception the run loop can act on, and cannot lose.

CasADi/IPOPT catch KeyboardInterrupt during a solve and return, so a Ctrl-C while
planning would be forgotten and the rig would then move. :class:`SignalGuard` raises
:class:`Interrupted` in the main thread at the first signal *and* remembers it, so
:meth:`SignalGuard.check` raises it again at the next safe point even when a library
swallowed the first. Later signals while the run is being stopped and recorded do not
interrupt that cleanup; they only print that it is under way.
"""

from __future__ import annotations

import signal
import sys
from types import FrameType, TracebackType


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

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: int | None = None
        self.shield = False  # set once the run records: signals only get noted, check() acts
        self._previous: dict[int, object] = {}

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        if self.received is None:
            self.received = signum
            if not self.shield:
                raise Interrupted(signum)
        print(f"{signal.Signals(signum).name}: stopping the run, please wait",
              file=sys.stderr)

    def check(self) -> None:
        """Raise :class:`Interrupted` if a signal arrived (even one a library swallowed)."""
        if self.received is not None:
            raise Interrupted(self.received)

    def __enter__(self) -> SignalGuard:
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
