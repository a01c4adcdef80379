"""What a stroke planner plans for, and how its plans measure against it.

:class:`StrokeReports` holds one plant's planning setup (the plant with its mold, the
drive limits, the robust variants and their scales, the mold-protection zone, the
problem's scales and parameters) and the reports on a plan: its peak over the plant and
the variants, the motor torque over the torque-speed curve, the mold-protection zone, the
limits it runs at. The planner (:class:`controllers.planner.ClampPlanner`) is this with the
solving; :func:`baseline_stroke` and :func:`baselines` are the strokes a plan is compared
with.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from controllers.limits import DriveLimits
from controllers.plans import (
    CONTACT_SPEED,
    CREEP_FACTOR,
    INTERVALS,
    NO_PROTECTION,
    Plan,
    Protection,
    protection_entry,
)
from controllers.profiles import (
    Profile,
    ProfileError,
    ProfileSamples,
    minimum_time,
    predict,
    ramp_time,
    s_curve,
)
from controllers.stroke_problem import (
    NO_CAP,
    StrokeProblem,
    curve_parameters,
    neutral,
    plant_masses,
)
from toggle.drive import (
    back_efficiency,
    copper_coefficient,
    reflected_mass,
    travel_per_radian,
)
from toggle.elastics import clamp_stroke
from toggle.params import ParameterError
from toggle.plant import PlantConfig, plant_outputs

_BINDING = 0.99  # a limit counts as binding above this fraction of its value
_BASELINE_STEP = 0.8  # factor on a baseline's acceleration while it breaks the torque curve
_KEPT_PEAKS = 32  # worst peaks kept per planner (worst_peak), a best plan's and a curve's


class StrokeReports:
    """One plant's planning setup on a :class:`StrokeProblem` (built here without
    ``problem``) and the reports on its plans. With ``variants`` (the clamp with other
    dimensional errors or masses) the reports take the worst of the plant and its
    variants, with the mold at the same crosshead position (:meth:`worst_peak`);
    ``scales`` divide the variants' forces (default 1: the absolute worst case; a
    variant's baseline peak over the plant's weighs each against its own baseline).
    """

    def __init__(self, cfg: PlantConfig, limits: DriveLimits, *,
                 contact_speed: float = CONTACT_SPEED, intervals: int = INTERVALS,
                 problem: StrokeProblem | None = None,
                 variants: tuple[PlantConfig, ...] = (),
                 scales: tuple[float, ...] | None = None,
                 protection: Protection = NO_PROTECTION) -> None:
        if cfg.x_contact is None:
            raise ParameterError("the planner needs a mold-contact position (x_contact)")
        if not (math.isfinite(contact_speed) and contact_speed > 0):
            raise ParameterError(f"contact speed must be > 0 m/s, got {contact_speed!r}")
        self.problem = problem or StrokeProblem(
            neutral(cfg), intervals, tuple(neutral(v) for v in variants))
        pr = self.problem
        self.config, self.limits, self.contact_speed = cfg, limits, contact_speed
        self.variants = tuple(v.with_(x_contact=cfg.x_contact, mu=cfg.mu) for v in variants)
        self.scales = tuple(scales or (1.0,) * len(variants))
        if len(self.scales) != len(variants) or not all(
                math.isfinite(k) and k > 0 for k in self.scales):
            raise ParameterError(f"need one positive force scale per variant, got {scales!r}")
        self.x_open, self.x_final, self.stroke = pr.x_open, pr.x_final, pr.stroke
        self.t_ref = minimum_time(self.stroke, limits.velocity, limits.acceleration, limits.jerk)
        self.jerk_bound = limits.jerk * self.t_ref**3 / self.stroke
        self.n1, self.n2 = pr.n1, pr.n2
        self.xi_contact = (cfg.x_contact - self.x_open) / self.stroke
        self.x_zone, self.protect_distance = protection_entry(cfg, protection.distance)
        self.xi_zone = (self.x_zone - self.x_open) / self.stroke
        self.protect_speed, self.protect_force = protection.speed, protection.force
        #: with a cap the zone's entry is pinned to a node; without, the approach and the zone
        #: share one interval length (the problem of a plain two-phase stroke)
        self.capped = (protection.speed, protection.force) != (None, None)
        self.force_limit = limits.force(cfg.mechanism.drive)
        self._worst_peaks: dict[int, tuple[Plan, float]] = {}
        self.f_ref = self._reference_force()

    @property
    def creep_speed(self) -> float:
        """The slowest crosshead speed the plans keep while clamping, m/s."""
        return CREEP_FACTOR * self.config.velocity_epsilon

    def clamping_creeps(self, settle: int) -> bool:
        """Whether the clamping (mold contact to the final position) is long enough to hold
        the creep floor on all but its last ``settle`` of n2 intervals: the floor holds for
        at least (n2 - settle) / settle times the fastest stop from :attr:`creep_speed`, so
        the clamping must be longer than that travel. A shorter one (a mold set within
        ~0.2 mm of the toggle on chang2021) builds so little force that its friction cannot
        be exploited, and the floor would make it infeasible."""
        lim, v = self.limits, min(self.creep_speed, self.limits.velocity)
        stop = ramp_time(v, lim.acceleration, lim.jerk)  # creep speed to rest
        travel = v * stop * ((self.n2 - settle) / settle + 0.5)
        return self.x_final - self.config.x_contact > travel

    @property
    def longest(self) -> float:
        """The longest duration planned, s: the S-curve cruising at :attr:`creep_speed`
        (slower strokes, the plan's and the baselines', would cross the clamping where the
        smoothed friction model fades)."""
        return minimum_time(self.stroke, min(self.creep_speed, self.limits.velocity),
                            self.limits.acceleration, self.limits.jerk)

    @property
    def last(self) -> Plan | None:
        """The latest plan on this planner's problem (any mold height)."""
        return self.problem.last

    def _force(self, x: Any, v: Any, a: Any) -> np.ndarray:
        """The plant's input force at the points (x, v, a) with this planner's mold, N."""
        return self.problem.input_force(x, v, a, self.config)

    def _reference_force(self) -> float:
        """Scale of the input force: its quasi-static peak at the reference speed, N."""
        xs = np.linspace(self.x_open, self.x_final, 401)
        f = self._force(xs, self.stroke / self.t_ref, 0.0)
        return max(float(np.max(np.abs(f))), 1e-6)

    def _parameters(self, weights: list[float], torque_factor: float = 1.0,
                    caps: tuple[float | None, float | None] = (None, None)) -> list[float]:
        """The problem's :data:`PARAMETERS` for these objective weights, factor on the
        torque-speed curve and protection caps (speed, force; None: none), then the plants'
        force scales."""
        drive = self.config.mechanism.drive
        return [*weights[:4], *self._integrand(bool(weights[4:5] and weights[4])),
                self.config.x_contact, self.f_ref, self.t_ref, self.limits.jerk,
                self.contact_speed, self.config.friction, travel_per_radian(drive),
                drive.efficiency, reflected_mass(drive), torque_factor,
                *curve_parameters(self.limits), *(NO_CAP if c is None else c for c in caps),
                1.0, *self.scales,
                *(m for plant in (self.config, *self.variants) for m in plant_masses(plant))]

    def _integrand(self, electrical: bool) -> list[float]:
        """The objective integral's :data:`controllers.stroke_problem.INTEGRAND`: of the
        squared input force, or (``electrical``) the stroke's electrical energy over
        f_ref S, which needs the motor's winding resistance and torque constant."""
        if not electrical:
            return [0.0, 1.0, 1.0, 0.0, 1.0]
        drive = self.config.mechanism.drive
        c = copper_coefficient(drive)
        if c is None:
            raise ParameterError(
                f"the energy objective needs the motor's winding_resistance and "
                f"torque_constant in the [drive] of {self.config.mechanism.name!r}")
        p = travel_per_radian(drive)
        return [reflected_mass(drive), drive.efficiency, back_efficiency(drive), 1.0,
                c * p**2 * self.f_ref * self.t_ref / self.stroke]

    # ---- reports ------------------------------------------------------------------

    def node_forces(self, plan: Plan) -> tuple[np.ndarray, float]:
        """Input force at the nodes and interval midpoints (N), platen speed at contact
        (m/s), from the plan's solution."""
        F, contact, _ = self.problem.monitor(plan.solution["x"], self._parameters([0] * 4))
        return np.asarray(F).ravel(), float(contact)

    def node_torque_ratio(self, plan: Plan) -> float:
        """The plan's largest motor torque over the torque-speed curve at the nodes and
        midpoints (the plant, not its variants), from its solution: cheap, no sampling."""
        F, _, z = self.problem.monitor(plan.solution["x"], self._parameters([0] * 4))
        z = np.asarray(z)
        return self.limits.torque_ratio(self.config.mechanism.drive, z[1], z[2],
                                        np.asarray(F).ravel())

    def protection(self, plan: Plan) -> dict[str, float]:
        """The plan in the mold-protection zone on its 1 ms samples through the plant: the
        time the platen spends there (s), its peak speed (m/s) and the peak |input force|
        (N); the zone's distance (m), entry and caps (m/s, N; None: no cap)."""
        s = plan.samples
        inside = (s.position >= self.x_zone) & (
            s.time >= plan.t_contact if self.problem.opening else s.time <= plan.t_contact)
        speed = plant_outputs(s.position[inside], s.velocity[inside], s.acceleration[inside],
                              self.config.with_(x_contact=None)).platen_velocity
        return {"distance": self.protect_distance, "x_entry": self.x_zone,
                "time": self._zone_time(plan),
                "peak_platen_speed": float(np.max(np.abs(speed), initial=0.0)),
                "peak_input_force": float(np.max(np.abs(s.input_force[inside]), initial=0.0)),
                "speed_cap": self.protect_speed, "force_cap": self.protect_force}

    def _zone_time(self, plan: Plan) -> float:
        """Time the plan spends in the protection zone, s: from the crosshead's crossing of
        the zone's entry (interpolated on the 1 ms samples) to mold contact (opening: from
        separation to the crossing)."""
        s, opening = plan.samples, self.problem.opening
        closing = s.time <= plan.t_contact if not opening else s.time >= plan.t_contact
        x, t = s.position[closing], s.time[closing]
        crossing = float(np.interp(self.x_zone, x[::-1], t[::-1]) if opening
                         else np.interp(self.x_zone, x, t))
        return abs(plan.t_contact - crossing)

    def worst_peak(self, plan: Plan) -> float:
        """The plan's peak input force (1 ms samples through the plant), N: the worst over
        the plant and its variants (each divided by its scale). Kept for the latest plans
        asked about (a best plan compares its starts' peaks after each: with variants each
        is a prediction per variant)."""
        if not self.variants:
            return plan.peak_force  # kept by the plan itself
        kept = self._worst_peaks.get(id(plan))
        if kept is None or kept[0] is not plan:
            if len(self._worst_peaks) >= _KEPT_PEAKS:
                self._worst_peaks.clear()
            kept = self._worst_peaks[id(plan)] = (plan, max([plan.peak_force, *(
                predict(plan.profile, v).peak_force / k
                for v, k in zip(self.variants, self.scales))]))
        return kept[1]

    def torque_ratio(self, plan: Plan) -> float:
        """The plan's largest motor torque over the torque-speed curve at the motor's speed
        (1 ms samples through the plant and its variants): at most 1 within the curve."""
        drive = self.config.mechanism.drive
        return max(self.limits.torque_ratio(drive, s.velocity, s.acceleration, s.input_force)
                   for s in (plan.samples, *(predict(plan.profile, v) for v in self.variants)))

    def binding_limits(self, plan: Plan, force_limit: float | None = None) -> list[str]:
        """Names of the limits the plan runs at (within 1 %), the force limit judged by the
        plan's 1 ms samples through the plant."""
        pr, lim = plan.profile, self.limits
        contact = self.node_forces(plan)[1]
        peak = self.worst_peak(plan)
        found = {
            f"velocity (max {lim.velocity * 1e3:.4g} mm/s)": np.max(np.abs(pr.v)) / lim.velocity,
            f"acceleration (max {lim.acceleration:.4g} m/s^2)":
                np.max(np.abs(pr.a)) / lim.acceleration,
            f"jerk (max {lim.jerk:.4g} m/s^3)": np.max(np.abs(pr.jerk)) / lim.jerk,
            f"motor torque (torque-speed curve, {lim.torque:.4g} N m at standstill)":
                self.torque_ratio(plan),
            f"platen speed at mold contact (max {self.contact_speed * 1e3:.4g} mm/s)":
                contact / self.contact_speed,
        }
        if force_limit is not None and force_limit < self.force_limit:
            found[f"input force (max {force_limit:.4g} N)"] = peak / force_limit
        zone, where = self.protection(plan), (
            f"over the first {self.protect_distance * 1e3:.3g} mm after mold separation"
            if self.problem.opening else f"over the last {self.protect_distance * 1e3:.3g} mm")
        if self.protect_speed is not None:
            found[f"mold-protection platen speed (max {self.protect_speed * 1e3:.4g} mm/s "
                  f"{where})"] = zone["peak_platen_speed"] / self.protect_speed
        if self.protect_force is not None:
            found[f"mold-protection input force (max {self.protect_force:.4g} N {where})"] = (
                zone["peak_input_force"] / self.protect_force)
        return [name for name, ratio in found.items() if ratio >= _BINDING]

    def clamp_force(self) -> float:
        """Clamp force held at rest in the locked position, N."""
        return float(plant_outputs(self.x_final, 0.0, 0.0, self.config).clamp_force)


def baseline_stroke(cfg: PlantConfig, limits: DriveLimits, duration: float,
                    jerk: float | None = None) -> Profile:
    """The S-curve stroke of the plant's clamp in ``duration`` under the limits (the jerk
    limit's unless ``jerk`` is given; inf: the trapezoidal velocity profile), held to the
    motor's torque-speed curve: where the stroke at full acceleration breaks it (the
    drive's inertia needs torque), the acceleration is lowered, in steps of
    :data:`_BASELINE_STEP` and then by bisection, to the highest that keeps the curve, as
    far as the duration allows (else the stroke at full acceleration, which the caller
    reports as breaking the curve: :meth:`DriveLimits.torque_ratio`)."""
    x_open, x_final = clamp_stroke(cfg.mechanism)
    jerk = limits.jerk if jerk is None else jerk
    drive = cfg.mechanism.drive

    def stroke(factor: float) -> Profile:
        return s_curve(x_open, x_final, duration, limits.velocity,
                       factor * limits.acceleration, jerk)

    def within(factor: float) -> bool:
        try:
            s = predict(stroke(factor), cfg)
        except ProfileError:  # too slow an acceleration for the duration
            return False
        return limits.torque_ratio(drive, s.velocity, s.acceleration, s.input_force) <= 1.0

    if within(1.0):
        return stroke(1.0)
    high, low = 1.0, _BASELINE_STEP
    while not within(low):
        if low < 1e-3:
            return stroke(1.0)
        high, low = low, low * _BASELINE_STEP
    for _ in range(20):  # the highest acceleration within the curve, to 0.01 %
        middle = 0.5 * (low + high)
        low, high = (middle, high) if within(middle) else (low, middle)
        if high - low < 1e-4 * high:
            break
    return stroke(low)


def baselines(cfg: PlantConfig, limits: DriveLimits, duration: float
              ) -> dict[str, ProfileSamples]:
    """The trapezoidal and S-curve strokes of the same duration and limits, predicted."""
    return {name: predict(baseline_stroke(cfg, limits, duration, jerk), cfg)
            for name, jerk in (("trapezoidal", math.inf), ("s_curve", limits.jerk))}
