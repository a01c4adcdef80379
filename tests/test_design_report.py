"""docs/design-runs.md replays (issue 38): its script reruns the documented command and reads the
record back without computing anything; the same seed gives the same record and the same
tables whether the record was computed in the process or on two workers; the comparison
lists every objective and constraint of a design and its reference, losses included."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from design.objectives import CONSTRAINTS, Evaluator
from design.placement import compare, design_values
from design.search import run_search
from design.targets import OBJECTIVES, load_targets
from toggle.params import load_preset

ROOT = Path(__file__).resolve().parents[1]
REDUCED = {"generations": 3, "population": 16, "seed": 3}


def _report():
    spec = importlib.util.spec_from_file_location("design_report",
                                                  ROOT / "docs" / "design_report.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _record(folder: Path) -> list[dict]:
    lines = (folder / "evaluations.jsonl").read_text().splitlines()
    return sorted((json.loads(line) for line in lines[1:]), key=lambda r: r["key"])


def test_the_report_replays_its_command_on_any_number_of_workers(tmp_path: Path) -> None:
    report = _report()
    assert report.command("li_micro", report.SEARCHES["li_micro"], ROOT / "build" / "x")[:2] \
        == ["design", "design/examples/li_micro.toml"]
    # the record computed on a local cluster of two workers, then by the documented command
    targets = load_targets(ROOT / "design" / "examples" / "li_micro.toml")
    two = run_search(targets, tmp_path / "two" / "li_micro", workers=2, **REDUCED)
    assert two.evaluated > 0
    on_two = report.seed_004(tmp_path / "two", REDUCED, figures=False)
    fresh = report.seed_004(tmp_path / "one", REDUCED, figures=False)  # in the process
    assert _record(tmp_path / "two" / "li_micro") == _record(tmp_path / "one" / "li_micro")
    body = fresh.split("```\n", 2)[-1]  # the tables, after the command line
    assert body == on_two.split("```\n", 2)[-1]
    assert "li_micro/1" in body and "in the Pareto set" in body
    again = report.seed_004(tmp_path / "one", REDUCED, figures=False)  # resumed: nothing new
    assert again == fresh


def test_a_comparison_lists_every_objective_and_constraint_losses_included() -> None:
    targets = load_targets(ROOT / "design" / "examples" / "sm55.toml")
    evaluator = Evaluator(targets)
    old = design_values(load_preset(str(ROOT / "design" / "examples" / "sm55_old_design.toml")))
    ref = design_values(load_preset("lin2003_sm55"))
    stroke = targets.targets["mold_open_stroke"]
    design, reference, objectives, limits = compare(evaluator, old, ref, stroke)
    for e in (design, reference):  # both opened by the same rule: to the same stroke
        assert e.metrics["platen_stroke"] == pytest.approx(stroke, rel=1e-8)
    assert reference.metrics["x_open"] == pytest.approx(-0.070, abs=1e-4)
    assert {r.key for r in objectives} == {k for k in OBJECTIVES if k in design.metrics}
    assert {r.key for r in limits} == {c for c in CONSTRAINTS if c in evaluator.active} - {
        "assembly", "clamp_force", "drive_thrust"}
    verdicts = {r.key: r.verdict for r in objectives + limits}
    assert verdicts["thrust_peak"] == "wins" and verdicts["transmission_angle"] == "loses"
    assert verdicts["radial_envelope"] == "loses" and verdicts["platen_side_load"] == "loses"
    row = next(r for r in objectives if r.key == "installation_length")
    assert row.change == pytest.approx(
        design.metrics["installation_length"] / reference.metrics["installation_length"] - 1)


def test_a_failed_command_stops_the_report_naming_it(capsys: pytest.CaptureFixture) -> None:
    from toggle_cli import main
    report = _report()
    with pytest.raises(SystemExit, match=r"^toggle design missing\.toml exited 2$"):
        report.run_cli(main, "toggle", ["design", "missing.toml"])
    assert "missing.toml" in capsys.readouterr().err


def test_the_rig_table_changes_are_of_the_magnitude_and_hold_only_across_offsets(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """The change is of the magnitude (a larger opening pull is positive); each preset runs
    as placed and with x_open moved by each offset (written beside the records); a change
    whose sign flips between two offsets is marked as not holding."""
    from hil.cli.run import SUMMARY_ROWS
    report = _report()
    for name in ("a", "b"):
        (tmp_path / f"{name}.toml").write_text("[clamp]\nx_open = -0.07\n")
    seen = []

    def run(main, prog, argv):
        preset = tmp_path / argv[argv.index("--preset") + 1]  # relative to ROOT
        seen.append(preset)
        moved = preset.stem != preset.stem.split("_")[0]  # F_TP flips when moved
        side = preset.stem.startswith("b")
        return json.dumps({key: {"mean": (-100.0 - 10 * side if key == "force_backward_min"
                                          else (-1.0 if moved and key == "force_toggle"
                                                else 1.0 + side))}
                           for key, *_ in SUMMARY_ROWS})

    monkeypatch.setattr(report, "run_cli", run)
    monkeypatch.setattr(report, "ROOT", tmp_path)
    table = report.rig_runs({"a": tmp_path / "a.toml", "b": tmp_path / "b.toml"}, tmp_path)
    assert len(seen) == 2 * len(report.OFFSETS)
    moved = [p for p in seen if "+100um" in p.stem]
    assert sum("printed" in p.stem for p in seen) == 2
    assert [float(p.read_text().split("x_open = ")[1]) for p in moved] == pytest.approx(
        [-0.0699, -0.0699])
    rows = {line.split(" | ")[0].strip("| "): line for line in table.splitlines()}
    assert "| +10.00 % |" in rows["F_B(min) (N)"] and rows["F_B(min) (N)"].endswith("| yes |")
    assert "| +100.00 % |" in rows["F_F(max) (N)"]
    assert "| +1000.0000 mm |" in rows["stroke error dS (mm)"]
    assert rows["F_TP (N)"].endswith("| no |")
