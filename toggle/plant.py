"""Dynamic plant of the clamp: what the drive, the encoder and the load cell see.

The drive positions the input link (crosshead) at x; the plant returns the
force between drive and input link (what the rig's load cell reads), the
moving platen's position and velocity (the linear encoder), the clamp and
tie-bar forces and the motor torque. It composes the one model, never
re-deriving it: kinematics of both halves (:mod:`toggle.kinematics`, with
exact AD derivatives), pin friction and real-mold clamping
(:mod:`toggle.statics`, :mod:`toggle.elastics`) and the drive
(:mod:`toggle.drive`). Written with numpy ufuncs, :func:`plant_outputs`
evaluates on floats, arrays and CasADi symbols (the planner optimises
through it); :class:`CompiledPlant` is the fast numeric form for time
stepping (the FMU, the rig emulator).

Input force:  F = M_eq(x) a + 1/2 M_eq'(x) v^2 + c v + F0(x, sgn v)
with M_eq = m_in + m_out g(x)^2 before mold contact (g = dL/dx averaged over
the halves, m_in = crosshead + links/2, m_out = platen + links/2; the platen
stops at mold contact, so only m_in remains after it), c the guide damping
and F0 the static crosshead thrust against the tie bars with pin friction
(zero before mold contact). The friction direction is tanh(v / v_eps), a
smooth sign for the optimiser. With unequal halves each half's clamp state is
computed with its own dimensions and the two are averaged, and the force the
rigid platen needs to force them to agree adds the pin friction and elastic
energy of :mod:`toggle.asymmetry` (docs/unequal-halves.md).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from toggle.asymmetry import AsymmetryParams, extra_input_force
from toggle.drive import motor_torque
from toggle.elastics import clamp_state
from toggle.kinematics import (
    AssemblyError,
    assemblable_range,
    half_pose,
    motion_terms,
    toggle_position,
)
from toggle.params import (
    HALVES,
    Dynamics,
    Mechanism,
    ParameterError,
    load_preset,
    paper_dimension,
)
from toggle.statics import force_ratios

#: Mechanical advantage reported where it is unbounded (the frictionless toggle).
MA_CAP = 1e12


class PlantError(ValueError):
    """The plant cannot be evaluated at this input (outside its range, self-locking)."""


class PlantOutputs(NamedTuple):
    """Everything the plant reports at one instant, SI units."""

    x: Any  # input-link (crosshead) position, m
    velocity: Any  # input-link velocity, m/s
    acceleration: Any  # input-link acceleration, m/s^2
    platen_position: Any  # moving platen, m (linkage frame, from the link-4 pivot)
    platen_velocity: Any  # m/s
    input_force: Any  # drive on input link (load cell), N
    clamp_force: Any  # N
    tiebar_force: Any  # total of all tie bars, N
    mechanical_advantage: Any  # F_cl / F0 with friction (kinematic 1/g without clamp data), 1
    toggle_angle: Any  # seed 001's alpha = theta4 of the lower half, rad
    asymmetry: Any  # L_upper - L_lower, m
    motor_torque: Any  # N m


@dataclass(frozen=True)
class PlantConfig:
    """A mechanism and the operating parameters of the dynamic plant (SI)."""

    mechanism: Mechanism
    mu: float | None = None  # kinetic pin friction; None: the preset's (0 without [clamp])
    x_contact: float | None = None  # crosshead position at mold contact; None: no mold
    velocity_epsilon: float = 1e-4  # m/s, width of the smooth friction direction
    #: the unequal-halves model (calibrated defaults of the desktop clamp)
    asymmetry: AsymmetryParams = AsymmetryParams()

    def __post_init__(self) -> None:
        mech = self.mechanism
        if self.mu is not None and not (math.isfinite(self.mu) and self.mu >= 0):
            raise ParameterError(f"mu must be a finite number >= 0, got {self.mu!r}")
        if mech.dynamics is None:
            raise ParameterError(f"preset {mech.name!r} has no [dynamics] section (masses)")
        if mech.drive is None:
            raise ParameterError(f"preset {mech.name!r} has no [drive] section")
        if self.x_contact is not None:
            if mech.clamp is None:
                raise ParameterError(f"mold contact needs the [clamp] data of {mech.name!r}")
            lo, hi = self.input_range
            if not (math.isfinite(self.x_contact) and lo <= self.x_contact <= hi):
                raise ParameterError(
                    f"mold-contact position x_contact = {self.x_contact!r} m is outside "
                    f"the assemblable range [{lo:.6g}, {hi:.6g}] m"
                )
        if not self.velocity_epsilon > 0:
            raise ParameterError("velocity_epsilon must be > 0")

    @property
    def friction(self) -> float:
        if self.mu is not None:
            return self.mu
        return self.mechanism.clamp.mu if self.mechanism.clamp else 0.0

    @property
    def dynamics(self) -> Dynamics:
        return self.mechanism.dynamics

    @functools.cached_property
    def input_range(self) -> tuple[float, float]:
        """Input positions where both halves assemble, m."""
        ranges = [assemblable_range(self.mechanism.half(h)) for h in HALVES]
        return max(r[0] for r in ranges), min(r[1] for r in ranges)

    def with_(self, **changes: Any) -> PlantConfig:
        return replace(self, **changes)


def plant_outputs(x: Any, v: Any, a: Any, cfg: PlantConfig, x_contact: Any = None,
                  mu: Any = None) -> PlantOutputs:
    """Plant outputs at input position x, velocity v and acceleration a.

    Floats, arrays or CasADi symbols; no assembly check (see
    :class:`CompiledPlant` for the checked numeric form). ``x_contact``, if
    given, replaces ``cfg.x_contact`` and may be a CasADi symbol: the planner
    keeps the mold height a parameter of its problem (no numeric check here);
    likewise ``mu`` replaces the pin friction ``cfg.friction``.
    """
    mech, dyn = cfg.mechanism, cfg.dynamics
    x_contact = cfg.x_contact if x_contact is None else x_contact
    friction = cfg.friction if mu is None else mu
    terms = [motion_terms(x, mech.half(h)) for h in HALVES]
    L = 0.5 * (terms[0][0] + terms[1][0])
    g = 0.5 * (terms[0][1] + terms[1][1])
    gp = 0.5 * (terms[0][2] + terms[1][2])
    direction = np.tanh(v / cfg.velocity_epsilon)
    m_in = dyn.crosshead + 0.5 * dyn.links
    m_out = dyn.platen + 0.5 * dyn.links
    if x_contact is None:
        moving = 1.0
        platen = L
        clamp = tiebar = thrust = 0.0 * x
        ma = 1.0 / np.maximum(np.fabs(g), 1.0 / MA_CAP)
    else:
        L_contact = 0.5 * sum(half_pose(x_contact, mech.half(h)).L for h in HALVES)
        moving = np.where(x < x_contact, 1.0, 0.0)
        platen = np.where(x < x_contact, L, L_contact)
        states = [clamp_state(x, x_contact, mech, friction, direction, half=h)
                  for h in HALVES]
        clamp = 0.5 * (states[0].clamp_force + states[1].clamp_force)
        tiebar = 0.5 * (states[0].tiebar_force + states[1].tiebar_force)
        thrust = 0.5 * (states[0].thrust + states[1].thrust)
        q = force_ratios(x, mech.lower, mech.clamp.pins, friction, direction).thrust
        ma = 1.0 / np.maximum(np.fabs(q), 1.0 / MA_CAP)
    inertia = m_in * a + moving * m_out * g * (g * a + gp * v * v)
    force = inertia + dyn.guide_damping * v + thrust
    if not mech.symmetric:  # a parameter decision: equal halves add exactly nothing
        force = force + extra_input_force(x, v, mech.lower, mech.upper, cfg.asymmetry)
    theta4 = half_pose(x, mech.lower, check=False).theta4
    return PlantOutputs(
        x=x, velocity=v, acceleration=a,
        platen_position=platen,
        platen_velocity=moving * g * v,
        input_force=force,
        clamp_force=clamp,
        tiebar_force=tiebar,
        mechanical_advantage=ma,
        toggle_angle=theta4,
        asymmetry=terms[1][0] - terms[0][0],
        motor_torque=motor_torque(force, mech.drive),
    )


class CompiledPlant:
    """:func:`plant_outputs` compiled once into a CasADi function, for time stepping.

    One call costs a few microseconds: it evaluates through CasADi's buffer
    interface (numpy arrays bound once to the function's input and output), so
    no DM is built per call, which would cost ten times the evaluation. Hence
    one instance must not be called from two threads at once. Inputs outside
    the assemblable range and non-finite results raise :class:`PlantError`
    instead of returning NaN.
    """

    def __init__(self, cfg: PlantConfig) -> None:
        self.config = cfg
        self.x_min, self.x_max = cfg.input_range
        sym = ca.SX.sym("xva", 3)
        outs = plant_outputs(sym[0], sym[1], sym[2], cfg)
        self._fn = ca.Function("plant", [sym], [ca.vertcat(*[ca.SX(o) for o in outs])],
                               {"cse": True})
        self._arg, self._res = np.zeros(3), np.zeros(len(PlantOutputs._fields))
        self._buffer, self._eval = self._fn.buffer()
        self._buffer.set_arg(0, memoryview(self._arg))
        self._buffer.set_res(0, memoryview(self._res))

    def __call__(self, x: float, v: float, a: float) -> PlantOutputs:
        if not (self.x_min <= x <= self.x_max):
            raise PlantError(
                f"input position x = {x!r} m outside the assemblable range "
                f"[{self.x_min:.6g}, {self.x_max:.6g}] m"
            )
        self._arg[:] = (x, v, a)
        self._eval()
        values = self._res.tolist()
        if not all(map(math.isfinite, values)):
            bad = [n for n, val in zip(PlantOutputs._fields, values) if not math.isfinite(val)]
            raise PlantError(f"no finite plant solution at x = {x!r} m ({', '.join(bad)})")
        return PlantOutputs(*values)


def with_errors(mech: Mechanism, errors: dict[str, float] | None
                ) -> tuple[Mechanism, list[str]]:
    """The mechanism with dimensional errors added by seed 000's names (``{"r8": 0.5e-3}``
    lengthens link 8 of the upper half), and the errors applied as text; every bad value
    raises :class:`ParameterError` naming it."""
    changed = []
    for name, delta in (errors or {}).items():
        if not math.isfinite(delta):
            raise ParameterError(f"dimensional error delta_{name} must be finite, got {delta!r}")
        half, dim = paper_dimension(name)
        if delta:
            try:
                mech = mech.with_error(half, dim, delta)
            except ParameterError as exc:
                raise ParameterError(f"delta_{name} = {delta!r} m: {exc}") from exc
            changed.append(f"delta_{name} = {delta!r} m")
    return mech, changed


def configure(
    preset: str,
    *,
    mu: float | None = None,
    x_contact: float | None = None,
    masses: dict[str, float] | None = None,
    errors: dict[str, float] | None = None,
) -> PlantConfig:
    """A plant from a preset, with overrides named as the FMU names its parameters.

    ``masses`` overrides fields of the preset's [dynamics] (crosshead, links,
    platen, guide_damping); ``errors`` adds dimensional errors by seed 000's
    names (for example ``{"r8": 0.5e-3}`` lengthens link 8 of the upper half).
    A contact position at or beyond the toggle means no mold. Every bad value
    raises :class:`ParameterError` naming it.
    """
    mech, changed = with_errors(load_preset(preset), errors)
    if masses:
        if mech.dynamics is None:
            raise ParameterError(f"preset {mech.name!r} has no [dynamics] section to override")
        mech = replace(mech, dynamics=replace(mech.dynamics, **masses))
    for h in HALVES:
        try:
            toggle_position(mech.half(h))
        except AssemblyError as exc:
            raise ParameterError(
                f"the {h} half with {', '.join(changed) or 'its nominal dimensions'}: {exc}"
            ) from exc
    if x_contact is not None and x_contact >= toggle_position(mech.lower):
        x_contact = None
    return PlantConfig(mech, mu=mu, x_contact=x_contact)


class DriveState(NamedTuple):
    """Input-link motion: position (m), velocity (m/s), acceleration (m/s^2)."""

    x: float
    v: float
    a: float


@functools.lru_cache(maxsize=64)
def _lag_matrices(
    bandwidth: float, damping: float, h: float
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Exact zero-order-hold discretisation of x'' = w^2 (u - x) - 2 zeta w x' (as floats)."""
    from scipy.linalg import expm

    w = 2 * math.pi * bandwidth
    A = np.array([[0.0, 1.0], [-w * w, -2 * damping * w]])
    B = np.array([0.0, w * w])
    M = expm(np.block([[A, B[:, None]], [np.zeros((1, 3))]]) * h)
    return tuple(float(v) for v in M[:2, :2].ravel()), (float(M[0, 2]), float(M[1, 2]))


def follow(state: DriveState, x_cmd: float, h: float, bandwidth: float = 0.0,
           damping: float = 0.7) -> DriveState:
    """Advance the drive by h toward the commanded position.

    ``bandwidth`` 0 is an ideal position source (velocity and acceleration by
    backward differences); otherwise a second-order tracking lag with that
    natural frequency (Hz) and damping ratio, discretised exactly.
    """
    if not h > 0:
        raise PlantError(f"step size must be > 0, got {h!r} s")
    if bandwidth <= 0:
        v = (x_cmd - state.x) / h
        return DriveState(x_cmd, v, (v - state.v) / h)
    (p00, p01, p10, p11), (g0, g1) = _lag_matrices(bandwidth, damping, h)
    x = p00 * state.x + p01 * state.v + g0 * x_cmd
    v = p10 * state.x + p11 * state.v + g1 * x_cmd
    w = 2 * math.pi * bandwidth
    return DriveState(x, v, w * w * (x_cmd - x) - 2 * damping * w * v)


__all__ = [
    "AssemblyError", "CompiledPlant", "DriveState", "PlantConfig", "PlantError", "PlantOutputs",
    "configure", "follow", "plant_outputs", "with_errors",
]
