"""Motion planning of the clamp stroke: optimal control through the plant model, baselines.

The public API is :func:`plan_stroke` and the :class:`Plan` it returns (loaded on first
use: this file imports nothing heavy); every other module here is private by convention.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {"plan_stroke": "controllers.api", "Plan": "controllers.api",
            "PlanningError": "controllers.plans", "DriveLimits": "controllers.limits"}
__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    """The exported names, from their modules on first use (PEP 562)."""
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'controllers' has no attribute {name!r}")
