"""Progress of planning: solves counted against the total the planner knows, on stderr.

The planner announces the IPOPT solves it is about to run (:func:`expect`: a best-of-N's
starts, a minimum-time search's continuation steps, a trade-off's force limits) and counts
each one done (:func:`advance`) on the :class:`Progress` of the current context
(:func:`reporting`); without one both do nothing, so the answers are the same either way.
The count grows while the planner learns more (the continuation's steps are known once
the fastest stroke's peak is), and shrinks by the solves skipped (a best-of-N ending
early on reaching the lower bound: counted as done, they made the time per solve look
short). A wait that is no solve (building the problem's
functions, compiling them) is named while it lasts (:func:`doing`).

What shows, once the work has taken :data:`SHOW_AFTER` s: on a terminal a tqdm bar
(count, total, elapsed, ETA), redrawn every second by a thread even while one solve or a
compile lasts; elsewhere (a log, a pipe) a line every :data:`LINE_EVERY` s (8: at most
10 s apart on a busy machine), at a count at most that often, and the last count at the
end if the lines showed an earlier one. The ETA is the time per solve up to the last count
(the named waits left out: they are no solves) times the solves left, less what the
current solve has taken; none before the first solve is done, during a named wait, nor
while the current solve has run longer than the time per solve. Solves are weighed by
their problem's size (a robust problem's, with its variant's rows, take half as long again
as its nominal twin's: :attr:`controllers.stroke_solver.StrokeSolver.solve_weight`).
Closing a progress (:func:`reporting` does it, also on an error) stops its thread, so that
a command's error, printed after, is the last line of its stderr.

A job in a second process (:mod:`controllers.background`) counts its solves on a
:class:`Relay`, which sends them to the parent; the parent adds them to its own
:class:`Progress` (:meth:`Progress.add_source`: drained at each of its own counts), so
that a robust plan's bar and ETA cover its nominal twin's solves too.
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
import threading
import time
import weakref
from collections.abc import Callable, Iterator
from typing import Any, TextIO

#: Seconds of work before anything shows (issue 37: a bar on anything over 2 s).
SHOW_AFTER = 2.0
#: Seconds between two progress lines where stderr is not a terminal: 8, so that a late
#: wake-up on a busy machine still keeps them within the 10 s issue 45 asks.
LINE_EVERY = 8.0
#: Seconds between two redraws of the bar on a terminal.
REDRAW_EVERY = 1.0

_current: contextvars.ContextVar[Progress | None] = contextvars.ContextVar(
    "progress", default=None)
#: The progresses whose thread runs (:func:`stop_all`).
_live: weakref.WeakSet[Progress] = weakref.WeakSet()


def _clock_text(seconds: float) -> str:
    minutes, secs = divmod(int(round(seconds)), 60)
    return f"{minutes}:{secs:02d}"


class Progress:
    """A count of ``unit`` out of a total that may grow, shown on ``file`` (default stderr)
    as a tqdm bar if it is a terminal, as lines if not; nothing when ``enabled`` is false
    (``--json``). ``heartbeat``: a thread shows it while nothing counts (tests drive
    :meth:`beat` themselves with their ``clock``)."""

    def __init__(self, desc: str, unit: str = "solve", total: int = 0, *,
                 file: TextIO | None = None, enabled: bool = True,
                 clock: Callable[[], float] = time.monotonic, heartbeat: bool = True) -> None:
        self.desc, self.unit, self.n, self.total = desc, unit, 0, total
        self._units = [0.0, float(total)]  # the solves' weights, done and in all
        self.file = file if file is not None else sys.stderr
        self.enabled, self._clock = enabled, clock
        self._start = clock()
        self._last_line: float | None = None
        self._lines_n = 0  # the count the last line showed
        self._activity: str | None = None
        self._aside, self._aside_since = 0.0, None  # time in named waits, and this one's
        self._counted_at: float | None = None  # the last count's time, and the solving's
        self._counted_work = 0.0
        self._bar: Any = None
        self._sources: list[Callable[[], object]] = []
        self._draining = False
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if enabled and self.file.isatty():
            from tqdm import tqdm
            self._bar = tqdm(total=total, desc=desc, unit=unit, delay=SHOW_AFTER,
                             file=self.file, dynamic_ncols=True,
                             bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]")
        if enabled and heartbeat:
            self._thread = threading.Thread(target=self._beating, name="progress",
                                            daemon=True)
            self._thread.start()
            _live.add(self)

    def _beating(self) -> None:
        every = REDRAW_EVERY if self._bar is not None else min(0.5, LINE_EVERY / 4)
        while not self._stop.wait(every):
            self.beat()

    def beat(self) -> None:
        """Show the progress if it is due (the thread's call, every second or so)."""
        with self._lock:
            if self._stop.is_set() and self._thread is not None:
                return
            self._show(due_line=True)

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

    def expect(self, steps: int, weight: float = 1.0) -> None:
        """``steps`` more solves are coming (fewer than announced: negative), each of
        ``weight``: its expected time relative to the others' (the ETA's)."""
        self._drain()
        with self._lock:
            self.total = max(self.total + steps, self.n)
            self._units[1] = max(self._units[1] + steps * weight, self._units[0])
            if self._bar is not None:
                self._bar.total = self.total

    def advance(self, steps: int = 1, weight: float = 1.0) -> None:
        """``steps`` solves of ``weight`` are done."""
        self._drain()
        if steps <= 0:
            return
        with self._lock:
            self.n += steps
            self.total = max(self.total, self.n)
            self._units[0] += steps * weight
            self._units[1] = max(self._units[1], self._units[0])
            self._counted_at = self._clock()
            self._counted_work = self._working(self._counted_at)
            if self._bar is not None:
                self._bar.total = self.total
                self._bar.update(steps)
            self._show(due_line=False)

    def _show(self, due_line: bool) -> None:
        """The bar redrawn, or a line written: at a count (``due_line`` false) if none was
        written for :data:`LINE_EVERY` s, by the heartbeat once one is that overdue."""
        now = self._clock()
        if not self.enabled or now - self._start < SHOW_AFTER:
            return
        if self._bar is not None:
            self._bar.set_description_str(self._label(), refresh=False)
            self._bar.set_postfix_str(self._eta_text(now), refresh=False)
            self._bar.refresh()
            return
        since = None if self._last_line is None else now - self._last_line
        if since is not None and since < LINE_EVERY * (1.0 if not due_line else 0.98):
            return
        self._write_line()

    def _write_line(self) -> None:
        now = self._clock()
        self._last_line, self._lines_n = now, self.n
        self.file.write(self.line(now - self._start) + "\n")
        self.file.flush()

    def _label(self) -> str:
        return f"{self.desc} ({self._activity})" if self._activity else self.desc

    def _working(self, now: float) -> float:
        """Seconds of solving up to ``now``: the time since the start less the named
        waits'."""
        aside = self._aside + (now - self._aside_since if self._aside_since is not None
                               else 0.0)
        return max(now - self._start - aside, 0.0)

    def eta(self, now: float | None = None) -> float | None:
        """Seconds left: the time per unit of weight up to the last count (named waits
        left out) times the weight of the solves left, less the time the current solve
        has run. None before a solve is done, during a named wait (a build, a compile: its
        length is not known; a cycle's opening stroke, built after 4 of 5 solves, showed
        0:00 for its 2.7 s), and while the current solve has run longer than a solve of the
        weight left on average takes: then its end is not known (a last solve's ETA showed
        0:00 for as long as it ran)."""
        now = self._clock() if now is None else now
        done, total = self._units
        if done <= 0 or self._aside_since is not None:  # no solve counted yet, or a wait
            return None
        per_unit = self._counted_work / done
        left = self.total - self.n
        running = self._working(now) - self._counted_work
        if left > 0 and running > per_unit * (total - done) / left:
            return None
        return max((total - done) * per_unit - running, 0.0)

    def _eta_text(self, now: float) -> str:
        eta = self.eta(now)
        return "ETA ?" if eta is None else f"ETA {_clock_text(eta)}"

    def doing(self, activity: str | None) -> None:
        """Name the wait now under way (None: it ended); its time is no solve's."""
        with self._lock:
            now = self._clock()
            if self._aside_since is not None:
                self._aside += now - self._aside_since
            self._activity = activity
            self._aside_since = now if activity else None

    def describe(self, desc: str) -> None:
        """Name the phase now planned (a cycle's closing or opening stroke)."""
        with self._lock:
            self.desc = desc
            if self._bar is not None:
                self._bar.set_description_str(self._label(), refresh=False)

    def line(self, elapsed: float) -> str:
        """The progress as one line: what it does, count, total, elapsed time and ETA."""
        count = f"{self.n}/{self.total} {self.unit}s" if self.total else f"{self.n} {self.unit}s"
        return (f"{self._label()}: {count} done, {_clock_text(elapsed)} elapsed, "
                f"{self._eta_text(self._start + elapsed)}")

    def close(self) -> None:
        """Stop showing (the thread ended before this returns); the bar is left as it is,
        a line written if the last one showed an earlier count."""
        self._stop.set()
        _live.discard(self)
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        with self._lock:
            if self._bar is not None:
                self._bar.close()
                self._bar = None
            elif self._last_line is not None and self._lines_n != self.n:
                self._write_line()  # the count the last line showed is out of date


class Relay(Progress):
    """The progress of a job in another process: each :meth:`expect` and :meth:`advance`
    is sent (``send(kind, steps, weight)``, kind ``"expect"`` or ``"tick"``) to the
    parent, which shows it; nothing is shown here."""

    def __init__(self, send: Callable[[str, int, float], object]) -> None:
        super().__init__("job", enabled=False)
        self._send = send

    def expect(self, steps: int, weight: float = 1.0) -> None:
        super().expect(steps, weight)
        self._send("expect", steps, weight)

    def advance(self, steps: int = 1, weight: float = 1.0) -> None:
        super().advance(steps, weight)
        if steps > 0:
            self._send("tick", steps, weight)

    def __call__(self) -> None:
        """One step done: the plain progress callback of a job that counts its own."""
        self.advance()


def stop_all() -> None:
    """Close every progress still showing: a command's last act before it prints its
    error, which is then the last line of stderr (one left open by a path that raised
    before its ``finally`` would go on writing lines after it)."""
    for progress in list(_live):
        progress.close()


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


def expect(steps: int, weight: float = 1.0) -> None:
    """The planner's: ``steps`` more solves of ``weight`` are coming (on the current
    :class:`Progress`)."""
    if (progress := _current.get()) is not None:
        progress.expect(steps, weight)


def advance(steps: int = 1, weight: float = 1.0) -> None:
    """The planner's: ``steps`` solves of ``weight`` are done."""
    if (progress := _current.get()) is not None:
        progress.advance(steps, weight)


def describe(desc: str) -> None:
    """The planner's caller's: name the phase now planned."""
    if (progress := _current.get()) is not None:
        progress.describe(desc)


@contextlib.contextmanager
def doing(activity: str) -> Iterator[None]:
    """Name a wait that is no solve (a build, a compile) on the current progress while the
    block runs."""
    progress = _current.get()
    if progress is not None:
        progress.doing(activity)
    try:
        yield
    finally:
        if progress is not None:
            progress.doing(None)
