"""toggle-clamp: one plant model of the double-toggle mold/die clamp.

The clamp's equations live in :mod:`toggle.kinematics` (positions), with the
mechanical-error analysis in :mod:`toggle.tolerance`. Everything else (FMU,
planner, HIL rig emulator, studies) calls them; none re-derives them.

This file imports nothing heavy: the ``toggle`` command gets its SIGINT/SIGTERM handlers
here, before numpy and the rest load (a Ctrl-C in its first second printed a
KeyboardInterrupt traceback), and ``hil`` imports :mod:`toggle.interrupts` before its own
handlers are installed. The names below load their modules on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from toggle.interrupts import install_exit_handlers, started_as

if started_as("toggle", "toggle.cli"):
    install_exit_handlers("toggle")

_EXPORTS = {"AssemblyError": "toggle.kinematics", "HalfDims": "toggle.params",
            "Mechanism": "toggle.params", "load_mechanism": "toggle.params",
            "load_preset": "toggle.params"}
__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    """The exported names, from their modules on first use (PEP 562)."""
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'toggle' has no attribute {name!r}")
