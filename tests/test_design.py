"""toggle design (issue 29): the evaluator against the one model, infeasible candidates as
constraints, targets errors by key, the store's resume, presets the other commands take,
the Pareto output, and seed 004's groups and seed 001's SM-55 against the front."""

from __future__ import annotations

import copy
import csv
import io
import json
import math
import re
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controllers.limits import drive_limits
from design.objectives import Evaluator, half_dims
from design.output import write_preset
from design.placement import design_values, place, reference_designs
from design.search import pareto_front, run_search
from design.targets import OBJECTIVES, VARIABLES, load_targets, targets_from_dict
from design.timing import close_time_bound
from toggle.elastics import analyse_clamping
from toggle.kinematics import half_pose, stroke_limits
from toggle.params import ParameterError, load_preset
from toggle.plant import PlantConfig
from toggle.study import angle_grid, angle_measures, criteria
from toggle_cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "design" / "examples"
SM55, LI_MICRO = EXAMPLES / "sm55.toml", EXAMPLES / "li_micro.toml"


def cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(list(argv))
        except SystemExit as exc:
            code = int(exc.code)
    return code, out.getvalue(), err.getvalue()


def table(path: Path) -> dict:
    from toggle.params import preset_table  # a TOML file, parsed as every preset is
    return preset_table(str(path))[0]


@pytest.fixture(scope="module")
def sm55() -> tuple:
    targets = load_targets(SM55)
    evaluator = Evaluator(targets)
    ref = evaluator(evaluator.vector(design_values(load_preset("lin2003_sm55"))))
    return targets, evaluator, ref


def test_the_sm55_as_a_candidate_is_the_sm55_of_the_one_model(sm55) -> None:
    _, evaluator, ref = sm55
    mech = load_preset("lin2003_sm55")
    assert ref.feasible, ref.reason
    assert "link_clearance" not in ref.constraints  # opt-in: no default
    assert ref.metrics["link_clearance"] < 0  # its elbows cross the axis (measured always)
    assert ref.metrics["x_open"] == pytest.approx(mech.clamp.x_open, abs=1e-9)
    clamped = analyse_clamping(mech)
    assert ref.metrics["thrust_peak"] == pytest.approx(clamped.thrust_max, rel=1e-6)
    x_tp = stroke_limits(mech.lower)[1]
    stroke = float(half_pose(x_tp, mech.lower).L - half_pose(mech.clamp.x_open, mech.lower).L)
    assert ref.metrics["platen_stroke"] == pytest.approx(stroke, abs=1e-8)
    assert half_dims(ref.variables).r4c == pytest.approx(mech.lower.r4c, rel=1e-12)


def test_the_closing_time_bound_is_below_every_stroke_the_drive_can_make(sm55) -> None:
    _, evaluator, ref = sm55
    mech = evaluator.mechanism(ref.variables, x_open=ref.metrics["x_open"])
    limits = drive_limits(mech)
    result = analyse_clamping(mech)
    bound = close_time_bound(PlantConfig(mech, x_contact=result.x_contact), limits,
                             ref.metrics["x_open"], result.x_final)
    assert bound == pytest.approx(ref.metrics["close_time"], rel=1e-12)
    v, a, s = limits.velocity, limits.acceleration, ref.metrics["crosshead_stroke"]
    trapezoid = s / v + v / a  # rest to rest at the speed and acceleration limits only
    assert trapezoid < bound < 0.6258  # toggle plan --min-time: 0.6258 s (docs/design.md)


def test_seed_004_criteria_are_the_studys(sm55) -> None:
    targets = load_targets(LI_MICRO)
    evaluator = Evaluator(targets)
    for name, values in reference_designs(targets).items():
        e = evaluator(evaluator.vector(values))
        dims = load_preset(name).lower
        measures = angle_measures(dims, angle_grid(math.radians(1), math.pi / 2, 90))
        expect = criteria(measures)
        # e follows gamma0 (settings.lockup_angle): the preset's e to its 10 digits
        assert e.metrics["stroke_ratio"] == pytest.approx(expect["stroke_ratio"], rel=1e-7)
        assert e.metrics["velocity_ratio_peak"] == pytest.approx(expect["velocity_ratio"],
                                                                 rel=1e-7)
        assert e.metrics["force_amplification"] == pytest.approx(  # Eq 6, one function
            expect["force_amplification"], rel=1e-7)
        assert e.metrics["mechanical_advantage_lock"] == pytest.approx(
            measures.mechanical_advantage[0], rel=1e-7)
        assert e.feasible, (name, e.reason)  # the targets are the groups' envelope


def test_infeasible_candidates_are_constraints_with_reasons(sm55) -> None:
    _, evaluator, ref = sm55
    no_toggle = evaluator(evaluator.vector({**ref.variables, "r4b": 0.115, "r5": 0.16,
                                            "d": 0.175, "r3": 0.05, "r4a": 0.093}))
    assert no_toggle.constraints["assembly"] > 0 and "assembl" in no_toggle.reason
    far = evaluator(evaluator.vector({**ref.variables, "alpha_open": 3.0}))
    assert far.constraints["assembly"] > 1  # 1 + the shortfall of the opening angle
    weak = evaluator(evaluator.vector({**ref.variables, "e": 0.0, "r4b": 0.115, "r5": 0.30}))
    assert not weak.feasible and weak.reason.split(":")[0] in weak.constraints


@settings(max_examples=25, deadline=None, derandomize=True)
@given(unit=st.lists(st.floats(0, 1), min_size=len(VARIABLES), max_size=len(VARIABLES)))
def test_every_candidate_in_the_bounds_evaluates(sm55, unit: list[float]) -> None:
    targets, evaluator, _ = sm55
    lo = np.array([targets.bounds[v][0] for v in VARIABLES])
    hi = np.array([targets.bounds[v][1] for v in VARIABLES])
    e = evaluator(lo + np.array(unit) * (hi - lo))
    assert all(math.isfinite(v) for v in e.constraints.values())
    if e.feasible:
        assert all(math.isfinite(e.metrics[k]) for k in targets.objectives)
        assert e.metrics["platen_stroke"] >= targets.targets["mold_open_stroke"]
    else:
        assert e.reason


@pytest.mark.parametrize("change, key", [
    ({"targets": {"clamp_forse": 1.0}}, "targets.clamp_forse"),
    ({"targets": {"mold_open_stroke": "long"}}, "targets.mold_open_stroke"),
    ({"objectives": ["close_time", "speed"]}, "'speed'"),
    ({"bounds": {"r3": [0.1, 0.05]}}, "bounds.r3"),
    ({"bounds": {"alpha4": [0.1, 4.0]}}, "bounds.alpha4"),
    ({"bounds": {"r3": None}}, "missing ['r3']"),
    ({"settings": {"points": 1}}, "points"),
    ({"preset": "li_micro", "objectives": ["close_time", "stroke_ratio"]}, "[clamp]"),
])
def test_a_malformed_targets_file_names_the_key(tmp_path: Path, change: dict, key: str
                                                ) -> None:
    base = table(SM55)
    for k, v in change.items():
        if isinstance(v, dict):
            base[k] = {**base.get(k, {}), **v}
            base[k] = {kk: vv for kk, vv in base[k].items() if vv is not None}
        else:
            base[k] = v
    with pytest.raises(ParameterError, match=None) as err:
        targets_from_dict(base, "t.toml")
    assert key in str(err.value)
    assert "t.toml" in str(err.value)


def test_the_cli_refuses_bad_targets_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(SM55.read_text().replace("[targets]", "[targets]\nforce = 3"))
    code, _, err = cli("design", str(bad), "--workers", "0", "--out", str(tmp_path / "o"))
    assert code == 2 and err.count("\n") == 1 and "targets.force" in err
    assert not (tmp_path / "o").exists()


def test_a_target_no_design_meets_names_the_binding_constraint(tmp_path: Path) -> None:
    text = LI_MICRO.read_text().replace("mold_open_stroke = 0.2035", "mold_open_stroke = 0.5")
    (tmp_path / "t.toml").write_text(text)
    code, _, err = cli("design", str(tmp_path / "t.toml"), "--workers", "0", "--doe", "lhs",
                       "24", "--out", str(tmp_path / "o"))
    # stderr: the search's progress lines (on a busy machine it takes over SHOW_AFTER s),
    # then the error, last
    *progress, last = err.splitlines()
    assert code == 2 and last.startswith("toggle design: error:")
    assert "mold_open_stroke binds" in last
    assert all(line.startswith("toggle design") and " done, " in line for line in progress)


def test_an_interrupted_search_resumes_where_it_stopped(tmp_path: Path) -> None:
    targets = load_targets(LI_MICRO)
    whole = run_search(targets, tmp_path / "a", doe_method="sobol", samples=16, workers=0)
    record = tmp_path / "a" / "evaluations.jsonl"
    lines = record.read_text().splitlines()
    (tmp_path / "b").mkdir()
    # a run killed after 6 results, in the middle of writing the 7th
    (tmp_path / "b" / record.name).write_text("\n".join(lines[:7]) + "\n" + lines[7][:40])
    again = run_search(targets, tmp_path / "b", doe_method="sobol", samples=16, workers=0)
    assert again.evaluated == 10 and whole.evaluated == 16
    assert [e.as_record() for e in again.evaluations] == [e.as_record()
                                                         for e in whole.evaluations]
    other = run_search(targets, tmp_path / "b", doe_method="sobol", samples=16, workers=0)
    assert other.evaluated == 0
    with pytest.raises(ParameterError, match="other targets"):
        run_search(load_targets(SM55), tmp_path / "b", doe_method="lhs", samples=2, workers=0)


def test_the_cli_writes_the_pareto_set_with_units_and_presets_the_other_commands_take(
        tmp_path: Path) -> None:
    out = tmp_path / "out"
    code, text, err = cli("design", str(LI_MICRO), "--workers", "0", "--generations", "4",
                          "--population", "16", "--out", str(out), "--json")
    assert code == 0, err
    summary = json.loads(text)
    rows = list(csv.DictReader((out / "pareto.csv").open()))
    assert len(rows) == summary["pareto"] > 0
    assert {"stroke_ratio (1)", "coping_angle_min (rad)", "r3 (m)", "alpha4 (rad)",
            "platen_stroke (m)"} <= set(rows[0])
    import pyarrow.parquet as pq
    parquet = pq.read_table(out / "pareto.parquet").to_pylist()
    assert [r["key"] for r in parquet] == [r["key"] for r in rows]
    assert parquet[0]["r3 (m)"] == float(rows[0]["r3 (m)"])
    preset = out / "presets" / f"design-{rows[0]['key'][:12]}.toml"
    mech = load_preset(str(preset))
    assert mech.lower == mech.upper == half_dims({v: float(rows[0][f"{v} ({u})"])
                                                  for v, (u, _) in VARIABLES.items()})
    code, text, err = cli("kinematics", "--preset", str(preset), "--json")
    assert code == 0, err
    assert (out / "front.png").stat().st_size > 1000


def test_a_design_preset_carries_the_clamp_drive_and_masses(sm55, tmp_path: Path) -> None:
    targets, evaluator, ref = sm55
    path = write_preset(tmp_path / "d.toml", targets, ref, name="sm55-again")
    mech = load_preset(str(path))
    base = load_preset("lin2003_sm55")
    assert (mech.drive, mech.dynamics) == (base.drive, base.dynamics)
    assert mech.clamp.x_open == pytest.approx(base.clamp.x_open, abs=1e-12)
    assert mech.clamp == replace(base.clamp, x_open=mech.clamp.x_open)
    assert mech.lower == base.lower.replace(r4c=mech.lower.r4c)
    assert mech.name == "sm55-again"
    text = path.read_text()  # the targets file named relative to the preset, not absolutely
    assert str(tmp_path) not in text and str(SM55.parent) not in text
    origin = re.search(r" for (\S+) \(key ", text).group(1)  # a path from the preset's
    assert origin == SM55.name or (path.parent / origin).resolve() == SM55.resolve()  # folder
    copy = tmp_path / "job" / "sm55.toml"  # a targets file and its run in one folder
    copy.parent.mkdir()
    copy.write_text(SM55.read_text())
    inside = write_preset(copy.parent / "out" / "d.toml", load_targets(copy), ref)
    assert "for ../sm55.toml (key" in inside.read_text()
    assert str(tmp_path) not in inside.read_text()


def test_seed_004_groups_are_on_the_front_or_dominated_by_a_named_design(tmp_path: Path
                                                                         ) -> None:
    targets = load_targets(LI_MICRO)
    result = run_search(targets, tmp_path, generations=8, population=24, workers=0)
    placements = place(targets, result.front)
    assert [p.name for p in placements] == [f"li_micro/{g}" for g in "1234567"]
    keys = targets.objectives
    for p in placements:
        stroke = p.reference.metrics["platen_stroke"]
        if p.dominated_by is None:  # no front design of an equal or longer stroke is as good
            for design in result.front:  # everywhere and better somewhere
                if design.metrics["platen_stroke"] < stroke:
                    continue
                gains = [OBJECTIVES[k].sense * (design.metrics[k] - p.reference.metrics[k])
                         for k in keys]
                assert min(gains) < 0 or max(gains) <= 0
        else:
            assert p.dominated_by.metrics["platen_stroke"] >= stroke  # a fair comparison
            assert p.margin == pytest.approx(min(p.improvements.values()))
            assert p.margin >= 0 and max(p.improvements.values()) > 0
    assert all(p.reference.feasible for p in placements)  # the targets are their envelope
    assert pareto_front(result.evaluations + [p.reference for p in placements], keys)


def test_the_sm55_design_beats_the_sm55_on_two_objectives_at_its_force_and_stroke(sm55
                                                                                  ) -> None:
    targets, evaluator, ref = sm55
    mech = load_preset(str(EXAMPLES / "sm55_design.toml"))
    design = evaluator(evaluator.vector(design_values(mech)))
    assert design.feasible, design.reason  # clamp force reached, stroke at least the SM-55's
    assert design.metrics["platen_stroke"] >= targets.targets["mold_open_stroke"]
    assert mech.clamp.final_tiebar_force == load_preset("lin2003_sm55").clamp.final_tiebar_force
    better = [k for k in targets.objectives
              if OBJECTIVES[k].sense * (design.metrics[k] - ref.metrics[k]) > 0]
    assert len(better) >= 2, better


def test_a_seed_replays_the_genetic_search_and_a_rerun_computes_nothing(tmp_path: Path
                                                                        ) -> None:
    targets = load_targets(LI_MICRO)  # four objectives: NSGA-III
    first = run_search(targets, tmp_path / "a", generations=4, population=20, seed=5,
                       workers=0)
    second = run_search(targets, tmp_path / "b", generations=4, population=20, seed=5,
                        workers=0)
    assert [e.key for e in first.evaluations] == [e.key for e in second.evaluations]
    again = run_search(targets, tmp_path / "a", generations=5, population=20, seed=5,
                       workers=0)
    assert 0 < again.evaluated <= 20  # only the new generation's candidates


def test_the_fronts_designs_get_the_planners_duty_once_and_recorded(sm55, tmp_path: Path
                                                                   ) -> None:
    """Runner.with_duty on two front designs (the SM-55 and sm55_design): each gets the
    minimum-time plan's duty that the planner finds on its written preset (plan_config: the
    contact from the clamp force, the link masses, the open position; planned_duty's cold
    start: a warm start from another plan ends 0.03 % away), the record keeps it
    (a reopened store has it; a second call plans nothing), and an infeasible-for-the-planner
    design is NaN, not an error."""
    from controllers.plans import plan_config
    from design.objectives import DUTY_MEASURES
    from design.runner import Runner
    from design.store import Store
    from design.timing import planned_duty

    targets, evaluator, ref = sm55
    design = evaluator(evaluator.vector(design_values(load_preset(
        str(EXAMPLES / "sm55_design.toml")))))
    store = Store(tmp_path, targets.digest())
    store.append([ref, design])
    with Runner(targets, store, workers=0) as runner:
        planned = runner.with_duty([ref, design])
    for e in planned:
        assert e.variables == store.get(e.key).variables
        cfg = plan_config(str(write_preset(tmp_path / f"{e.key}.toml", targets, e)))
        duty = planned_duty(cfg, drive_limits(cfg.mechanism), targets.settings["hold"],
                            targets.settings["eject"])
        for key in DUTY_MEASURES:
            assert e.metrics[key] == pytest.approx(duty[key], rel=1e-6)
        assert e.metrics["close_plan_time"] > e.metrics["close_time"]  # above the bound
    lines = store.path.read_text().count("\n")
    again = Store(tmp_path, targets.digest())
    assert [again.get(e.key).metrics for e in planned] == [e.metrics for e in planned]
    with Runner(targets, again, workers=0) as runner:
        assert runner.with_duty([ref, design]) == planned
    assert store.path.read_text().count("\n") == lines  # nothing planned again
    weak = copy.copy(evaluator)  # a motor far too small to close the clamp
    weak._limits = replace(evaluator._limits, torque=1.0)
    assert math.isnan(weak.with_duty(ref).metrics["close_rms_torque"])


def test_the_default_back_end_is_the_one_fair_share_gives_more() -> None:
    """By hand: the process gets min(1, c / (load + 1)) of a core, w workers
    0.85 w min(1, c / (load + w)); the cluster where that is over 1.05 times the process."""
    from design.runner import default_workers
    assert default_workers(2400, cores=2, load=0.2) == 2  # 1.55 against 1
    # one CPU hog: 2 x 2/3 x 0.85 = 1.13 against 1 (bench_design.py measured 1.13)
    assert default_workers(2400, cores=2, load=1.0) == 2
    assert default_workers(2400, cores=2, load=13.0) == 2  # 0.227 against 0.143
    assert default_workers(2400, cores=1, load=0.0) == 0  # 0.85 against 1
    assert default_workers(2400, cores=1, load=3.0) == 0  # 0.85 x 1/4 against 1/4
    assert default_workers(2400, cores=16, load=3.6) == 12  # the free cores: 10.2 against 1
    assert default_workers(50, cores=16, load=0.0) == 0  # too small to pay for a cluster


def test_busy_cores_sees_a_new_hog_before_the_load_average(tmp_path) -> None:
    """A hog started a moment ago: the load average still says 0.2, /proc/loadavg's count
    of runnable tasks says two (the hog and this process); the rule takes the hog."""
    from design.runner import busy_cores, default_workers
    fake = tmp_path / "loadavg"
    fake.write_text("0.20 0.10 0.05 2/180 4242\n")
    assert busy_cores(fake, average=0.2) == 1.0
    assert default_workers(2400, cores=4, load=busy_cores(fake, average=0.2)) == 3
    assert busy_cores(fake, average=3.5) == 3.5  # a load that just ended still counts
    fake.write_text("garbled\n")
    assert busy_cores(fake, average=0.7) == 0.7  # no count: the load average alone


def test_one_progress_bar_counts_the_whole_search(tmp_path: Path, monkeypatch) -> None:
    from design import runner
    bars: list[dict] = []

    class Bar:  # records what the search tells its progress
        def __init__(self, desc: str, *, unit: str, total: int, enabled: bool) -> None:
            bars.append({"total": total, "done": 0, "closed": False})

        def advance(self, n: int = 1) -> None:
            bars[-1]["done"] += n

        def close(self) -> None:
            bars[-1]["closed"] = True

    monkeypatch.setattr(runner, "Progress", Bar)
    targets = load_targets(LI_MICRO)
    run_search(targets, tmp_path, generations=2, population=12, workers=0, progress=True)
    assert bars == [{"total": 24, "done": 24, "closed": True}]  # one bar, 2 x 12 designs
    run_search(targets, tmp_path, generations=3, population=12, workers=0, progress=True)
    assert bars[1] == {"total": 36, "done": 36, "closed": True}  # the record's 24 counted


def test_a_search_off_a_terminal_writes_progress_lines(tmp_path: Path, monkeypatch,
                                                      capsys) -> None:
    """Off a terminal (a log, CI) the search said nothing for minutes: now a line with the
    count once the work has taken progress.SHOW_AFTER, then one every progress.LINE_EVERY s,
    and the last count at the end."""
    from controllers import progress
    monkeypatch.setattr(progress, "SHOW_AFTER", 0.0)
    run_search(load_targets(LI_MICRO), tmp_path, generations=2, population=12, workers=0,
               progress=True)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("toggle design")]
    # the first once SHOW_AFTER has passed; the last count at the end
    assert len(lines) == 2 and "/24 " in lines[0] and "24/24 " in lines[-1], lines
