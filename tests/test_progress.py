"""The planning's progress (controllers.progress): a count against a total, a tqdm bar on a
terminal after SHOW_AFTER s, a line at most every LINE_EVERY s elsewhere."""

from __future__ import annotations

import io

from controllers import progress
from controllers.progress import LINE_EVERY, SHOW_AFTER, Progress, reporting


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


def test_without_a_terminal_one_line_a_minute():
    out, clock = io.StringIO(), Clock()
    bar = Progress("planning", total=100, file=out, clock=clock)
    for _ in range(100):
        clock.now += 1.0
        bar.advance()
    lines = out.getvalue().splitlines()
    # the first once SHOW_AFTER s have passed, then one each LINE_EVERY s: at 2 s and 62 s
    assert len(lines) == 1 + int((100 - SHOW_AFTER) // LINE_EVERY)
    assert lines[0].startswith("planning:") and f"{int(SHOW_AFTER)}/100" in lines[0]
    assert f"{int(SHOW_AFTER + LINE_EVERY)}/100" in lines[1]


def test_nothing_is_shown_when_disabled_or_quick(monkeypatch):
    out, clock = Terminal(), Clock()
    with reporting(Progress("planning", file=out, enabled=False)):
        progress.expect(1)
        progress.advance()
    quick = Progress("planning", file=io.StringIO(), clock=clock)  # under SHOW_AFTER s
    quick.expect(2)
    quick.advance(2)
    assert out.getvalue() == "" and quick.file.getvalue() == ""
