"""ISO 286-1 standard tolerance grades (IT1-IT18, nominal sizes up to 500 mm)."""

from __future__ import annotations

import bisect
import functools
from importlib import resources

from toggle.params import ParameterError, tomllib


@functools.lru_cache(maxsize=1)
def _table() -> tuple[list[float], dict[int, list[float]]]:
    text = (resources.files("toggle") / "data" / "iso286_it.toml").read_text(encoding="utf-8")
    raw = tomllib.loads(text)
    bounds = [b * 1e-3 for b in raw["upper_bounds_mm"]]
    grades = {int(k[2:]): [v * 1e-6 for v in vals] for k, vals in raw["grades_um"].items()}
    return bounds, grades


def it_tolerance(nominal: float, grade: int) -> float:
    """Standard tolerance (the full IT value) of a nominal size, both in metres.

    The size range is "over lower, up to and including upper"; a size of zero
    falls in the first range (0-3 mm).
    """
    bounds, grades = _table()
    if grade not in grades:
        raise ParameterError(f"IT grade must be one of {min(grades)}..{max(grades)}, got {grade}")
    size = abs(nominal)
    if size > bounds[-1] * (1 + 1e-12):
        raise ParameterError(f"ISO 286-1 table covers sizes up to 500 mm, got {size * 1e3:g} mm")
    i = bisect.bisect_left(bounds, size * (1 - 1e-12))
    return grades[grade][i]
