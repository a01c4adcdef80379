"""Clamp design: search the double-toggle family for a designer's targets (issue 29).

Layer: imports :mod:`toggle` and :mod:`controllers`, never :mod:`hil`; neither of those
imports it. ``toggle design`` is its command line (:mod:`toggle_cli.design`). The public
API is :func:`search_designs` and what it returns (:mod:`design.api`, loaded on first use);
every other module here is private by convention.
"""

from __future__ import annotations

from toggle import lazy_exports

_EXPORTS = {"search_designs": ".api", "DesignSearch": ".api",
            "Targets": ".targets"}
__all__ = list(_EXPORTS)

__getattr__ = lazy_exports(__name__, _EXPORTS)
