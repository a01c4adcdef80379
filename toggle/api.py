"""The public API of the model: kinematics, mechanical errors, statics and clamping force.

Thin wrappers over `toggle.kinematics`, `toggle.tolerance` and
`toggle.elastics` (the one source of the equations): they take a whole
`toggle.params.Mechanism` (or a preset's name) and return small named results.
Import them from `toggle` (``from toggle import clamp_kinematics``); the modules behind
them are private by convention and may change.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from toggle.kinematics import half_motion, stroke_limits
from toggle.params import Mechanism, ParameterError, load_preset
from toggle.tolerance import AsymmetryReport, MonteCarloResult, asymmetry, it_tolerances
from toggle.tolerance import monte_carlo as _monte_carlo

if TYPE_CHECKING:  # the statics load scipy.optimize (0.3 s): only clamping_force needs them
    from toggle.elastics import ClampingResult


@dataclass(frozen=True)
class Kinematics:
    """The motion of one half over its stroke (SI: m, rad).

    Attributes:
        x_open: Crosshead position with the clamp open, m.
        x_toggle: Crosshead position at the toggle (the links collinear), m.
        stroke: Crosshead stroke ``x_toggle - x_open``, m.
        x: Crosshead positions evaluated, m.
        platen: Output (platen) position L at ``x``, m.
        velocity_ratio: dL/dx at ``x`` (platen speed over crosshead speed), 1.
        mechanical_advantage: Ideal force ratio 1/(dL/dx), 1 (``inf`` at the toggle).
    """

    x_open: float
    x_toggle: float
    stroke: float
    x: np.ndarray
    platen: np.ndarray
    velocity_ratio: np.ndarray
    mechanical_advantage: np.ndarray


@dataclass(frozen=True)
class MechanicalErrors:
    """Linearised and exact mechanical errors of the clamp at one crosshead position.

    Attributes:
        grade: ISO 286 IT grade of the tolerances.
        tolerances: Full IT band of every dimension of both halves, m.
        report: Sensitivities, worst-case and RSS deviations and the asymmetry indices
            (seed 000, Eqs 38-43).
        monte_carlo: Exact nonlinear Monte Carlo of both outputs, or None if not asked.
    """

    grade: int
    tolerances: dict[str, dict[str, float]]
    report: AsymmetryReport
    monte_carlo: MonteCarloResult | None


def _mechanism(mechanism: str | Mechanism) -> Mechanism:
    """A Mechanism, loading a preset (or TOML file) given by name."""
    if isinstance(mechanism, Mechanism):
        return mechanism
    if isinstance(mechanism, str):
        return load_preset(mechanism)
    raise ParameterError(f"mechanism must be a Mechanism or a preset name, got {mechanism!r}")


def clamp_kinematics(mechanism: str | Mechanism, points: int = 101, *,
               half: str = "lower") -> Kinematics:
    """Positions, velocity ratio and mechanical advantage of one half over its stroke.

    Args:
        mechanism: A `toggle.params.Mechanism` or a preset's name or TOML path.
        points: Number of crosshead positions from open to the toggle (at least 2).
        half: ``"lower"`` or ``"upper"``.

    Returns:
        The stroke's ends and the motion at ``points`` positions (seed 000, Eqs 2-17).

    Raises:
        ParameterError: A bad argument.
        AssemblyError: Dimensions that cannot make the clamp.
    """
    if isinstance(points, bool) or not isinstance(points, int) or points < 2:
        raise ParameterError(f"points must be an integer >= 2, got {points!r}")
    dims = _mechanism(mechanism).half(half)
    x_open, x_toggle = stroke_limits(dims)
    x = np.linspace(x_open, x_toggle, points)
    motion = half_motion(x, dims, label=half)
    return Kinematics(x_open, x_toggle, x_toggle - x_open, x, motion.L, motion.dL_dx,
                      motion.mechanical_advantage)


def mechanical_errors(mechanism: str | Mechanism, grade: int = 10, *, x: float | None = None,
                      samples: int = 0, seed: int = 0) -> MechanicalErrors:
    """Mechanical errors of the clamp with every dimension at ISO 286 grade ``grade``.

    Args:
        mechanism: A `toggle.params.Mechanism` or a preset's name or TOML path.
        grade: IT grade, 1 to 18 (seed 000 uses 10).
        x: Crosshead position, m; default the lower half's toggle position.
        samples: Monte Carlo samples (normal, sigma = tolerance/3); 0 for none.
        seed: Seed of the Monte Carlo draws.

    Returns:
        The tolerances, the linearised budget and asymmetry, and the Monte Carlo result.

    Raises:
        ParameterError: A bad grade or sample count.
        AssemblyError: Tolerances so wide that a sample cannot assemble.
    """
    mech = _mechanism(mechanism)
    tolerances = it_tolerances(mech, grade)
    report = asymmetry(mech, tolerances, x)
    mc = _monte_carlo(mech, tolerances, x=x, samples=samples, seed=seed) if samples else None
    return MechanicalErrors(grade, tolerances, report, mc)


def clamping_force(mechanism: str | Mechanism, mu: float | None = None, *,
                   clamp_force: float | None = None,
                   x_contact: float | None = None) -> ClampingResult:
    """Friction statics of real-mold clamping: the thrust needed and the clamp force held.

    Args:
        mechanism: A mechanism with a ``[clamp]`` table (e.g. ``"lin2003_sm55"``).
        mu: Pin-joint friction coefficient; default the preset's.
        clamp_force: Final tie-bar (clamp) force to reach, N; default the preset's.
        x_contact: Mold-contact crosshead position, m (instead of ``clamp_force``).

    Returns:
        Contact and final positions, the peak thrust and the clamp state at lock-up with
        kinetic and static friction (seed 001, Eqs 1-30).

    Raises:
        ClampingError: No clamp data, or both ``clamp_force`` and ``x_contact`` given.
        StaticsError: A friction coefficient out of range.
    """
    from toggle.elastics import analyse_clamping

    return analyse_clamping(_mechanism(mechanism), mu, tiebar_force=clamp_force,
                            x_contact=x_contact)
