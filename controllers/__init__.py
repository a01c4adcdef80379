"""Motion planning of the clamp stroke: optimal control through the plant model, baselines.

The public API is :func:`plan_stroke` and the :class:`Plan` it returns (loaded on first
use: this file imports nothing heavy); every other module here is private by convention.
"""

from __future__ import annotations

from toggle import lazy_exports

_EXPORTS = {"plan_stroke": ".api", "Plan": ".api",
            "PlanningError": ".plans", "DriveLimits": ".limits"}
__all__ = list(_EXPORTS)

__getattr__ = lazy_exports(__name__, _EXPORTS)
