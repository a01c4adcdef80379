"""The clamp as FMUs: the sources and their builders, on the model (:mod:`toggle`).

``toggle_clamp_fmu.py`` is the pythonfmu slave (a thin shell over :mod:`toggle.plant`),
built by :mod:`fmu_src.build` with :mod:`fmu_src.slave` (its declared variables) and
:mod:`fmu_src.state` (the saved-state format); ``guard/`` is the C guard in front of
pythonfmu's binary (:mod:`fmu_src.guard_build`); ``native/`` is the hand-written C core of
the native FMUs around CasADi's generated model (:mod:`fmu_src.native_build`);
:mod:`fmu_src.host` loads a built FMU in this process. This file imports nothing: the
pythonfmu FMU bundles the modules its slave uses.
"""
