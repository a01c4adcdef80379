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
from typing import Any

#: The package's version (pyproject.toml reads it from here).
__version__ = "0.1.0"

#: The public API (everything else in the package is private by convention): its names and
#: the modules they load from.
_EXPORTS = {
    # load or define a mechanism
    "Mechanism": "toggle.params", "HalfDims": "toggle.params", "load_preset": "toggle.params",
    "load_mechanism": "toggle.params", "preset_names": "toggle.params",
    # kinematics and mechanical errors; statics and clamping force
    "clamp_kinematics": "toggle.api", "Kinematics": "toggle.api",
    "mechanical_errors": "toggle.api", "MechanicalErrors": "toggle.api",
    "clamping_force": "toggle.api", "ClampingResult": "toggle.elastics",
    # the errors a caller may catch
    "ParameterError": "toggle.params", "AssemblyError": "toggle.kinematics",
    "ClampingError": "toggle.elastics",
}
__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    """The exported names, from their modules on first use (PEP 562)."""
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'toggle' has no attribute {name!r}")
