"""Progress of planning: solves counted against the total the planner knows, on stderr.

The planner announces the IPOPT solves it is about to run (:func:`expect`: a best-of-N's
starts, a minimum-time search's continuation steps, a trade-off's force limits) and counts
each one done (:func:`advance`) on the :class:`Progress` of the current context
(:func:`reporting`); without one both do nothing, so the answers are the same either way.
The count grows while the planner learns more (the continuation's steps are known once
the fastest stroke's peak is), and a skipped solve (a best-of-N ending early on reaching
the lower bound) counts as done.

On a terminal the bar (tqdm: count, total, rate and ETA) shows once the work has taken
:data:`SHOW_AFTER` s; elsewhere (a log, a pipe) the same line is written, ended, at most
once every :data:`LINE_EVERY` s. The bar moves between solves: one long solve (a first
plan's compilation) shows at its end.

A job in a second process (:mod:`controllers.background`) counts its solves on a
:class:`Relay`, which sends them to the parent; the parent adds them to its own
:class:`Progress` (:meth:`Progress.add_source`: drained at each of its own counts), so
that a robust plan's bar and ETA cover its nominal twin's solves too.
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any, TextIO

#: Seconds of work before anything shows (issue 37: a bar on anything over 2 s).
SHOW_AFTER = 2.0
#: Seconds between two progress lines where stderr is not a terminal.
LINE_EVERY = 60.0

_current: contextvars.ContextVar[Progress | None] = contextvars.ContextVar(
    "progress", default=None)


class Progress:
    """A count of ``unit`` out of a total that may grow, shown on ``file`` (default stderr)
    as a tqdm bar if it is a terminal, as a line at most every :data:`LINE_EVERY` s if
    not; nothing when ``enabled`` is false (``--json``)."""

    def __init__(self, desc: str, unit: str = "solve", total: int = 0, *,
                 file: TextIO | None = None, enabled: bool = True,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.desc, self.unit, self.n, self.total = desc, unit, 0, total
        self.file = file if file is not None else sys.stderr
        self.enabled, self._clock = enabled, clock
        self._start = self._last_line = clock()
        self._bar: Any = None
        self._sources: list[Callable[[], object]] = []
        self._draining = False
        if enabled and self.file.isatty():
            from tqdm import tqdm
            self._bar = tqdm(total=total, desc=desc, unit=unit, delay=SHOW_AFTER,
                             file=self.file, dynamic_ncols=True)

    def add_source(self, drain: Callable[[], object]) -> None:
        """Call ``drain`` at each count here: it brings in the counts of a job in another
        process (:meth:`expect` and :meth:`advance` with that job's steps)."""
        self._sources.append(drain)

    def remove_source(self, drain: Callable[[], object]) -> None:
        if drain in self._sources:
            self._sources.remove(drain)

    def _drain(self) -> None:
        if self._draining:  # a source's own counts come back here
            return
        self._draining = True
        try:
            for drain in list(self._sources):
                drain()
        finally:
            self._draining = False

    def expect(self, steps: int) -> None:
        """``steps`` more solves are coming."""
        self._drain()
        self.total += steps
        if self._bar is not None:
            self._bar.total = self.total

    def advance(self, steps: int = 1) -> None:
        """``steps`` solves are done (or skipped)."""
        self._drain()
        if steps <= 0:
            return
        self.n += steps
        self.total = max(self.total, self.n)
        if self._bar is not None:
            self._bar.total = self.total
            self._bar.update(steps)
            return
        now = self._clock()
        if self.enabled and now - self._start >= SHOW_AFTER and now - self._last_line >= (
                LINE_EVERY if self._last_line > self._start else 0.0):
            self._last_line = now
            self.file.write(self.line(now - self._start) + "\n")
            self.file.flush()

    def describe(self, desc: str) -> None:
        """Name the phase now planned (a cycle's closing or opening stroke)."""
        self.desc = desc
        if self._bar is not None:
            self._bar.set_description_str(desc, refresh=False)

    def line(self, elapsed: float) -> str:
        """The progress as one line: count, total, elapsed time and ETA."""
        from tqdm import tqdm
        return tqdm.format_meter(self.n, self.total, elapsed, prefix=self.desc, unit=self.unit,
                                 ncols=80)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


class Relay(Progress):
    """The progress of a job in another process: each :meth:`expect` and :meth:`advance`
    is sent (``send(kind, steps)``, kind ``"expect"`` or ``"tick"``) to the parent, which
    shows it; nothing is shown here."""

    def __init__(self, send: Callable[[str, int], object]) -> None:
        super().__init__("job", enabled=False)
        self._send = send

    def expect(self, steps: int) -> None:
        super().expect(steps)
        self._send("expect", steps)

    def advance(self, steps: int = 1) -> None:
        super().advance(steps)
        if steps > 0:
            self._send("tick", steps)

    def __call__(self) -> None:
        """One step done: the plain progress callback of a job that counts its own."""
        self.advance()


def current() -> Progress | None:
    """The :class:`Progress` of the current context (:func:`reporting`), if any."""
    return _current.get()


@contextlib.contextmanager
def reporting(progress: Progress) -> Iterator[Progress]:
    """Count the planner's solves in this context on ``progress``; closed at the end."""
    token = _current.set(progress)
    try:
        yield progress
    finally:
        _current.reset(token)
        progress.close()


def expect(steps: int) -> None:
    """The planner's: ``steps`` more solves are coming (on the current :class:`Progress`)."""
    if (progress := _current.get()) is not None:
        progress.expect(steps)


def advance(steps: int = 1) -> None:
    """The planner's: ``steps`` solves are done or skipped."""
    if (progress := _current.get()) is not None:
        progress.advance(steps)


def describe(desc: str) -> None:
    """The planner's caller's: name the phase now planned."""
    if (progress := _current.get()) is not None:
        progress.describe(desc)
