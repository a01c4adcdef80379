"""toggle-clamp: one plant model of the double-toggle mold/die clamp.

The clamp's equations live in :mod:`toggle.kinematics` (positions), with the
mechanical-error analysis in :mod:`toggle.tolerance`. Everything else (FMU,
planner, HIL rig emulator, studies) calls them; none re-derives them.
"""

from toggle.kinematics import AssemblyError
from toggle.params import HalfDims, Mechanism, load_mechanism, load_preset

__all__ = ["AssemblyError", "HalfDims", "Mechanism", "load_mechanism", "load_preset"]
