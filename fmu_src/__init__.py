"""The clamp as FMUs: the sources and their builders, on the model (:mod:`toggle`).

``toggle_clamp_fmu.py`` is the pythonfmu slave (a thin shell over :mod:`toggle.plant`),
built by :mod:`fmu_src.build` with :mod:`fmu_src.slave` (its declared variables) and
:mod:`fmu_src.state` (the saved-state format); ``guard/`` is the C guard in front of
pythonfmu's binary (:mod:`fmu_src.guard_build`); ``native/`` is the hand-written C core of
the native FMUs around CasADi's generated model (:mod:`fmu_src.native_build`);
:mod:`fmu_src.host` loads a built FMU in this process. The public API is
:func:`build_fmu` (:mod:`fmu_src.api`); the rest is private by convention. This file imports
nothing on import (the name loads on first use): the pythonfmu FMU bundles the modules its
slave uses.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {"build_fmu": "fmu_src.api", "fmu_file_name": "fmu_src.api"}
__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    """The exported names, from their modules on first use (PEP 562)."""
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'fmu_src' has no attribute {name!r}")
