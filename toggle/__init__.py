"""toggle-clamp: one plant model of the double-toggle mold/die clamp.

The clamp's equations live in :mod:`toggle.kinematics` (positions), with the
mechanical-error analysis in :mod:`toggle.tolerance`. Everything else (FMU,
planner, HIL rig emulator, studies) calls them; none re-derives them.

This file imports nothing heavy (the ``toggle`` and ``hil`` commands install their
SIGINT/SIGTERM handlers from :mod:`toggle.interrupts` before numpy and the rest load): the
names below load their modules on first use.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

#: The package's version (pyproject.toml reads it from here).
__version__ = "0.1.0"

#: The public API (everything else in the package is private by convention): its names and
#: the modules they load from.
_EXPORTS = {
    # load or define a mechanism
    "Mechanism": ".params", "HalfDims": ".params", "load_preset": ".params",
    "load_mechanism": ".params", "preset_names": ".params",
    # kinematics and mechanical errors; statics and clamping force
    "clamp_kinematics": ".api", "Kinematics": ".api",
    "mechanical_errors": ".api", "MechanicalErrors": ".api",
    "clamping_force": ".api", "ClampingResult": ".elastics",
    # the errors a caller may catch
    "ParameterError": ".params", "AssemblyError": ".kinematics", "ClampingError": ".elastics",
}
__all__ = list(_EXPORTS)


def lazy_exports(package: str, exports: dict[str, str]) -> Callable[[str], Any]:
    """A package's module ``__getattr__`` (PEP 562) that loads each exported name from its
    module (relative to the package, so that a bundled copy loads its own) on first use:
    every package's ``__init__`` exports its public API this way and stays cheap to import.
    """
    def exported(name: str) -> Any:
        if name in exports:
            return getattr(importlib.import_module(exports[name], package), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return exported


__getattr__ = lazy_exports(__name__, _EXPORTS)
