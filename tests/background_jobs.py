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
    """Write this process's id, then wait to be stopped."""
    with open(pid_file, "w") as f:
        f.write(str(os.getpid()))
    while True:
        time.sleep(0.05)
