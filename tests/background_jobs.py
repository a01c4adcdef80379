"""Jobs for tests/test_background.py, importable by the spawned child (by name)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable


def count(n: int, progress: Callable[[], object]) -> dict[str, int]:
    """Tick ``n`` times, then answer with the process that did it."""
    for _ in range(n):
        progress()
    return {"n": n, "pid": os.getpid()}


def refuse(message: str, progress: Callable[[], object]) -> None:
    raise ValueError(message)


def sleep_forever(pid_file: str, progress: Callable[[], object]) -> None:
    """Write this process's id (whole: the file appears with it, so a test that waits for
    the file never reads it empty), then wait to be stopped."""
    with open(f"{pid_file}.tmp", "w") as f:
        f.write(str(os.getpid()))
    os.replace(f"{pid_file}.tmp", pid_file)
    while True:
        time.sleep(0.05)


def solves(n: int, progress) -> int:
    """Announce ``n`` solves and count each, as a planner does (``reporting(progress)``)."""
    from controllers import progress as counted
    from controllers.progress import reporting

    with reporting(progress):
        counted.expect(n)
        for _ in range(n):
            counted.advance()
    return n


def nested(progress: Callable[[], object]) -> bool:
    """Whether a job's own Background would run a second process (it must not: a daemonic
    process has no children)."""
    from controllers import background

    return background.parallel()
