"""Argument types of the ``hil`` command line: numbers in a range, paths, negative values.

argparse takes ``-0.5e-3`` for an option and ``float`` takes ``nan``; these types and the
argv rewrite make every bad value a one-line usage error (exit 2) naming its option.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from pathlib import Path

#: A negative number as the value of an option (argparse takes '-1e-3' for an option).
_NEGATIVE = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$", re.IGNORECASE)


def join_negative_numbers(argv: list[str]) -> list[str]:
    """``--opt -0.5e-3`` -> ``--opt=-0.5e-3``, so negative values in e-notation parse."""
    out: list[str] = []
    for token in argv:
        if (out and _NEGATIVE.match(token) and out[-1].startswith("--")
                and "=" not in out[-1]):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def number(lo: float, hi: float, what: str) -> Callable[[str], float]:
    """argparse type: a finite float in [lo, hi]."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not (math.isfinite(value) and lo <= value <= hi):
            raise argparse.ArgumentTypeError(f"{what}, got {text!r}")
        return value
    parse.__name__ = "number"
    return parse


PROBABILITY = number(0.0, 1.0, "must be a probability between 0 and 1")
TIME = number(0.0, 1e6, "must be a time >= 0 s")


def path(text: str) -> Path:
    """argparse type: a non-empty path (an empty one would mean the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path")
    return Path(text)
