"""Clamp design: search the double-toggle family for a designer's targets (issue 29).

Layer: imports :mod:`toggle` and :mod:`controllers`, never :mod:`hil`; neither of those
imports it. ``toggle design`` is its command line (:mod:`toggle_cli.design`). The public
API is :func:`search_designs` and what it returns (:mod:`design.api`, loaded on first use);
every other module here is private by convention.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {"search_designs": "design.api", "DesignSearch": "design.api",
            "Targets": "design.targets"}
__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    """The exported names, from their modules on first use (PEP 562)."""
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'design' has no attribute {name!r}")
