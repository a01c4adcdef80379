"""JSON text that every JSON reader accepts: numbers that are not finite written null.

Python's ``json`` writes NaN and Infinity, which JSON does not have (a browser's or jq's
parser refuses them). Where the project has such a value it means "none" or "without
limit" (a film law turned off, h_s = inf; a standard error not identified), which the
field's documentation says; null carries that.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def finite_or_none(value: Any) -> Any:
    """``value`` with every non-finite float inside (dicts, lists, tuples) made None."""
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def json_text(payload: Any, indent: int | None = 2) -> str:
    """``payload`` as strict JSON (non-finite numbers null)."""
    return json.dumps(finite_or_none(payload), indent=indent, allow_nan=False)
