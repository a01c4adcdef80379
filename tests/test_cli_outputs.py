"""``toggle``'s one results folder (docs/cli.md, "Outputs and errors"): every command that writes
files names the folder and the files on its last line; figure kinds write into the
``--out`` folder (default figures) and refuse existing outputs before the work, as do
``build-fmu`` and ``design``."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest
from cli_fuzz import run_command

from toggle.files import atomic_path, results_line, take_written
from toggle_cli import main

ROOT = Path(__file__).resolve().parent.parent


answer = functools.partial(run_command, main)  # (argv, capsys) -> (code, stdout, stderr)


@pytest.mark.parametrize("files, line", [
    (["figures/kinematics.png"], "results in figures/ (kinematics.png)"),
    (["out/plan.csv", "out/cycle.csv", "duty.png"],
     "results in ./ (out/plan.csv, out/cycle.csv, duty.png)"),
    (["sm/pareto.csv", *(f"sm/presets/design-{i}.toml" for i in range(5)), "sm/front.png"],
     "results in sm/ (pareto.csv, presets/, front.png)"),
])
def test_the_results_line_names_one_folder_and_what_is_in_it(files, line) -> None:
    assert results_line([Path(f) for f in files]) == line


def test_atomic_writes_are_what_the_results_line_names(tmp_path: Path) -> None:
    take_written()
    for name in ("a.csv", "b.png"):
        with atomic_path(tmp_path / name) as tmp:
            tmp.write_text("x")
    assert take_written() == [tmp_path / "a.csv", tmp_path / "b.png"]
    assert take_written() == []


def test_a_figure_kind_names_its_folder_last_and_json_keeps_stdout(tmp_path: Path,
                                                                   capsys) -> None:
    code, out, _ = answer(["plot", "kinematics", "--out", str(tmp_path)], capsys)
    assert code == 0 and out == f"results in {tmp_path}/ (kinematics_chang2021.png)\n"
    code, out, err = answer(["tolerance", "--samples", "0", "--json"], capsys)
    assert code == 0 and json.loads(out) and "results in" not in err  # wrote nothing


@pytest.fixture
def no_planning(monkeypatch):
    import controllers.planner as planner  # toggle plan loads it when it runs
    import toggle_cli.plan_setup as plan_setup

    monkeypatch.setattr(planner, "planner_for", lambda *a, **k: pytest.fail("solved first"))
    monkeypatch.setattr(plan_setup, "trade_off_curves",
                        lambda *a, **k: pytest.fail("planned first"))


@pytest.mark.parametrize("argv, name", [
    (["plot", "trade-off", "--points", "2"], "trade_off_chang2021.png"),
    (["plot", "plan", "{tmp}/plan.csv"], "plan_lin2003_sm55.png"),  # its header's preset
])
def test_plan_figures_go_into_the_folder_and_refuse_an_existing_one_first(
        argv, name, tmp_path: Path, capsys, no_planning) -> None:
    (tmp_path / "plan.csv").write_text('# preset = "lin2003_sm55"\n')
    argv = [arg.format(tmp=tmp_path) for arg in argv]
    (tmp_path / name).write_text("mine\n")
    code, _, err = answer([*argv, "--out", str(tmp_path)], capsys)
    assert code == 2 and err.strip().endswith(
        f"--out {tmp_path / name}: exists; give --force to replace it")
    assert (tmp_path / name).read_text() == "mine\n"
    code, _, err = answer([*argv, "--out", str(tmp_path / "x.png")], capsys)
    assert code == 2 and "names a file; --out is the folder" in err


def test_plot_plan_refuses_a_profile_in_mm(tmp_path: Path, capsys) -> None:
    columns = ("time [s],position [m],velocity [m/s],acceleration [m/s^2],input_force [N],"
               "platen_position [m]")
    csv = tmp_path / "mm.csv"
    csv.write_text(columns + "\n" + "".join(f"{t / 10},{-3.4 + 5 * t},1,0,1,0\n"
                                            for t in range(11)))
    code, _, err = answer(["plot", "plan", str(csv), "--out", str(tmp_path)], capsys)
    assert code == 2 and f"profile {csv}: its positions span -3.4 to 46.6 m" in err
    assert "positions are in m" in err and not (tmp_path / "plan_chang2021.png").exists()


def test_plot_plan_refuses_a_plan_cut_short_naming_it(tmp_path: Path, capsys) -> None:
    columns = ("time [s],position [m],velocity [m/s],acceleration [m/s^2],input_force [N],"
               "platen_position [m]")
    csv = tmp_path / "cut.csv"
    csv.write_text("# duration = 0.5\n" + columns + "\n" + "".join(
        f"{t / 1000},{-3.4e-3 + 1e-5 * t},0.01,0,1,0\n" for t in range(301)))
    code, _, err = answer(["plot", "plan", str(csv), "--out", str(tmp_path)], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert (f"profile {csv}: truncated: its samples end at 0.3 s, its header says duration = "
            "0.5 s") in err and not (tmp_path / "plan_chang2021.png").exists()


def test_plot_clamp_writes_into_figures_by_default(tmp_path: Path, monkeypatch,
                                                   capsys) -> None:
    monkeypatch.chdir(tmp_path)
    code, out, _ = answer(["plot", "clamp", "--mu", "0.1"], capsys)
    assert code == 0 and out.rstrip().splitlines()[-1].startswith("results in figures/ (fig4")
    assert sorted(p.name for p in (tmp_path / "figures").iterdir())[0] == (
        "fig4_tiebar_force_lin2003_sm55.png")  # the command's default preset


def test_build_fmu_refuses_an_existing_fmu_before_the_build(tmp_path: Path, monkeypatch,
                                                            capsys) -> None:
    import fmu_src.build as build  # toggle build-fmu loads it when it runs
    import fmu_src.native_build as native

    monkeypatch.setattr(build, "build_fmu", lambda *a, **k: pytest.fail("built first"))
    monkeypatch.setattr(native, "build_native_fmu", lambda out, *a: out / "ToggleClampNative.fmu")
    (tmp_path / "ToggleClamp.fmu").write_bytes(b"PK mine")
    code, _, err = answer(["build-fmu", "--out", str(tmp_path)], capsys)
    assert code == 2 and err.strip().endswith(
        f"--out {tmp_path / 'ToggleClamp.fmu'}: exists; give --force to replace it")
    code, out, _ = answer(["build-fmu", "--out", str(tmp_path), "--native"], capsys)
    assert code == 0 and "ToggleClampNative.fmu" in out  # another file: not refused


def test_design_refuses_a_finished_search_before_searching(tmp_path: Path, monkeypatch,
                                                            capsys) -> None:
    import design.search

    monkeypatch.setattr(design.search, "run_search", lambda *a, **k: pytest.fail("searched"))
    (tmp_path / "pareto.csv").write_text("mine\n")
    code, _, err = answer(["design", str(ROOT / "design/examples/sm55.toml"), "--out",
                           str(tmp_path)], capsys)
    assert code == 2 and err.strip().endswith(
        f"--out {tmp_path / 'pareto.csv'}: exists; give --force to replace it")
