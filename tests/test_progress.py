"""The planning's progress (controllers.progress): a count against a total, a tqdm bar on a
terminal after SHOW_AFTER s, a line at least every LINE_EVERY s elsewhere (also while
nothing counts: a build, a compile), an ETA from the solves' own time, and nothing after a
command's error."""

from __future__ import annotations

import io
import time
from contextlib import redirect_stderr, redirect_stdout

import pytest

from controllers import progress
from controllers.progress import LINE_EVERY, SHOW_AFTER, Progress, reporting
from toggle_cli import main


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_the_bar_counts_against_a_growing_total_on_a_terminal(monkeypatch):
    monkeypatch.setattr(progress, "SHOW_AFTER", 0.0)
    out = Terminal()
    with reporting(Progress("planning", file=out)) as bar:
        progress.expect(3)
        progress.advance()
        progress.expect(2)  # learnt later: a continuation's steps
        progress.advance(4)
    text = out.getvalue()
    assert "| 5/5 [" in text
    assert "100%" in text  # the total followed the count (tqdm's meter, left at the end)
    assert (bar.n, bar.total) == (5, 5)
    progress.advance()  # outside reporting(): nothing counts it
    assert bar.n == 5


def test_without_a_terminal_a_line_every_line_every_seconds_at_the_counts():
    out, clock = io.StringIO(), Clock()
    bar = Progress("planning", total=100, file=out, clock=clock, heartbeat=False)
    for _ in range(100):
        clock.now += 1.0
        bar.advance()
    lines = out.getvalue().splitlines()
    # the first once SHOW_AFTER s have passed, then one each LINE_EVERY s: at 2 s, 12 s...
    assert len(lines) == 1 + int((100 - SHOW_AFTER) // LINE_EVERY)
    assert lines[0].startswith("planning:") and f"{int(SHOW_AFTER)}/100" in lines[0]
    assert f"{int(SHOW_AFTER + LINE_EVERY)}/100" in lines[1]
    bar.close()  # the last count, 100, not shown yet
    assert out.getvalue().splitlines()[-1].startswith("planning: 100/100 solves done")


def test_a_long_wait_without_counts_still_prints_a_line_every_line_every_seconds():
    """A compile or one long solve: the heartbeat's beats write the lines, naming the wait;
    no ETA before a solve is done."""
    out, clock = io.StringIO(), Clock()
    bar = Progress("planning", file=out, clock=clock, heartbeat=False)
    bar.doing("compiling the problem")
    for _ in range(60):
        clock.now += 0.5
        bar.beat()
    lines = out.getvalue().splitlines()
    assert len(lines) == 1 + int((30 - SHOW_AFTER) // LINE_EVERY)
    assert all(line.startswith("planning (compiling the problem): 0 solves") for line in lines)
    assert all(line.endswith("ETA ?") for line in lines)
    assert "0:02 elapsed" in lines[0] and f"0:{2 + int(LINE_EVERY):02d} elapsed" in lines[1]


def test_the_eta_is_the_time_per_solve_times_the_solves_left_without_the_named_waits():
    clock = Clock()
    bar = Progress("planning", total=0, file=io.StringIO(), clock=clock, heartbeat=False)
    bar.doing("building the problem")
    clock.now = 30.0  # a build: no solve's time
    bar.doing(None)
    bar.expect(4)
    assert bar.eta() is None
    for _ in range(2):
        clock.now += 5.0
        bar.advance()
    assert bar.eta() == 10.0  # 5 s a solve, two left
    assert "ETA 0:10" in bar.line(clock.now)
    clock.now += 3.0  # into the third solve
    assert bar.eta() == 7.0
    clock.now += 4.0  # the third solve overdue: its end unknown (it said 0:05 before)
    assert bar.eta() is None and "ETA ?" in bar.line(clock.now)
    clock.now += 1.0
    bar.advance()  # 6 s a solve over three
    assert bar.eta() == 6.0
    clock.now += 7.0  # the last solve overdue: unknown, where it said 0:00 until its end
    assert bar.eta() is None


def test_no_eta_during_a_named_wait_after_solves():
    """A cycle's opening stroke is built after the closing stroke's solves: the wait's
    length is unknown, so is the time left (it said ETA 0:00 for 2.7 s); after it, the
    time per solve counts the solves only."""
    clock = Clock()
    bar = Progress("planning", total=0, file=io.StringIO(), clock=clock, heartbeat=False)
    bar.expect(2)
    clock.now += 4.0
    bar.advance()
    assert bar.eta() == 4.0
    bar.doing("building the problem")
    clock.now += 3.0
    assert bar.eta() is None and "(building the problem)" in bar.line(clock.now)
    assert "ETA ?" in bar.line(clock.now)
    bar.doing(None)
    clock.now += 1.0  # one second into the last solve
    assert bar.eta() == 3.0


def test_the_eta_weighs_each_solve_by_its_problems_size():
    """A robust plan's solve (weight 2.4: its rows in thousands) took 2.4 s; its nominal
    twin's four solves (1.6 each) are left: 6.4 s, where counting solves alike said 9.6 s
    (issue 45: the robust plan's ETA of 0:04 with 2.1 s left)."""
    clock = Clock()
    bar = Progress("planning", total=0, file=io.StringIO(), clock=clock, heartbeat=False)
    bar.expect(1, 2.4)
    bar.expect(4, 1.6)
    clock.now += 2.4
    bar.advance(1, 2.4)
    assert (bar.n, bar.total) == (1, 5) and bar.eta() == pytest.approx(6.4)
    clock.now += 1.0
    assert bar.eta() == pytest.approx(5.4)
    clock.now += 0.7  # longer than a solve of 1.6: that one's end is unknown
    assert bar.eta() is None


def test_skipped_solves_leave_the_total_and_not_the_time_per_solve():
    """A best-of-N that skips its late starts (it reached the lower bound) takes them off
    the total: counted as done they made the time per solve look short, and the ETA of the
    solves after them (a robust plan's twin's, a cycle's opening) with it."""
    clock = Clock()
    bar = Progress("planning", total=0, file=io.StringIO(), clock=clock, heartbeat=False)
    bar.expect(4)  # a best of four
    clock.now += 2.0
    bar.advance()
    bar.expect(-3)  # the late starts skipped
    bar.expect(4)  # the next best of four
    assert (bar.n, bar.total) == (1, 5) and bar.eta() == 8.0  # 2 s a solve, four left


def test_a_closed_progress_writes_nothing_more(monkeypatch):
    monkeypatch.setattr(progress, "SHOW_AFTER", 0.0)
    monkeypatch.setattr(progress, "LINE_EVERY", 0.02)
    out = io.StringIO()
    bar = Progress("planning", file=out)
    time.sleep(0.3)
    assert out.getvalue().count("\n") >= 2  # the heartbeat wrote
    bar.close()
    written = out.getvalue()
    time.sleep(0.2)
    assert out.getvalue() == written


def test_a_commands_error_is_the_last_line_of_stderr_after_progress_lines(monkeypatch):
    """A progress a failing path left open (its ``finally`` not reached) is stopped by
    main() before the error is printed."""
    monkeypatch.setattr(progress, "SHOW_AFTER", 0.0)
    monkeypatch.setattr(progress, "LINE_EVERY", 0.02)
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        Progress("planning")  # left open, writing lines every 20 ms
        time.sleep(0.2)
        code = main(["plan", "--break-speed", "0.005"])  # refused: no --cycle
        time.sleep(0.2)
    lines = err.getvalue().splitlines()
    assert code == 2 and len(lines) >= 3
    assert lines[-1].startswith("toggle plan: error: --break-speed")
    assert all(line.startswith("planning: 0 solves") for line in lines[:-1])


def test_nothing_is_shown_when_disabled_or_quick(monkeypatch):
    out, clock = Terminal(), Clock()
    with reporting(Progress("planning", file=out, enabled=False)):
        progress.expect(1)
        progress.advance()
    quick = Progress("planning", file=io.StringIO(), clock=clock)  # under SHOW_AFTER s
    quick.expect(2)
    quick.advance(2)
    assert out.getvalue() == "" and quick.file.getvalue() == ""
