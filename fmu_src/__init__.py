"""The clamp as FMUs: the sources and their builders, on the model (:mod:`toggle`).

``toggle_clamp_fmu.py`` is the pythonfmu slave (a thin shell over :mod:`toggle.plant`),
built by :mod:`fmu_src.build` with :mod:`fmu_src.slave` (its declared variables) and
:mod:`fmu_src.state` (the saved-state format); ``guard/`` is the C guard in front of
pythonfmu's binary (:mod:`fmu_src.guard_build`); ``native/`` is the hand-written C core of
the native FMUs around CasADi's generated model (:mod:`fmu_src.native_build`);
:mod:`fmu_src.host` loads a built FMU in this process. The public API is
:func:`build_fmu` (:mod:`fmu_src.api`); the rest is private by convention. This file imports
only :mod:`toggle`'s light ``__init__`` (the names load on first use): the pythonfmu FMU
bundles the modules its slave uses.
"""

from __future__ import annotations

from toggle import lazy_exports

_EXPORTS = {"build_fmu": ".api", "fmu_file_name": ".api"}
__all__ = list(_EXPORTS)

__getattr__ = lazy_exports(__name__, _EXPORTS)
