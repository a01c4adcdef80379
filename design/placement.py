"""Existing designs against a front: the seed papers' clamps as candidates of the same
problem, and which front design dominates each, by how much.

A reference design is the base preset itself, or every group of a preset family (seed
004's parameter groups). It is evaluated by the same :class:`Evaluator` as the search's
candidates. "By how much" is the dominating design's least relative improvement over the
reference across the objectives (every objective at least that much better); of several
dominating designs the one with the largest least improvement is named. Only designs with
an equal or longer mold (platen) stroke than the reference's are set against it.

:func:`compare` sets one design against a reference the way a reviewer accepts: both opened
by the same rule (just far enough for the same mold stroke), at the same clamp force, with
every objective and every constraint side by side.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from scipy.optimize import brentq

from design.objectives import CONSTRAINTS, MEASURES, Evaluation, Evaluator, half_dims
from design.targets import DESIGN_LIMITS, OBJECTIVES, TARGETS, Targets
from toggle.kinematics import half_pose, stroke_limits
from toggle.params import Mechanism, load_preset, preset_groups, split_group
from toggle.study import angle_measures


def design_values(mech: Mechanism, alpha_open: float | None = None) -> dict[str, float]:
    """The design variables of a (symmetric) mechanism's lower half; the opening angle
    from ``alpha_open``, else from its clamp's open position, else its kinematic one."""
    dims = mech.lower
    x_open, x_toggle = stroke_limits(dims)
    if alpha_open is None:
        if mech.clamp is not None and mech.clamp.x_open is not None:
            x_open = mech.clamp.x_open
        alpha_open = float(half_pose(x_open, dims).theta4 - half_pose(x_toggle, dims).theta4)
    return {"d": dims.r1 - dims.r2, "r3": dims.r3, "r4a": dims.r4a, "r4b": dims.r4b,
            "alpha4": dims.alpha4, "r5": dims.r5, "e": dims.e, "alpha_open": alpha_open}


def reference_designs(targets: Targets) -> dict[str, dict[str, float]]:
    """The base preset's design, or each group's of a family, by name. An opening angle
    held fixed by the bounds is the references' too (seed 004 compares over one range)."""
    lo, hi = targets.bounds["alpha_open"]
    fixed = lo if lo == hi else None
    family, group = split_group(targets.preset)
    groups = preset_groups(family) if group is None else []
    if not groups:
        mech = load_preset(targets.preset)
        return {mech.name: design_values(mech, fixed)}
    return {f"{family}/{g}": design_values(load_preset(family, group=g), fixed)
            for g in groups}


@dataclass(frozen=True)
class Placement:
    """Where one reference design stands against a front."""

    name: str
    reference: Evaluation
    dominated_by: Evaluation | None
    margin: float  # least relative improvement of dominated_by over the reference (1)
    improvements: dict[str, float]  # per objective, relative (positive is better)
    #: for one on the front: the front design nearest to dominating it, and its largest
    #: relative loss (how much that design would have to gain to dominate it)
    nearest: Evaluation | None = None
    shortfall: float = 0.0

    @property
    def status(self) -> str:
        if not self.reference.feasible:
            return f"infeasible ({self.reference.reason})"
        return "dominated" if self.dominated_by is not None else "on the front"


def improvements(design: Evaluation, reference: Evaluation, keys: Sequence[str]
                 ) -> dict[str, float]:
    """Relative improvement of ``design`` over ``reference`` per objective (> 0 better)."""
    out = {}
    for k in keys:
        a, b, sense = design.metrics[k], reference.metrics[k], OBJECTIVES[k].sense
        out[k] = sense * (a - b) / max(abs(b), 1e-300)
    return out


def place(targets: Targets, front: Sequence[Evaluation],
          references: dict[str, dict[str, float]] | None = None) -> list[Placement]:
    """Each reference design evaluated and placed against ``front``."""
    evaluator = Evaluator(targets)
    keys = targets.objectives
    out = []
    for name, values in (references or reference_designs(targets)).items():
        ref = evaluator(evaluator.vector(values))
        best, margin, gains = None, -math.inf, {}
        nearest, shortfall = None, math.inf
        if all(math.isfinite(ref.metrics.get(k, math.nan)) for k in keys):
            stroke = ref.metrics.get("platen_stroke", -math.inf)
            for design in front:  # compared at an equal or longer mold stroke only
                if design.metrics.get("platen_stroke", math.inf) < stroke * (1 - 1e-9):
                    continue
                gain = improvements(design, ref, keys)
                least = min(gain.values())
                dominates = least >= 0 and max(gain.values()) > 0
                if dominates and least > margin:
                    best, margin, gains = design, least, gain
                if not dominates and -least < shortfall:
                    nearest, shortfall = design, -least
        if best is not None:
            nearest, shortfall = None, 0.0
        out.append(Placement(name, ref, best, margin if best else 0.0, gains, nearest,
                             shortfall if nearest else 0.0))
    return out


def open_to_stroke(evaluator: Evaluator, values: dict[str, float], stroke: float
                   ) -> dict[str, float]:
    """``values`` with the opening angle at which the platen stroke is ``stroke`` (the rule
    both sides of a comparison open by; a hair over, so the stroke target is met)."""
    dims = half_dims(evaluator.values(evaluator.vector(values)))
    want = stroke * (1 + 1e-9)

    def short(alpha: float) -> float:
        return float(angle_measures(dims, [alpha]).platen_stroke[-1]) - want

    lo, hi = evaluator.targets.bounds["alpha_open"]
    lo, hi = min(lo, values["alpha_open"]) / 4, max(hi, values["alpha_open"])
    return dict(values, alpha_open=brentq(short, lo, hi, xtol=1e-14))


@dataclass(frozen=True)
class Row:
    """One line of a comparison: ``better`` +1 higher, -1 lower; ``limit`` for a
    constraint (None for an objective)."""

    key: str
    unit: str
    better: int
    reference: float
    design: float
    limit: float | None = None

    @property
    def change(self) -> float:
        """Relative change of the design against the reference (signed, not by sense)."""
        return (self.design - self.reference) / max(abs(self.reference), 1e-300)

    @property
    def verdict(self) -> str:
        gain = self.better * self.change
        return "wins" if gain > 1e-9 else "loses" if gain < -1e-9 else "equal"


#: A constraint's measured quantity where its key is not one (targets on the geometry).
_MEASURED = {"mold_open_stroke": "platen_stroke", "max_link_ratio": "link_ratio"}


def compare(evaluator: Evaluator, design: dict[str, float], reference: dict[str, float],
            stroke: float) -> tuple[Evaluation, Evaluation, list[Row], list[Row]]:
    """The design and the reference, both opened to ``stroke`` and evaluated alike: their
    evaluations and the rows of every objective and every constraint measured on both."""
    ref = evaluator(evaluator.vector(open_to_stroke(evaluator, reference, stroke)))
    des = evaluator(evaluator.vector(open_to_stroke(evaluator, design, stroke)))
    if "close_time" in ref.metrics and "close_time" in des.metrics:  # the motor's duty too
        for e in (ref, des):
            e.metrics.update(evaluator.close_duty(e.variables, e.metrics["x_open"]))
    objectives = [Row(k, o.unit, o.sense, ref.metrics[k], des.metrics[k])
                  for k, o in OBJECTIVES.items() if k in ref.metrics and k in des.metrics]
    limits = []
    for c in CONSTRAINTS:
        key = _MEASURED.get(c, c)
        if c not in evaluator.active or key not in ref.metrics or key not in des.metrics:
            continue
        if c in DESIGN_LIMITS:
            lim = DESIGN_LIMITS[c]
            unit, most, limit = lim.unit, lim.most, evaluator.limits[c]
        else:
            unit, most = MEASURES.get(key, TARGETS[c][0]), c != "mold_open_stroke"
            limit = evaluator.targets.targets[c]
        limits.append(Row(c, unit, -1 if most else 1, ref.metrics[key], des.metrics[key],
                          limit))
    return des, ref, objectives, limits
