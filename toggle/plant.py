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

from toggle.asymmetry import (
    AsymmetryParams,
    advance_slip_state,
    asymmetry,
    hysteretic_force,
)
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
#: Platen speed scale of the platen friction's rate strengthening, m/s.
PLATEN_RATE_SPEED = 1e-3
#: A mold-contact position this close to the toggle (or beyond it) means no mold, m. The
#: toggle is a root found to about 1e-12 m, by Brent's method here and by bisection in the
#: native FMU: an FMU's x_contact start value (the toggle) must mean no mold in both.
NO_MOLD_TOLERANCE = 1e-9


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
                  slip_state: Any = None, mu: Any = None) -> PlantOutputs:
    """Plant outputs at input position x, velocity v and acceleration a.

    Floats, arrays or CasADi symbols; no assembly check (see
    :class:`CompiledPlant` for the checked numeric form). ``x_contact``, if
    given, replaces ``cfg.x_contact`` and may be a CasADi symbol: the planner
    keeps the mold height a parameter of its problem (no numeric check here);
    likewise ``mu`` replaces the pin friction ``cfg.friction``.
    ``slip_state`` z in [-1, 1] is the hysteretic friction state of the guides and
    of the unequal halves (:func:`toggle.asymmetry.advance_slip_state`, carried by the
    caller); None: steady sliding (z = the smooth sign of v), the stateless plant.
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
    guide = direction if slip_state is None else slip_state
    # the platen's bushings: a friction at the platen, rate-strengthening with the platen's
    # speed |g v| (smooth: g >= 0 over the stroke, v tanh(v / eps) ~ |v|), times dL/dx
    ratio = np.fabs(g)
    platen_friction = moving * dyn.platen_friction * ratio * guide * (
        1 + dyn.platen_rate * np.log1p(ratio * v * direction / PLATEN_RATE_SPEED))
    force = (inertia + dyn.guide_damping * v + dyn.guide_friction * guide + platen_friction
             + thrust)
    if not mech.symmetric:  # a parameter decision: equal halves add exactly nothing
        extra = asymmetry(x, v, mech.lower, mech.upper, cfg.asymmetry)
        force = force + (extra.force if slip_state is None
                         else hysteretic_force(extra, slip_state))
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
        motor_torque=motor_torque(force, mech.drive, a),
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
        sym = ca.SX.sym("xvaz", 4)
        self._calls = {}
        for stateful in (False, True):
            outs = plant_outputs(sym[0], sym[1], sym[2], cfg,
                                 slip_state=sym[3] if stateful else None)
            fn = ca.Function("plant", [sym], [ca.vertcat(*[ca.SX(o) for o in outs])],
                             {"cse": True})
            arg, res = np.zeros(4), np.zeros(len(PlantOutputs._fields))
            buffer, evaluate = fn.buffer()
            buffer.set_arg(0, memoryview(arg))
            buffer.set_res(0, memoryview(res))
            self._calls[stateful] = (arg, res, buffer, evaluate)

    def check_input(self, x: float) -> None:
        """Raise :class:`PlantError` unless the input position ``x`` (m) assembles."""
        if not (self.x_min <= x <= self.x_max):
            raise PlantError(
                f"input position x = {x!r} m outside the assemblable range "
                f"[{self.x_min:.6g}, {self.x_max:.6g}] m"
            )

    def __call__(self, x: float, v: float, a: float,
                 slip_state: float | None = None) -> PlantOutputs:
        """Outputs at (x, v, a); ``slip_state``: the friction state (None: steady sliding)."""
        self.check_input(x)
        arg, res, _, evaluate = self._calls[slip_state is not None]
        arg[:] = (x, v, a, 0.0 if slip_state is None else slip_state)
        evaluate()
        values = res.tolist()
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


class HystereticPlant:
    """A :class:`CompiledPlant` stepped along a drive path, carrying the slip state.

    What the rig emulator uses, and what an FMU must do to show the hysteresis: keep
    (x, z) from the previous step, advance z by the crosshead move with
    :func:`toggle.asymmetry.advance_slip_state`, evaluate the plant in that state.
    """

    def __init__(self, cfg: PlantConfig, slip_state: float = 0.0) -> None:
        self.plant = CompiledPlant(cfg)
        self.slip_distance = cfg.asymmetry.slip_distance
        #: (last position m or None before the first call, slip state): what a saved
        #: state (the FMU's) must hold besides the drive
        self.state: tuple[float | None, float] = (None, slip_state)

    def __call__(self, drive: DriveState) -> PlantOutputs:
        x_last, z = self.state
        if x_last is not None:
            z = float(advance_slip_state(z, drive.x - x_last, self.slip_distance))
        out = self.plant(drive.x, drive.v, drive.a, z)  # raises before the state changes
        self.state = (drive.x, z)
        return out


def configure(
    preset: str | Mechanism,
    *,
    mu: float | None = None,
    x_contact: float | None = None,
    masses: dict[str, float] | None = None,
    errors: dict[str, float] | None = None,
    drive: dict[str, Any] | None = None,
) -> PlantConfig:
    """A plant from a preset (a name, a TOML path or a loaded :class:`Mechanism`), with
    overrides named as the FMU names its parameters.

    ``masses`` overrides fields of the preset's [dynamics] (crosshead, links,
    platen, guide_damping) or, for a preset without one, supplies them (crosshead,
    links and platen at least); ``drive`` overrides fields of its [drive]
    (rotor_inertia, screw_inertia, ...); ``errors`` adds dimensional errors by seed 000's
    names (for example ``{"r8": 0.5e-3}`` lengthens link 8 of the upper half).
    A contact position at or beyond the toggle (within :data:`NO_MOLD_TOLERANCE`) means
    no mold. Every bad value
    raises :class:`ParameterError` naming it.
    """
    mech, changed = with_errors(
        preset if isinstance(preset, Mechanism) else load_preset(preset), errors)
    if masses:
        if mech.dynamics is None and not {"crosshead", "links", "platen"} <= set(masses):
            raise ParameterError(f"preset {mech.name!r} has no [dynamics] section: give the "
                                 "masses (crosshead, links, platen)")
        mech = replace(mech, dynamics=replace(mech.dynamics, **masses) if mech.dynamics
                       else Dynamics(**masses))
    if drive:
        if mech.drive is None:
            raise ParameterError(f"preset {mech.name!r} has no [drive] section to override")
        mech = replace(mech, drive=replace(mech.drive, **drive))
    for h in HALVES:
        try:
            toggle_position(mech.half(h))
        except AssemblyError as exc:
            raise ParameterError(
                f"the {h} half with {', '.join(changed) or 'its nominal dimensions'}: {exc}"
            ) from exc
    if x_contact is not None and x_contact >= toggle_position(mech.lower) - NO_MOLD_TOLERANCE:
        x_contact = None
    return PlantConfig(mech, mu=mu, x_contact=x_contact)


class DriveState(NamedTuple):
    """Input-link motion: position (m), velocity (m/s), acceleration (m/s^2); and the
    last command (m), its mean slope (m/s) over the ``span`` (s) before it, and the last
    step (s), from which the next step interpolates (:func:`follow`) or extrapolates
    (:func:`drive_step`) the command."""

    x: float
    v: float
    a: float
    u: float
    slope: float = 0.0
    h: float = 0.0  # 0: no step yet
    span: float = 0.0  # 0: no slope yet

    @classmethod
    def at_rest(cls, x: float) -> DriveState:
        return cls(x, 0.0, 0.0, x)


#: Bounds of a commanded motion (an input link, not a projectile): beyond them the
#: command is a step or a glitch of the master, refused rather than turned into 1e19 N.
MAX_INPUT_SPEED = 10.0  # m/s
MAX_INPUT_ACCELERATION = 1e4  # m/s^2


def lag_transition(w: float, zeta: float, h: float) -> tuple[float, float, float, float]:
    """exp(A h) of the drive lag A = [0 1; -w^2 -2 zeta w] (w > 0, zeta >= 0, h > 0), in a
    form that cannot overflow for any step.

    With the eigenvalues l1, l2 of A, exp(A h) = c0 I + D A, where D is the divided
    difference (e^{l1 h} - e^{l2 h}) / (l1 - l2) and c0 = e^{l1 h} - l1 D. Overdamped (real
    l2 < l1 <= 0): D = e^{l1 h} h (-expm1(-d)) / d with d = (l1 - l2) h, every factor in
    [0, 1] times h. Underdamped (l = -zeta w +- i q / h): D = e^{-zeta w h} h sin(q) / q and
    c0 = e^{-zeta w h} (cos q + zeta w h sin(q) / q). Near critical damping (|q^2| < 1e-2,
    q^2 = (w h)^2 (zeta^2 - 1)) the series of cosh/cos and sinh(q)/q in q^2 replaces both.
    A few floating-point operations per step, for any step size (no matrix exponential,
    no cache).
    """
    wh = w * h
    q2 = wh * wh * (zeta - 1.0) * (zeta + 1.0)
    if q2 >= 1e-2:  # overdamped: l1 = -w / (zeta + r), l2 = -w (zeta + r), r = sqrt(zeta^2 - 1)
        r = math.sqrt((zeta - 1.0) * (zeta + 1.0))
        l1h, l2h = -wh / (zeta + r), -wh * (zeta + r)
        e1 = math.exp(l1h)
        d = l1h - l2h
        big_d = e1 * h * (-math.expm1(-d) / d)
        c0 = e1 - (l1h / h) * big_d
        return c0, big_d, -w * w * big_d, e1 + (l2h / h) * big_d
    e = math.exp(-zeta * wh)
    if q2 <= -1e-2:  # underdamped
        q = math.sqrt(-q2)
        c, s = math.cos(q), math.sin(q) / q
    else:  # near critical: q2^k / (2k)! and q2^k / (2k+1)!
        c = s = term = 1.0
        for k in range(1, 9):
            term *= q2 / ((2.0 * k - 1.0) * (2.0 * k))
            c += term
            s += term / (2.0 * k + 1.0)
    es = e * s
    return e * c + es * zeta * wh, es * h, -(es * wh) * w, e * c - es * zeta * wh


def _bandwidth_hint(bandwidth: float) -> str:
    """What a command the drive refused says about ``drive_bandwidth`` (Hz)."""
    if bandwidth <= 0:
        return (" (drive_bandwidth = 0: an ideal drive follows a setpoint jump within one "
                "step; a drive_bandwidth > 0 Hz follows it through the drive's lag)")
    return (f" (drive_bandwidth = {bandwidth:.6g} Hz; a lower drive_bandwidth follows larger "
            "setpoint jumps)")


def follow(state: DriveState, x_cmd: float, h: float, bandwidth: float = 0.0,
           damping: float = 0.7) -> DriveState:
    """Advance the drive by h toward the commanded position.

    Between communication points the command is the parabola through the last
    three commands, so a command of constant acceleration is followed exactly
    whatever the step sizes (a master's variable steps change nothing).
    ``bandwidth`` 0 is an ideal position source: the input link is at the
    command, with the parabola's acceleration and its velocity limited to the
    sign of the step's mean slope and twice its size (so a stop, mean slope 0,
    has velocity 0 rather than the parabola's overshoot). Otherwise a
    second-order tracking lag with that natural frequency (Hz) and damping
    ratio, solved exactly for that command. A command beyond
    :data:`MAX_INPUT_SPEED` or :data:`MAX_INPUT_ACCELERATION` raises
    :class:`PlantError`.
    """
    if not (h > 0 and math.isfinite(h)):
        raise PlantError(f"step size must be > 0, got {h!r} s")
    rate = (x_cmd - state.u) / h  # the command's mean slope over the step
    curvature = 2 * (rate - state.slope) / (state.h + h)  # the parabola's 2nd derivative
    du1 = rate + curvature * h / 2  # the command's slope at the end of the step
    if bandwidth <= 0:  # a command that stops is not read as a reversal (nor doubles back)
        x, v, a = x_cmd, min(max(du1, min(0.0, 2 * rate)), max(0.0, 2 * rate)), curvature
    else:
        x, v, a = _lag_response(state, state.u, rate - curvature * h / 2, curvature, h,
                                bandwidth, damping)
    _check_motion(x_cmd, h, v, a, bandwidth)
    return DriveState(x, v, a, x_cmd, rate, h, h)


def _lag_response(state: DriveState, u0: float, du0: float, ddu: float, h: float,
                  bandwidth: float, damping: float) -> tuple[float, float, float]:
    """(x, v, a) after h of the second-order lag driven by the parabola u0 + du0 t + ddu t^2/2.

    x_p = u - k1 u' + k2 u'' solves x'' + 2 zeta w x' + w^2 x = w^2 u for a parabola u; the
    deviation from it decays as exp(A h), so the step is exact for that command.
    """
    w = 2 * math.pi * bandwidth
    k1, k2 = 2 * damping / w, (4 * damping * damping - 1) / (w * w)
    u1, du1 = u0 + du0 * h + ddu * h * h / 2, du0 + ddu * h
    e0 = state.x - (u0 - k1 * du0 + k2 * ddu)
    e1 = state.v - (du0 - k1 * ddu)
    p00, p01, p10, p11 = lag_transition(w, damping, h)
    x = u1 - k1 * du1 + k2 * ddu + p00 * e0 + p01 * e1
    v = du1 - k1 * ddu + p10 * e0 + p11 * e1
    return x, v, w * w * (u1 - x) - 2 * damping * w * v


def _check_motion(x_cmd: float, h: float, v: float, a: float, bandwidth: float) -> None:
    if not (abs(v) <= MAX_INPUT_SPEED and abs(a) <= MAX_INPUT_ACCELERATION):
        raise PlantError(
            f"the command x_cmd = {x_cmd:.6g} m after {h:.6g} s asks for {v:.3g} m/s and "
            f"{a:.3g} m/s^2; an input link moves within {MAX_INPUT_SPEED:g} m/s and "
            f"{MAX_INPUT_ACCELERATION:g} m/s^2" + _bandwidth_hint(bandwidth))


def extrapolation(state: DriveState, x_cmd: float, h: float,
                  bounds: tuple[float, float] | None = None) -> tuple[float, float]:
    """x_cmd's first and second derivatives at the step's start, read off the inputs of the
    last steps (a master that sends none): the parabola through the last three commands
    (the line through two after the first step, held before), so that over the step the
    command is extrapolated to third order in h instead of held (first order).

    A stop is not read as a reversal, nor a jump as a ramp that goes on: the extrapolated
    move over the step lies between 0 and twice the last mean slope times h, at most twice
    the last change of the command (a step longer than the last one extrapolates no
    further), and within ``bounds`` (m, the input's range), the derivatives scaled down
    together if not.
    """
    if state.h <= 0:
        return 0.0, 0.0
    rate = (x_cmd - state.u) / state.h
    d2 = 2 * (rate - state.slope) / (state.h + state.span) if state.span > 0 else 0.0
    d1 = rate + d2 * state.h / 2
    move = d1 * h + d2 * h * h / 2
    reach = 2 * rate * min(h, state.h)  # twice the last slope, nor over a longer step
    lo, hi = min(0.0, reach), max(0.0, reach)
    if bounds is not None:  # 0 stays within [lo, hi]: x_cmd itself may lie outside bounds
        lo, hi = min(0.0, max(lo, bounds[0] - x_cmd)), max(0.0, min(hi, bounds[1] - x_cmd))
    limited = min(max(move, lo), hi)
    if limited == move:
        return d1, d2
    scale = limited / move  # move != 0 here: 0 lies within [lo, hi]
    return d1 * scale, d2 * scale


def drive_step(state: DriveState, x_cmd: float, h: float, bandwidth: float = 0.0,
               damping: float = 0.7, du: float | None = None,
               ddu: float | None = None,
               bounds: tuple[float, float] | None = None) -> DriveState:
    """Advance the drive over [t, t + h] as an FMI master means it (FMI 2.0 section 4.2.2).

    ``x_cmd`` is the command at the step's start t, ``du`` and ``ddu`` its first and second
    derivatives there (None: not given, taken as 0 if the other is given); over the step the
    command is the polynomial x_cmd + du s + ddu s^2 / 2, and the lag (``bandwidth`` > 0 Hz)
    is solved exactly for it. Without derivatives the lag's command is extrapolated from
    the last commands (:func:`extrapolation`, within ``bounds``, the input's range): a
    held command would bias the lag's acceleration by w^2 u' h. The ideal drive
    (``bandwidth`` 0) is at the polynomial's end; without derivatives at x_cmd, its
    velocity and acceleration the command's as :func:`follow` reads them off the last
    three commands (a position source at its setpoint).
    """
    if du is None and ddu is None and bandwidth <= 0:
        return follow(state, x_cmd, h)
    if not (h > 0 and math.isfinite(h)):
        raise PlantError(f"step size must be > 0, got {h!r} s")
    if du is None and ddu is None:
        d1, d2 = extrapolation(state, x_cmd, h, bounds)
    else:
        d1, d2 = du or 0.0, ddu or 0.0
    if bandwidth <= 0:
        x, v, a = x_cmd + d1 * h + d2 * h * h / 2, d1 + d2 * h, d2
    else:
        x, v, a = _lag_response(state, x_cmd, d1, d2, h, bandwidth, damping)
    _check_motion(x_cmd, h, v, a, bandwidth)
    rate = (x_cmd - state.u) / state.h if state.h > 0 else 0.0
    return DriveState(x, v, a, x_cmd, rate, h, state.h)


__all__ = [
    "AssemblyError", "CompiledPlant", "DriveState", "HystereticPlant", "PlantConfig",
    "PlantError", "PlantOutputs", "configure", "drive_step", "extrapolation", "follow",
    "plant_outputs",
    "with_errors",
]
