"""The front door's findings of issue 47, each as a user meets it: one build folder for
``toggle build-fmu`` and ``hil run``, files that carry their preset, the port and file
errors in words with exit 2 before the work, lengths with a unit, help defaults with
their unit, angles wrapped, the linkage figure's words, ``hil emulate``'s exit on SIGINT."""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from cli_fuzz import run_command

from hil.cli.main import main as hil_main
from toggle.args import HelpFormatter, length
from toggle_cli import main as toggle_main

ROOT = Path(__file__).resolve().parent.parent
CHANG_STROKE = (-3.4386e-3, 51.5661e-3)  # m, toggle kinematics --preset chang2021


def fake_fmu(path: Path, preset: str) -> Path:
    """A zip whose modelDescription.xml names the preset as the project's FMUs do."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("modelDescription.xml", (
            '<fmiModelDescription fmiVersion="2.0" modelName="ToggleClamp"><ModelVariables>'
            f'<ScalarVariable name="preset" causality="parameter"><String start="{preset}"/>'
            "</ScalarVariable></ModelVariables></fmiModelDescription>"))
    return path


def profile(path: Path, peak: float, preset: str = "chang2021") -> Path:
    """A planned profile of chang2021's stroke in 0.4 s whose input force peaks at ``peak``."""
    rows = []
    for i in range(401):
        t = i * 1e-3
        x = CHANG_STROKE[0] + (CHANG_STROKE[1] - CHANG_STROKE[0]) * (1 - math.cos(
            math.pi * t / 0.4)) / 2
        rows.append(f"{t:.3f},{x:.9f},0,0,{peak * math.sin(math.pi * t / 0.4):.6f},0")
    path.write_text(f'# preset = "{preset}"\n# duration = 0.4\n'
                    "time [s],position [m],velocity [m/s],acceleration [m/s^2],"
                    "input_force [N],platen_position [m]\n" + "\n".join(rows) + "\n")
    return path


# --- lengths with a unit, help defaults with their unit --------------------------------

@pytest.mark.parametrize("text, metres", [("0.25mm", 0.25e-3), ("250um", 0.25e-3),
                                          ("0.25e-3", 0.25e-3), ("-0.5mm", -0.5e-3),
                                          ("2.5 cm", 25e-3), ("250\u00b5m", 0.25e-3)])
def test_a_length_takes_metres_or_a_unit(text: str, metres: float) -> None:
    assert length(-1.0, 1.0, "within 1 m")(text) == pytest.approx(metres, rel=1e-12)


@pytest.mark.parametrize("text", ["0.25kg", "mm", "inf", "nan", "", "1..2mm", "2m"])
def test_a_length_that_is_none_or_out_of_range_is_refused(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        length(-1.0, 1.0, "within 1 m")(text)


def test_length_options_take_units_on_both_command_lines(capsys) -> None:
    code, out, _ = run_command(toggle_main, ["asymmetry", "--delta-r8", "0.5mm", "--json"],
                               capsys)
    assert code == 0 and '"delta_r8": 0.0005' in out.replace(" ", "").replace(":", ": ")
    code, _, err = run_command(hil_main, ["run", "--delta-r8", "-5.5mm", "--speed", "5e-3"],
                               capsys)
    assert code == 2 and "below 5 mm" in err  # -5.5 mm, read as such, out of range


def _numeric_defaults(parser: argparse.ArgumentParser, prog: str):
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for name, sub in action.choices.items():
                yield from _numeric_defaults(sub, f"{prog} {name}")
        elif (action.option_strings and isinstance(action.default, float)
              and action.help not in (None, argparse.SUPPRESS)):
            yield prog, action


def test_every_help_default_of_a_quantity_prints_its_unit() -> None:
    """A float default is a quantity: its help says the unit after the number (``(default:
    0.005 m/s)``, ``(default 0.5e-3 m)``), or it is a ratio or a probability."""
    from hil.cli.main import build_parser as hil_parser
    from toggle_cli import build_parser as toggle_parser

    dimensionless = ("probability", "P(", "weight", "friction", "default: the")
    for prog, parser in (("toggle", toggle_parser()), ("hil", hil_parser())):
        for where, action in _numeric_defaults(parser, prog):
            text = HelpFormatter(prog)._get_help_string(action) % {  # noqa: SLF001
                **vars(action), "prog": prog}
            if any(word in text for word in dimensionless):
                continue
            tail = text[text.index("default"):]
            assert any(unit in tail for unit in (" m", " s", " N", " deg", " rpm")), (
                where, action.option_strings, text)


# --- the build folder -------------------------------------------------------------------

def test_build_fmu_writes_the_build_folder_and_names_it_last(tmp_path: Path, monkeypatch,
                                                              capsys) -> None:
    import fmu_src.build as build

    monkeypatch.setattr(build, "build_folder", lambda: tmp_path / "build")
    monkeypatch.setattr(build, "build_fmu", lambda out, preset: fake_fmu(
        Path(out) / "ToggleClamp.fmu", preset))
    code, out, _ = run_command(toggle_main, ["build-fmu", "--preset", "lin2003_sm55"], capsys)
    assert code == 0 and out == f"results in {tmp_path / 'build'}/ (ToggleClamp.fmu)\n"
    assert build.fmu_preset(tmp_path / "build" / "ToggleClamp.fmu") == "lin2003_sm55"


def test_hil_run_takes_the_fmu_built_last_with_its_preset(tmp_path: Path, monkeypatch) -> None:
    import fmu_src.build as build
    from hil.host.backends import default_fmu_path
    from hil.host.run_settings import resolve_settings

    monkeypatch.setattr(build, "build_folder", lambda: tmp_path)
    fake_fmu(tmp_path / "ToggleClamp.fmu", "lin2003_sm55")
    args = argparse.Namespace(config=None, json=False, quiet=True, force_limit=2e4,
                              speed=5e-3)
    s = resolve_settings(args)
    assert s.preset == "lin2003_sm55" and s.fmu is None
    assert default_fmu_path(s.preset) == tmp_path / "ToggleClamp.fmu"  # the one just built
    # another preset asked for: its own FMU, not the one built last
    assert default_fmu_path("chang2021") == tmp_path / "chang2021" / "ToggleClamp.fmu"


def test_an_fmu_of_another_preset_is_refused_before_the_work(tmp_path: Path, capsys) -> None:
    fmu = fake_fmu(tmp_path / "chang.fmu", "chang2021")
    code, _, err = run_command(hil_main, ["run", "--fmu", str(fmu), "--preset",
                                          "lin2003_sm55", "--speed", "5e-3"], capsys)
    assert code == 2 and err.strip() == (
        f"hil run: error: --fmu {fmu}: built for preset chang2021, not lin2003_sm55; drop "
        "--preset to run it, or drop --fmu to run lin2003_sm55's own FMU (built when missing)")


def test_a_profile_whose_peak_exceeds_a_given_force_limit_is_refused_before_the_run(
        tmp_path: Path, capsys) -> None:
    plan = profile(tmp_path / "sm.csv", peak=1172.0)
    code, _, err = run_command(hil_main, ["run", "--profile", str(plan), "--force-limit",
                                          "400"], capsys)
    assert code == 2 and "planned peak input force is 1172 N, above --force-limit 400 N" in err
    assert "at least 1172 N" in err and len(err.strip().splitlines()) == 1


def test_the_simulated_rig_at_the_default_limit_takes_the_limit_its_plan_needs(
        tmp_path: Path, capsys) -> None:
    from hil.host.run_settings import resolve_settings

    plan = profile(tmp_path / "sm.csv", peak=1172.0)
    args = argparse.Namespace(config=None, json=False, quiet=True, profile=plan)
    s = resolve_settings(args)
    assert s.force_limit == 1460.0 and not s.force_limit_given  # 1.25 x 1172 N, 3 digits
    assert "force limit 1460 N, 1.25 x the plan's peak 1172 N" in capsys.readouterr().err
    small = profile(tmp_path / "small.csv", peak=100.0)
    assert resolve_settings(argparse.Namespace(config=None, json=False, quiet=True,
                                               profile=small)).force_limit == 400.0


# --- a plan's header, figures named after their preset -----------------------------------

def test_plot_plan_takes_the_preset_of_the_profile(tmp_path: Path, capsys) -> None:
    plan = profile(tmp_path / "plan.csv", peak=50.0, preset="chang2021")
    code, _, err = run_command(toggle_main, ["plot", "plan", str(plan), "--preset",
                                             "lin2003_sm55", "--out", str(tmp_path)], capsys)
    assert code == 2 and "planned with preset = 'chang2021', but --preset gives" in err
    text = plan.read_text().replace('"chang2021"', '"lin2003_sm55"')
    (tmp_path / "sm.csv").write_text(text)  # 0.4 s: too short for the SM-55's stroke
    code, _, err = run_command(toggle_main, ["plot", "plan", str(tmp_path / "sm.csv"),
                                             "--out", str(tmp_path)], capsys)
    assert code == 2 and "the stroke of 180.1 mm needs at least" in err  # the SM-55's


def test_figures_of_two_presets_sit_side_by_side(tmp_path: Path, capsys) -> None:
    for preset in ("chang2021", "lin2003_sm55"):
        code, out, _ = run_command(toggle_main, ["plot", "linkage", "--preset", preset,
                                                 "--out", str(tmp_path)], capsys)
        assert code == 0 and out == f"results in {tmp_path}/ (linkage_{preset}.png)\n"


# --- errors in words, exit 2 before the work ----------------------------------------------

@pytest.mark.parametrize("port, words", [
    ("/dev/null", "is a mem device, not a serial port"),
    ("spy://nonexistent", "no such device"),
    ("{tmp}", "is a folder, not a serial device"),
    ("{tmp}/file", "is a file, not a serial device"),
])
def test_a_port_that_is_no_serial_port_is_refused_in_words(port: str, words: str,
                                                           tmp_path: Path, capsys) -> None:
    (tmp_path / "file").write_text("")
    port = port.format(tmp=tmp_path)
    for argv in (["rig", "status", "--port", port],
                 ["run", "--real", "--port", port, "--speed", "5e-3"]):
        code, _, err = run_command(hil_main, argv, capsys)
        assert code == 2 and err.strip().endswith(
            f"--port {port}: {words} (a serial device such as /dev/ttyACM0, the pty hil "
            "emulate printed, or socket://host:port)"), err


def test_input_files_are_refused_in_the_projects_words(tmp_path: Path, capsys) -> None:
    (tmp_path / "empty.toml").write_text("")
    (tmp_path / "binary.toml").write_bytes(b"preset = 'x'\n\xff\xfe")
    for argv, said in (
            (["plot", "plan", "nosuch.csv"], "profile nosuch.csv: no such file"),
            (["design", "nosuch.toml"], "targets file nosuch.toml: no such file"),
            (["design", str(tmp_path / "empty.toml")], "empty.toml: is empty; it needs"),
            (["design", str(tmp_path / "binary.toml")],
             "not UTF-8 text (line 2, column 1: byte 0xff)"),
            (["plot", "kinematics", "--out", str(tmp_path / ("n" * 315))],
             "a name of 315 characters; the file system takes at most 255")):
        code, _, err = run_command(toggle_main, argv, capsys)
        assert code == 2 and said in err and "Errno" not in err, (argv, err)


def test_tables_takes_out_and_its_old_name(capsys) -> None:
    code, _, err = run_command(toggle_main, ["tables", "--out", "a", "--plot", "b"], capsys)
    assert code == 2 and "give --out DIR alone (--plot is its old name)" in err


# --- angles, the linkage figure ------------------------------------------------------------

@pytest.mark.parametrize("preset", ["chang2021", "lin2003_sm55"])
def test_kinematics_json_wraps_every_angle(preset: str, capsys) -> None:
    import json

    code, out, _ = run_command(toggle_main, ["kinematics", "--preset", preset, "--json"],
                               capsys)
    data = json.loads(out)
    angles = [data["theta8_toggle"], *(h["platen_link_angle_toggle"]
                                       for h in data["halves"].values())]
    assert code == 0 and all(-math.pi < a <= math.pi for a in angles), angles
    lower, upper = (data["halves"][h]["platen_link_angle_toggle"] for h in ("lower", "upper"))
    assert lower == pytest.approx(-upper, abs=1e-12)  # mirror images: no whole turn apart


def test_the_linkage_says_where_the_halves_cross_the_axis() -> None:
    from toggle.linkage import axis_crossings, crossing_note, stroke_ends
    from toggle.params import load_preset

    sm55 = load_preset("lin2003_sm55")
    crossed = dict(axis_crossings(sm55, stroke_ends(sm55)[0]))
    assert set(crossed) == {"E", "B"} and crossed["E"] == pytest.approx(8.99e-3, abs=1e-4)
    assert "cross the clamp axis (by 9.0 mm)" in crossing_note(list(crossed.items()))
    chang = load_preset("chang2021")
    assert not any(axis_crossings(chang, x) for x in stroke_ends(chang))


def test_the_moving_platen_is_numbered_inside_the_view() -> None:
    from toggle.linkage import draw_linkage
    from toggle.params import load_preset
    from toggle.plots import plt

    fig, ax = plt.subplots()
    try:
        draw_linkage(ax, load_preset("lin2003_sm55"), -0.07)
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        nines = [t for t in ax.texts if t.get_text() == "9"]
        assert len(nines) == 1
        x, y = nines[0].xy
        assert x0 < x < x1 and y0 < y < y1
    finally:
        plt.close(fig)


def test_design_axes_are_words_with_display_units() -> None:
    from design.figures import axis_label

    assert axis_label("thrust_peak") == "peak crosshead thrust (kN)"
    assert axis_label("link_stress") == "peak link stress (MPa)"
    assert axis_label("installation_length") == "installation length (mm)"
    assert axis_label("transmission_angle") == "least transmission angle (deg)"


# --- hil emulate, stopped as a shell's background job ---------------------------------------

@pytest.mark.real_time  # a signal sent to a serving emulator
def test_hil_emulate_sent_sigint_as_a_background_job_exits_130() -> None:
    """A shell starts a background job with SIGINT ignored; ``kill -INT`` still stops the
    emulator, which exits 130 as README's convention says (it exited 0)."""
    def as_background_job() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    proc = subprocess.Popen([sys.executable, "-m", "hil.cli", "emulate"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=as_background_job, env={**os.environ})
    try:
        assert proc.stdout.readline().startswith("/dev/")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    # serving: "hil emulate: interrupted by SIGINT; the emulated rig is closed"; a signal
    # between the port's line and the serving (a loaded machine): hil's own early handler
    assert err.strip().splitlines()[-1].startswith(("hil emulate: interrupted by SIGINT",
                                                    "hil: interrupted by SIGINT")), err
