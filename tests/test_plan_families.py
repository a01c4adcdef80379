"""Why docs/design-runs.md's rig row of the SM-55 flipped with 4 um of open position (issue 46):
``hil run`` drives the planner's minimum-peak plan of the preset, and for the SM-55 (opened
to the targets' mold stroke, x_open = -69.954 mm) that problem has two families of local
optima whose peaks are 0.24 % apart and whose RMS input forces are 5 % apart. Which one
the planner's starts land in changes with a micrometre of x_open, and the rig's RMS force,
opening pull and toggle force with it; the rig's physics, driven by one plan, moves
smoothly (docs/design-runs.md). A claim on the rig's figures therefore holds only where it
holds across such perturbations (docs/design_report.py)."""

from __future__ import annotations

from pathlib import Path

from controllers.limits import drive_limits
from controllers.planner import default_duration, planner_for
from controllers.plans import plan_config
from controllers.stroke_problem import objective_weights
from design.objectives import Evaluator
from design.output import write_preset
from design.placement import open_to_stroke, reference_designs
from design.targets import load_targets

ROOT = Path(__file__).resolve().parents[1]


def test_the_sm55_minimum_peak_plan_has_two_families_of_unlike_rms_force(tmp_path):
    """From the planner's polynomial guess and late S-curves stretched 1 to 2 times, the
    SM-55 reference's plans of the default duration reach peaks within 0.5 % of each other
    (the objective barely tells them apart) but RMS input forces more than 4 % apart (the
    rig's F_F(rms) and opening pull follow the plan)."""
    targets = load_targets(ROOT / "design" / "examples" / "sm55.toml")
    evaluator = Evaluator(targets)
    (values,) = reference_designs(targets).values()
    placed = evaluator(evaluator.vector(open_to_stroke(
        evaluator, values, targets.targets["mold_open_stroke"])))
    preset = write_preset(tmp_path / "sm55_reference.toml", targets, placed)
    cfg = plan_config(str(preset))
    planner = planner_for(cfg, drive_limits(cfg.mechanism))
    duration = default_duration(planner)
    weights = objective_weights("peak")
    plans = [planner.solve(duration, warm=False)]
    for stretch in (1.0, 1.05, 1.1, 1.6, 2.0):
        plan, ok = planner._run(weights, (duration, duration), planner.force_limit, "peak",
                                None, False, guess=planner._late_guess(duration, stretch))
        if ok:
            plans.append(plan)
    peaks = [planner.worst_peak(p) for p in plans]
    rms = [p.rms_force for p in plans]
    assert max(peaks) / min(peaks) - 1 < 0.005
    assert max(rms) / min(rms) - 1 > 0.04
