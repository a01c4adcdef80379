"""Each defect of issue 19, answered: bad input gets one clear line, outputs stay whole."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest
from cli_fuzz import run_command
from matplotlib.figure import Figure

from hil.cli.main import build_parser as hil_parser
from hil.cli.main import main as hil
from toggle.params import load_preset
from toggle.rig_tables import CHANG2021_READING
from toggle_cli import build_parser as toggle_parser
from toggle_cli import main as toggle


def answer(main, argv: list[str], capsys) -> tuple[int, str, str]:
    """(exit code, stdout, the last stderr line) of one in-process command."""
    code, out, err = run_command(main, argv, capsys)
    return code, out, (err.strip().splitlines() or [""])[-1]


@pytest.fixture
def regular(tmp_path: Path) -> Path:
    path = tmp_path / "regular.txt"
    path.write_text("a file, not a folder\n")
    return path


# --- unwritable outputs -----------------------------------------------------------------


def test_plan_refuses_an_unwritable_out_before_solving(monkeypatch, capsys, regular):
    import controllers.planner as planner  # toggle plan loads it when it runs

    monkeypatch.setattr(planner, "planner_for", lambda *a, **k: pytest.fail("solved first"))
    code, _, err = answer(toggle, ["plan", "--out", str(regular / "plan.csv")], capsys)
    # a refused output is a usage error (exit 2), told before the work
    assert code == 2 and err.startswith("toggle plan: error: --out") and str(regular) in err


@pytest.mark.parametrize("argv", [
    ["build-fmu", "--out", "{r}/sub"],
    ["plot", "kinematics", "--out", "{r}/sub"],
    ["plot", "asymmetry", "--out", "{r}"],
])
def test_toggle_outputs_under_a_regular_file_are_one_line(argv, capsys, regular):
    code, _, err = answer(toggle, [a.format(r=regular) for a in argv], capsys)
    assert code == 2 and "error:" in err and str(regular) in err
    assert regular.read_text() == "a file, not a folder\n"


@pytest.mark.parametrize("argv", [
    ["run", "--speed", "5e-3", "--out", "{r}/run"],
    ["rsm", "--paper-tables", "--out", "{r}/rsm"],
])
def test_hil_outputs_under_a_regular_file_are_one_line(argv, capsys, regular):
    code, _, err = answer(hil, [a.format(r=regular) for a in argv], capsys)
    assert code in (1, 2) and err.startswith(f"hil {argv[0]}: error:") and str(regular) in err


def test_a_figure_is_written_whole_or_not_at_all(monkeypatch, tmp_path):
    from toggle.plots import plt, save_figure

    def broken(fig, path, **kw):
        Path(path).write_bytes(b"\x89PNG half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", broken)
    with pytest.raises(OSError):
        save_figure(plt.figure(), tmp_path / "f.png")
    assert list(tmp_path.iterdir()) == []  # neither f.png nor the temporary file


# --- numbers ----------------------------------------------------------------------------


@pytest.mark.parametrize("argv, option", [
    (["synthesize", "--samples", "0"], "--samples"),
    (["synthesize", "--samples", "-1"], "--samples"),
    (["plot", "clamp", "--rpm", "0"], "--rpm"),
    (["plot", "clamp", "--rpm", "nan"], "--rpm"),
    (["asymmetry", "--speed", "0"], "--speed"),
    (["plot", "asymmetry", "--speed", "0"], "--speed"),
    (["plan", "--v-max", "1e-300"], "--v-max"),
    (["tolerance", "--samples", "1e308"], "--samples"),
    (["study", "--alpha-max", "nan"], "--alpha-max"),
])
def test_bad_numbers_are_usage_errors_naming_the_option(argv, option, capsys, tmp_path,
                                                        monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = answer(toggle, argv, capsys)
    assert code == 2 and f"argument {option}:" in err
    assert list(tmp_path.iterdir()) == []  # plot clamp wrote no figure before refusing


def test_both_asymmetry_commands_judge_speed_alike(capsys):
    answers = [answer(toggle, [*cmd, "--speed", "0"], capsys)[2].split("error: ")[1]
               for cmd in (["asymmetry"], ["plot", "asymmetry"])]
    assert answers[0] == answers[1]


def test_negative_e_notation_values_parse(capsys):
    code, out, _ = answer(toggle, ["asymmetry", "--delta-r8", "-0.5e-3", "--json"], capsys)
    assert code == 0 and json.loads(out)["delta_r8"] == -0.5e-3


# --- presets ----------------------------------------------------------------------------


def test_study_takes_a_group_as_its_baseline(capsys):
    code, out, _ = answer(toggle, ["study", "--preset", "li_micro/6", "--points", "5",
                                   "--json"], capsys)
    data = json.loads(out)
    assert code == 0 and data["baseline"] == "6" and len(data["groups"]) == 7


def test_study_with_no_valid_group_fails_in_degrees(capsys):
    code, _, err = answer(toggle, ["study", "--alpha-max", "170", "--points", "3"], capsys)
    assert code == 2 and "--alpha-max 170 deg" in err and "157.0 deg" in err
    code, _, err = answer(toggle, ["study", "--alpha-lock", "30", "--alpha-max", "10"], capsys)
    assert code == 2 and "got 30 and 10 deg" in err


@pytest.mark.parametrize("argv, says", [
    (["kinematics", "--preset", "dong2022"], "press"),
    (["calibrate", "--preset", "li_micro"], "measured on chang2021"),
    (["clamp", "--preset", "li_micro"], "no [clamp] section"),
    (["kinematics", "--preset", "/tmp"], "/tmp is a directory, not a preset TOML file"),
])
def test_a_preset_that_does_not_fit_says_why(argv, says, capsys):
    code, _, err = answer(toggle, argv, capsys)
    assert code == 2 and says in err


def test_help_names_the_presets_each_command_takes(capsys):
    helps = {cmd: answer(toggle, [cmd, "--help"], capsys)[1]
             for cmd in ("calibrate", "synthesize", "kinematics", "plan")}
    assert "dong2022" in helps["synthesize"] and "dong2022" not in helps["kinematics"]
    assert "measured on the chang2021 rig" in " ".join(helps["calibrate"].split())
    assert "[dynamics]" in helps["plan"]


def test_hil_run_refuses_a_preset_without_masses_by_name(capsys):
    code, _, err = answer(hil, ["run", "--preset", "li_micro"], capsys)
    assert code == 2 and "[dynamics]" in err and "give the masses" not in err


def _write_preset(path: Path, scale: float = 1.0, r3: object = None) -> Path:
    mech = load_preset("chang2021").lower
    lines = ["[half]"] + [f"{k} = {getattr(mech, k) * scale!r}" for k in
                          ("r1", "r2", "r4a", "r4b", "r4c", "r5", "e")]
    value = json.dumps(r3) if r3 is not None else repr(mech.r3 * scale)
    lines.append(f"r3 = {value}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_preset_in_mm_is_refused(tmp_path, capsys):
    code, _, err = answer(toggle, ["kinematics", "--preset",
                                   str(_write_preset(tmp_path / "mm.toml", 1e3))], capsys)
    assert code == 2 and "in metres (was it written in mm?)" in err and "mm.toml" in err


def test_a_string_in_a_preset_names_the_file_and_key(tmp_path, capsys):
    path = _write_preset(tmp_path / "text.toml", r3="0.1")
    code, _, err = answer(toggle, ["kinematics", "--preset", str(path)], capsys)
    assert code == 2 and str(path) in err and "r3 = '0.1' is not a number" in err


def test_impossible_geometry_is_said_without_reprs(capsys):
    code, _, err = answer(toggle, ["tolerance", "--x", "0.2"], capsys)
    assert code == 2 and "cannot assemble" in err
    assert not re.search(r"HalfDims\(|np\.float64\(|array\(", err)


# --- tables and messages ------------------------------------------------------------------


def test_kinematics_table_keeps_its_columns(capsys):
    code, out, _ = answer(toggle, ["kinematics", "--points", "5"], capsys)
    lines = [ln for ln in out.splitlines()[1:] if ln.strip() and not ln.startswith("(")]
    assert code == 0 and {len(ln) for ln in lines} <= {60, 72}  # 12 characters a column
    angles = [float(ln.split()[-1]) for ln in lines[1:3]]
    assert all(-180 < a <= 180 for a in angles) and angles[0] == pytest.approx(-angles[1])
    assert lines[-1].split()[-1] == "inf"  # MA at the toggle


def test_force_limit_message_names_the_force_limit(capsys):
    code, _, err = answer(toggle, ["plan", "--min-time", "--force-limit", "1",
                                   "--intervals", "10"], capsys)
    assert code == 2 and "force limit" in err and "at most 1 N" in err and "N m" not in err
    assert "lower bound" in err  # why: no stroke of any duration peaks that low


def test_calibrate_prints_units(capsys):
    code, out, _ = answer(toggle, ["calibrate", "--fit", "free_play", "--speeds", "5e-3"],
                          capsys)
    assert code == 0 and re.search(r"free_play = \S+ m$", out, re.MULTILINE)


def test_tables_rows_options_are_never_silently_unused(capsys):
    """--speeds and --statistics choose the rows of a fit: without --fit they refit the
    stroke reading alone or are refused by name, never ignored; a --fit with no force
    statistic to fit on is refused; each row's role says what informed the model shown."""
    code, _, err = answer(toggle, ["tables", "--statistics", "stroke", "--fit", "mu"], capsys)
    assert code == 2 and "mu" in err and "none is chosen" in err
    code, _, err = answer(toggle, ["tables", "--speeds", "25e-3"], capsys)
    assert code == 2 and "--fit PARAM" in err
    code, out, _ = answer(toggle, ["tables", "--statistics", "stroke", "--speeds", "25e-3",
                                   "--json"], capsys)
    assert code == 0
    data = json.loads(out)
    assert data["fit_speeds"] == [0.025] and data["fit_statistics"] == ["stroke"]
    assert data["reading"]["datum"] != pytest.approx(CHANG2021_READING.datum, rel=1e-3)
    roles = {(r["statistic"], r["speed"]): r["role"] for r in data["rows"]}
    assert roles[("stroke", 0.025)] == "fitted" and roles[("stroke", 0.005)] == "predicted"
    assert roles[("force_toggle", 0.005)] == "fitted"  # the shipped force calibration
    assert roles[("force_toggle", 0.025)] == "predicted"


def test_plan_masses_take_commas_or_words_and_refuse_a_field_twice(capsys):
    """``--masses a=1 b=2`` (words, like every other list option) was refused with the
    top-level usage ('unrecognized arguments: b=2'); a field given twice took the last."""
    from toggle_cli.plan_setup import parse_masses as _masses

    assert _masses(["platen_friction=5", "platen_rate=2"]) == _masses(
        ["platen_friction=5,platen_rate=2"]) == {"platen_friction": 5.0, "platen_rate": 2.0}
    code, _, err = answer(toggle, ["plan", "--masses", "platen_rate=1,platen_rate=2"], capsys)
    assert code == 2 and "platen_rate is given twice" in err


def test_every_option_with_a_default_shows_it(capsys):
    from cli_fuzz import commands

    from toggle.args import has_default

    for parser in (toggle_parser(), hil_parser()):
        for words, sub in commands(parser).items():
            formatter = sub._get_formatter()  # noqa: SLF001
            for action in sub._actions:  # noqa: SLF001
                if (action.option_strings and has_default(action)
                        and action.help not in (None, "==SUPPRESS==")
                        and "help" not in action.dest and action.dest != "version"):
                    text = formatter._expand_help(action)  # noqa: SLF001
                    assert "default" in formatter._get_help_string(action) or "default" in text, (
                        words, action.dest)


def test_figure_axes_use_one_unit_style(monkeypatch, tmp_path, capsys):
    labels: list[str] = []

    def collect(fig, path, **kw):
        for ax in fig.axes:
            labels.extend(t for t in (ax.get_xlabel(), ax.get_ylabel()) if t)
        Path(path).write_bytes(b"\x89PNG")

    monkeypatch.setattr(Figure, "savefig", collect)
    for argv in (["kinematics"], ["tolerance"], ["asymmetry"], ["synthesize"],
                 ["clamp", "--mu", "0.1"], ["study", "--points", "3"]):
        assert answer(toggle, ["plot", *argv, "--out", str(tmp_path)], capsys)[0] == 0
    assert len(labels) > 15
    for label in labels:
        assert re.search(r" \([^()]+\)$", label) and "[" not in label, label


def test_version_of_both_commands(capsys):
    for main, name in ((toggle, "toggle"), (hil, "hil")):
        code, out, _ = answer(main, ["--version"], capsys)
        assert code == 0 and re.fullmatch(rf"{name} \d+\.\d+\S*\n", out)


def test_piping_into_head_ends_quietly():
    code = ("import sys; from toggle_cli import main; sys.exit(main(['kinematics', "
            "'--points', '20000']))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    proc.stdout.readline()
    proc.stdout.close()  # what head does after its lines
    err = proc.stderr.read().decode()
    proc.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipe" not in err
    assert math.isfinite(proc.returncode)
