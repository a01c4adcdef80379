"""The evaluation of one candidate clamp: its objectives and its constraints.

A candidate is a vector of :data:`design.targets.VARIABLES`. :class:`Evaluator` turns it
into a symmetric :class:`toggle.params.Mechanism` on the base preset (its clamp data,
drive and masses), then measures it with the one model: seed 004's measures over the
opening (:func:`toggle.study.angle_measures`), real-mold clamping up to the target force
(:func:`toggle.elastics.analyse_clamping`), the closing-time bound
(:mod:`design.timing`) and seed 003's tolerance synthesis
(:mod:`toggle.synthesis`). A candidate that does not assemble, has no toggle, cannot open
to its angle or cannot reach the clamp force is not an error: it gets a positive
constraint value (a violation) and the reason, and the search moves on.

Constraint values are normalised (0 is the limit, 1 a violation as large as the limit)
so that their sum, the constraint violation NSGA-II ranks infeasible candidates by, adds
like with like.
"""

from __future__ import annotations

import hashlib
import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from design import constraints as checks
from design.targets import DESIGN_LIMITS, OBJECTIVES, TARGETS, VARIABLES, Targets
from design.timing import StallError
from toggle.elastics import ClampingError, analyse_clamping
from toggle.kinematics import AssemblyError, output_position, sensitivities, stroke_limits
from toggle.params import HalfDims, Mechanism, ParameterError
from toggle.statics import StaticsError
from toggle.study import angle_grid, angle_measures, criteria

#: Measures recorded for every feasible candidate besides the objectives, with units.
MEASURES = {"platen_stroke": "m", "crosshead_stroke": "m", "x_open": "m", "x_toggle": "m",
            "link_ratio": "1", "transmission_D": "rad", "transmission_A": "rad",
            "platen_side_load": "1", "radial_envelope": "m", "tiebar_clearance": "m",
            "link_clearance": "m",
            "link_mass": "kg", "lockup_angle": "rad", "breakaway_force": "N",
            "self_locking_travel": "m", "clamp_force_sensitivity": "1/m",
            "link_utilisation": "1", "buckling_utilisation": "1", "pin_pressure": "Pa",
            "die_height_range": "1", "die_height_thrust": "N", "die_height_sensitivity": "1/m",
            "close_rms_torque": "N m", "close_energy": "J", "close_plan_time": "s",
            "cycle_rms_torque": "N m", "cycle_energy": "J", "cycle_time": "s"}

#: The constraints, in the order of the G matrix; each is active when its target is set
#: (assembly always; drive_thrust when the preset has a drive and clamp data; the
#: designer's limits of :data:`design.targets.DESIGN_LIMITS` at their defaults when the
#: preset has the data they need, or at the value [targets] gives).
CONSTRAINTS = ("assembly", "mold_open_stroke", "installation_length", "max_link_ratio",
               "clamp_force", "drive_thrust", "tolerances", *DESIGN_LIMITS)

#: Objectives of the motor's duty over the minimum-time closing stroke and molding cycle.
_DUTY = ("close_rms_torque", "close_energy", "cycle_rms_torque", "cycle_energy")
#: The measures of those plans (:func:`design.timing.planned_duty`).
DUTY_MEASURES = (*_DUTY, "close_plan_time", "cycle_time")

#: The designer's limits read on the geometry alone (the others need the clamping forces).
_GEOMETRIC = ("transmission_angle", "radial_envelope", "tiebar_clearance", "platen_side_load",
              "link_clearance")

#: Platen travel before mold contact over which the speed ratio "at mold close" is read
#: (the planner's default mold-protection zone: the last tenth).
PROTECT_FRACTION = 0.1


def candidate_key(digest: str, vector: Sequence[float]) -> str:
    """Hash of a candidate (and of the problem's digest): the key of its evaluation."""
    raw = digest.encode() + b"".join(struct.pack("<d", float(v)) for v in vector)
    return hashlib.sha256(raw).hexdigest()[:20]


@dataclass
class Evaluation:
    """One evaluated candidate (SI). ``constraints``: value <= 0 is met; ``reason`` says
    what fails for an infeasible one."""

    key: str
    variables: dict[str, float]
    metrics: dict[str, float] = field(default_factory=dict)
    constraints: dict[str, float] = field(default_factory=dict)
    reason: str = ""

    @property
    def feasible(self) -> bool:
        return all(v <= 0 for v in self.constraints.values())

    def as_record(self) -> dict[str, Any]:
        return {"key": self.key, "variables": self.variables, "metrics": self.metrics,
                "constraints": self.constraints, "reason": self.reason}

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> Evaluation:
        return cls(record["key"], dict(record["variables"]), dict(record["metrics"]),
                   dict(record["constraints"]), record.get("reason", ""))


def half_dims(values: Mapping[str, float]) -> HalfDims:
    """The half of a candidate (r2 = 0; r4c closes the triangle at alpha4)."""
    a, b, angle = values["r4a"], values["r4b"], values["alpha4"]
    r4c = math.sqrt(a * a + b * b - 2 * a * b * math.cos(angle))
    return HalfDims(r1=values["d"], r2=0.0, r3=values["r3"], r4a=a, r4b=b, r4c=r4c,
                    r5=values["r5"], e=values["e"])


class Evaluator:
    """Evaluates candidates of one targets file; build it once per process (a Dask worker
    keeps it: :func:`design.runner.evaluate_chunk`)."""

    def __init__(self, targets: Targets) -> None:
        self.targets = targets
        self.base = targets.base
        self.digest = targets.digest()
        self.limits = self._limits_in_force()
        self.active = self._active_constraints()
        wanted = set(targets.objectives)
        self._clamp = self.base.clamp is not None and bool(
            wanted & {"close_time", "thrust_peak", "link_stress", "tiebar_stress",
                      "link_mass", "breakaway_force"}
            or "clamp_force" in targets.targets or set(self.limits) - set(_GEOMETRIC))
        self._limits = None
        if self.base.drive is not None:
            from controllers.limits import drive_limits
            self._limits = drive_limits(self.base)

    def _has(self, need: str) -> bool:
        base = self.base
        if need == "spacing":
            return base.clamp is not None and base.clamp.tiebars.spacing is not None
        if need == "die_height":
            return base.clamp is not None and base.clamp.die_height is not None
        return getattr(base, need) is not None

    def _limits_in_force(self) -> dict[str, float]:
        """Each designer's limit at the value [targets] gives, else at its default where
        the preset has the data it needs (the radial envelope's default: the base
        preset's own, at its open position)."""
        out = {}
        for key, lim in DESIGN_LIMITS.items():
            if not all(self._has(n) for n in lim.needs):
                continue
            if key in self.targets.targets:
                out[key] = self.targets.targets[key]
            elif lim.default is not None:
                out[key] = lim.default
            elif key == "radial_envelope":
                dims = self.base.lower
                x_open, x_toggle = stroke_limits(dims)
                if self.base.clamp is not None and self.base.clamp.x_open is not None:
                    x_open = self.base.clamp.x_open
                out[key] = checks.radial_envelope(checks.joint_paths(dims, x_open, x_toggle))
        return out

    def _active_constraints(self) -> tuple[str, ...]:
        t, base = self.targets, self.base
        on = {"assembly": True,
              "mold_open_stroke": "mold_open_stroke" in t.targets,
              "installation_length": "installation_length" in t.targets,
              "max_link_ratio": "max_link_ratio" in t.targets,
              "clamp_force": base.clamp is not None,
              "drive_thrust": base.clamp is not None and base.drive is not None,
              "tolerances": "tolerance_cost" in t.objectives}
        on.update({k: k in self.limits for k in DESIGN_LIMITS})
        return tuple(c for c in CONSTRAINTS if on[c])

    def vector(self, values: Mapping[str, float]) -> np.ndarray:
        return np.array([float(values[v]) for v in VARIABLES])

    def values(self, vector: Sequence[float]) -> dict[str, float]:
        """The variables of a vector; with settings.lockup_angle, e follows the links."""
        out = dict(zip(VARIABLES, (float(v) for v in vector)))
        if self.targets.settings["lockup_angle"] > 0:
            out["e"] = (out["r4b"] + out["r5"]) * math.sin(self.targets.settings["lockup_angle"])
        return out

    def mechanism(self, values: Mapping[str, float], x_open: float | None = None,
                  name: str = "design") -> Mechanism:
        """The candidate as a symmetric mechanism on the base preset, its clamp opening at
        ``x_open`` to the target clamp force."""
        dims = half_dims(values)
        clamp = self.base.clamp
        if clamp is not None:
            clamp = replace(clamp, x_open=x_open, final_tiebar_force=self.targets.targets.get(
                "clamp_force", clamp.final_tiebar_force))
        dynamics = self.base.dynamics
        if dynamics is not None and self.base.sections is not None and clamp is not None:
            # the links' mass scales with their lengths (sections as the preset's)
            scale = (checks.link_mass(dims, self.base)
                     / checks.link_mass(self.base.lower, self.base))
            dynamics = replace(dynamics, links=dynamics.links * scale)
        return replace(self.base, name=name, lower=dims, upper=dims, clamp=clamp,
                       dynamics=dynamics,
                       description=f"designed by toggle design on {self.base.name}")

    def __call__(self, vector: Sequence[float]) -> Evaluation:
        values = self.values(vector)
        out = Evaluation(candidate_key(self.digest, vector), values)
        out.constraints = dict.fromkeys(self.active, 0.0)
        try:
            self._measure(values, out)
        except (AssemblyError, ParameterError, StaticsError) as exc:
            out.constraints["assembly"] = 1.0 + getattr(exc, "shortfall", 0.0)
            out.reason = f"assembly: {exc}"
        if not out.reason and not out.feasible:
            worst = max(out.constraints, key=out.constraints.__getitem__)
            out.reason = f"{worst}: violated by {out.constraints[worst]:.3g} of its limit"
        return out

    def _measure(self, values: dict[str, float], out: Evaluation) -> None:
        t, m, g = self.targets, out.metrics, out.constraints
        dims = half_dims(values)
        x_toggle = stroke_limits(dims)[1]  # AssemblyError: no toggle
        alphas = angle_grid(t.settings["alpha_lock"], values["alpha_open"],
                            int(t.settings["points"]))
        try:
            measures = angle_measures(dims, alphas)
        except AssemblyError as exc:  # cannot open that far: how far short, as a fraction
            limit = getattr(exc, "alpha_limit", 0.0)
            exc.shortfall = max(0.0, 1.0 - limit / values["alpha_open"])
            raise
        slowest = float(np.min(measures.velocity_ratio))
        if slowest <= 0:  # the platen would turn back while the clamp opens
            where = math.degrees(float(alphas[np.argmin(measures.velocity_ratio)]))
            raise AssemblyError(f"the platen reverses while the clamp opens (velocity ratio "
                                f"{slowest:.3g} at a toggle angle of {where:.4g} deg)")
        m.update(criteria(measures))
        m["velocity_ratio_peak"] = m.pop("velocity_ratio")
        # seed 004's Mp (Eq 6) is toggle study's; Eq 5's force ratio is half of it near lock-up
        m["mechanical_advantage_lock"] = float(measures.mechanical_advantage[0])
        m["x_open"], m["x_toggle"] = float(measures.x[-1]), x_toggle
        m["platen_stroke"] = float(measures.platen_stroke[-1])
        m["crosshead_stroke"] = float(measures.crosshead_stroke[-1])
        # read where a tenth of the platen's travel remains (platen_stroke rises with alpha)
        m["velocity_ratio_close"] = float(np.interp(PROTECT_FRACTION * m["platen_stroke"],
                                                    measures.platen_stroke,
                                                    measures.velocity_ratio))
        links = (dims.r3, dims.r4a, dims.r4b, dims.r4c, dims.r5)
        m["link_ratio"] = max(links) / min(links)
        # from the crosshead's rearmost position (behind the pivot if x_open < 0) to the
        # platen joint at lock-up
        m["installation_length"] = float(output_position(x_toggle, dims)) - min(0.0, m["x_open"])
        for key, value, most in (("mold_open_stroke", -m["platen_stroke"], False),
                                 ("installation_length", m["installation_length"], True),
                                 ("max_link_ratio", m["link_ratio"], True)):
            if key in g:  # a least target: -(measured - target) / target
                target = t.targets[key]
                g[key] = (value - target) / target if most else (value + target) / target
                if g[key] > 0 and not out.reason:
                    unit = TARGETS[key][0]
                    out.reason = (f"{key}: {abs(value):.6g} {unit} against "
                                  f"{'at most' if most else 'at least'} {target:.6g} {unit}")
        self._geometry(dims, x_toggle, m, g, out)
        sens = sensitivities(x_toggle, dims)
        m["tolerance_sensitivity"] = float(math.sqrt(sum(float(v) ** 2 for v in sens.values())))
        if "tolerance_cost" in t.objectives:
            self._tolerances(values, m, g, out)
        if self._clamp:
            self._clamping(values, m, g, out)

    def _limit(self, key: str, value: float, g: dict[str, float], out: Evaluation) -> None:
        """The normalised constraint of a designer's limit (0 at the limit, > 0 violated)."""
        if key not in g:
            return
        lim, target = DESIGN_LIMITS[key], self.limits[key]
        g[key] = (value - target if lim.most else target - value) / abs(target)
        if g[key] > 0 and not out.reason:
            out.reason = (f"{key}: {value:.6g} {lim.unit} against "
                          f"{'at most' if lim.most else 'at least'} {target:.6g} {lim.unit}")

    def _geometry(self, dims: HalfDims, x_toggle: float, m: dict[str, float],
                  g: dict[str, float], out: Evaluation) -> None:
        paths = checks.joint_paths(dims, m["x_open"], x_toggle,
                                   int(self.targets.settings["points"]))
        m.update(checks.transmission_angles(paths))
        m["transmission_angle"] = min(m["transmission_D"], m["transmission_A"])
        m["platen_side_load"] = checks.platen_side_load(paths)
        m["radial_envelope"] = checks.radial_envelope(paths)
        m["link_clearance"] = checks.link_clearance(dims, dims, m["x_open"], x_toggle)
        if self._has("sections") and self._has("spacing"):
            m["tiebar_clearance"] = checks.tiebar_clearance(
                replace(self.base, lower=dims, upper=dims), paths)
        for key in _GEOMETRIC:
            if key in m:
                self._limit(key, m[key], g, out)

    def _tolerances(self, values: dict[str, float], m: dict[str, float],
                    g: dict[str, float], out: Evaluation) -> None:
        from toggle.synthesis import allocate, clamp_error_model
        try:
            m["tolerance_cost"] = allocate(clamp_error_model(self.mechanism(values))).cost
        except ValueError as exc:
            g["tolerances"] = 1.0
            out.reason = f"tolerances: {exc}"

    def _clamping(self, values: dict[str, float], m: dict[str, float],
                  g: dict[str, float], out: Evaluation) -> None:
        mech = self.mechanism(values, x_open=m["x_open"])
        try:
            result = analyse_clamping(mech)
        except (ClampingError, StaticsError) as exc:
            g["clamp_force"] = 1.0
            out.reason = f"clamp_force: {exc}"
            return
        clamp = mech.clamp
        m["thrust_peak"] = result.thrust_max
        m["force_amplification_clamp"] = result.final.clamp_force / result.thrust_max
        states = (result.final, result.hold)
        links = clamp.links
        m["link_stress"] = max(max(abs(s.link1_force) / links.area1,
                                   abs(s.link2_bf_force) / links.area2,
                                   abs(s.link2_cf_force) / links.area2) for s in states)
        bars = clamp.tiebars
        m["tiebar_stress"] = max(s.tiebar_force for s in states) / (bars.count * bars.area)
        m.update(checks.lockup(mech, result))
        if mech.sections is not None:
            m.update(checks.structure(mech, result))
            if mech.dynamics is not None:
                m["link_mass"] = mech.dynamics.links
        if "die_height_range" in g:
            try:
                m.update(checks.die_height(
                    mech, self._limits.force(mech.drive) if self._limits else None,
                    self.limits.get("clamp_force_sensitivity",
                                    DESIGN_LIMITS["clamp_force_sensitivity"].default)))
            except (ClampingError, StaticsError, ParameterError) as exc:
                g["die_height_range"] = 1.0
                out.reason = out.reason or f"die_height_range: {exc}"
        for key in DESIGN_LIMITS:
            if key not in _GEOMETRIC and key in m:
                self._limit(key, m[key], g, out)
        if "drive_thrust" in g:
            most = self._limits.force(mech.drive)
            g["drive_thrust"] = (result.thrust_max - most) / most
            if g["drive_thrust"] > 0:
                out.reason = (f"drive_thrust: the clamp needs {result.thrust_max:.6g} N, the "
                              f"motor holds {most:.6g} N")
                return
        if {"close_time", *_DUTY} & set(self.targets.objectives):
            try:
                m.update(self._timing(mech, result, set(_DUTY) & set(self.targets.objectives)))
            except StallError as exc:  # the motor cannot close this clamp
                g["drive_thrust"] = max(g.get("drive_thrust", 0.0), 1.0)
                out.reason = f"drive_thrust: {exc}"

    def _timing(self, mech: Mechanism, result: Any, duty: bool) -> dict[str, float]:
        """The closing-time bound (:func:`design.timing.close_time_bound`, on the mold
        contact of the clamping measures) and, with ``duty``, the minimum-time plan's duty
        (:func:`design.timing.planned_duty`) of the plant ``toggle plan`` takes for the
        design's preset (:func:`controllers.plans.plan_config`: the exact inverse of the
        plant's force for the contact; analyse_clamping's, the paper's linearised Eq 25,
        lands 5 um away on the SM-55). StallError where the motor cannot close it."""
        from design.timing import close_time_bound
        from toggle.plant import PlantConfig
        out = {"close_time": close_time_bound(PlantConfig(mech, x_contact=result.x_contact),
                                              self._limits, mech.clamp.x_open, result.x_final)}
        return {**out, **self._duty(mech)} if duty else out

    def _duty(self, mech: Mechanism) -> dict[str, float]:
        """:func:`design.timing.planned_duty` of ``mech`` with the targets' dwells;
        StallError where the planner finds no stroke."""
        from controllers.plans import PlanningError, plan_config
        from design.timing import planned_duty
        settings = self.targets.settings
        try:
            return planned_duty(plan_config(mech), self._limits, settings["hold"],
                                settings["eject"])
        except PlanningError as exc:
            raise StallError(f"the planner finds no stroke: {exc}") from exc

    def close_duty(self, values: Mapping[str, float], x_open: float) -> dict[str, float]:
        """The closing stroke's time bound and the planned duty (:data:`DUTY_MEASURES`) of a
        feasible candidate opening at ``x_open``."""
        mech = self.mechanism(values, x_open=x_open)
        return self._timing(mech, analyse_clamping(mech), True)

    @property
    def plans_duty(self) -> bool:
        """The preset has what the planner needs (clamp, drive, masses)."""
        return all(self._has(n) for n in ("clamp", "drive", "dynamics"))

    def with_duty(self, e: Evaluation) -> Evaluation:
        """A feasible evaluation with its planned duty (stroke and molding cycle) among its metrics
        (:data:`DUTY_MEASURES`; NaN where the planner finds no stroke): what the front's
        designs get when the search did not weigh it."""
        try:
            duty = self._duty(self.mechanism(e.variables, x_open=e.metrics["x_open"]))
        except StallError:
            duty = dict.fromkeys(DUTY_MEASURES, math.nan)
        return replace(e, metrics={**e.metrics, **duty})


def objective_matrix(evaluations: Sequence[Evaluation], keys: Sequence[str]) -> np.ndarray:
    """Objectives as minimised values (maximised ones negated); NaN where not measured."""
    sense = np.array([OBJECTIVES[k].sense for k in keys], dtype=float)
    raw = np.array([[e.metrics.get(k, math.nan) for k in keys] for e in evaluations],
                   dtype=float).reshape(len(evaluations), len(keys))
    return -sense * raw

