"""``hil run`` settings: every --config key honoured or refused, clear refusals, guards."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil.cli.main import main
from hil.host.recording import read_samples


def test_config_force_limit_is_honoured(tmp_path, capsys) -> None:
    cfg = tmp_path / "rig.toml"
    cfg.write_text("force_limit = 50.0\ncycles = 1\ndelta_r8 = 0.75e-3\nspeed = 25e-3\n")
    out = tmp_path / "run"
    assert main(["run", "--config", str(cfg), "--out", str(out), "--quiet"]) == 1
    assert "force limit" in capsys.readouterr().err
    force = read_samples(out / "samples.csv").force
    assert np.all(np.abs(force[:-1]) <= 50.0) and abs(force[-1]) > 50.0  # stopped at 50 N
    meta = json.loads((out / "meta.json").read_text())
    assert meta["settings"]["force_limit"] == 50.0 and meta["settings"]["cycles"] == 1
    assert meta["settings"]["delta_r8"] == 0.75e-3 and meta["aborted"]


def test_command_line_wins_over_config(tmp_path) -> None:
    cfg = tmp_path / "rig.toml"
    cfg.write_text("cycles = 5\nspeed = 40e-3\n")
    out = tmp_path / "run"
    assert main(["run", "--config", str(cfg), "--cycles", "1", "--out", str(out),
                 "--quiet"]) == 0
    meta = json.loads((out / "meta.json").read_text())
    assert meta["settings"]["cycles"] == 1 and meta["settings"]["speed"] == 40e-3


@pytest.mark.parametrize("text, message", [
    ("force_limt = 50.0\n", "unknown key(s) force_limt"),
    ('cycles = "3"\n', "cycles = '3' must be a whole number"),
    ("force_limit = true\n", "must be a number"),
    ("as_built = 1\n", "as_built = 1 must be true or false"),
    ('backend = "moon"\n', "backend"),
    ('backend = "real"\nport = "loop://"\nforce_limit = 900.0\n', "load cell"),
    ("force_limit = nan\n", "--force-limit"),
])
def test_bad_config_is_refused_by_name(tmp_path, capsys, text: str, message: str) -> None:
    cfg = tmp_path / "rig.toml"
    cfg.write_text(text)
    out = tmp_path / "run"
    assert main(["run", "--config", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["--port", "/dev/ttyACM0"], "--port needs --real"),
    (["--real"], "--real needs --port"),
    (["--cycles", "0"], "--cycles"),
    (["--mu", "nan"], "--mu"),
    (["--mu", "-1"], "--mu"),
    (["--watchdog-ms", "0"], "--watchdog-ms"),
    (["--watchdog-ms", "-5"], "--watchdog-ms"),
    (["--heartbeat-ms", "10"], "--heartbeat-ms"),
    (["--heartbeat-ms", "5000"], "--heartbeat-ms"),
    (["--x-contact", "1"], "--x-contact"),
    (["--delta-r8", "1.0"], "--delta-r8"),
    (["--speed", "0.2"], "--speed"),
    (["--speed", "1e-6"], "--max-duration"),
    (["--profile", "p.csv", "--speed", "5e-3"], "not both"),
])
def test_refused_runs_name_the_option_and_leave_nothing(tmp_path, capsys, argv, message) -> None:
    out = tmp_path / "run"
    assert main(["run", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_negative_values_in_e_notation_parse(tmp_path) -> None:
    out = tmp_path / "run"
    assert main(["run", "--delta-r8", "-0.25e-3", "--speed", "40e-3", "--cycles", "1",
                 "--out", str(out), "--quiet"]) == 0
    assert json.loads((out / "meta.json").read_text())["delta_r8"] == -0.25e-3


def test_one_cycle_prints_a_summary_with_units(tmp_path, capsys) -> None:
    assert main(["run", "--speed", "40e-3", "--cycles", "1", "--out", str(tmp_path / "r"),
                 "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "1 of 1 cycles complete" in out and "one cycle: no spread" in out
    assert " mm " in out and " N " in out


def test_long_runs_are_announced(tmp_path, capsys) -> None:
    # 8 cycles at 5 mm/s: about 2.5 min of motion; refused below that, announced above
    argv = ["run", "--speed", "5e-3", "--cycles", "8", "--out", str(tmp_path / "r")]
    assert main([*argv, "--max-duration", "60"]) == 2
    err = capsys.readouterr().err
    assert "min of motion" in err and "MB of samples" in err and "--max-duration" in err


def test_meta_records_every_setting_that_shaped_the_run(tmp_path) -> None:
    out = tmp_path / "run"
    assert main(["run", "--speed", "40e-3", "--cycles", "1", "--mu", "0.1", "--x-contact",
                 "0.045", "--force-limit", "300", "--no-as-built", "--out", str(out),
                 "--quiet"]) == 0
    meta = json.loads((out / "meta.json").read_text())
    s = meta["settings"]
    assert (s["mu"], s["x_contact"], s["force_limit"], s["backend"]) == (0.1, 0.045, 300.0,
                                                                         "fmu")
    assert s["as_built"] is False and meta["plant"]["dimensional_errors_m"] == {"r8": 0.0}
    assert meta["plant"]["backend"] == "fmu" and s["max_duration"] == 3600.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["aborted"] is False and summary["link"] == {}


def test_profile_settings_are_applied_and_clashes_refused(tmp_path, capsys) -> None:
    profile = tmp_path / "p.csv"
    x = np.linspace(-3.4386e-3, 51.5e-3, 2001)
    rows = "\n".join(f"{i * 1e-3:.6f},{xi:.9f}" for i, xi in enumerate(x))
    profile.write_text('# preset = "chang2021"\n# x_contact = 0.045\n# mu = 0.08\n'
                       f"time [s],position [m]\n{rows}\n")
    out = tmp_path / "run"  # the model's clamp: the prototype's as-built error adds ~70 N
    assert main(["run", "--profile", str(profile), "--cycles", "1", "--no-as-built", "--out",
                 str(out), "--quiet"]) == 0
    s = json.loads((out / "meta.json").read_text())["settings"]
    assert (s["x_contact"], s["mu"]) == (0.045, 0.08)
    assert len(s["profile_sha256"]) == 64
    assert main(["run", "--profile", str(profile), "--mu", "0.05", "--out",
                 str(tmp_path / "clash")]) == 2
    assert "planned with mu = 0.08" in capsys.readouterr().err
    assert not (tmp_path / "clash").exists()


def test_profile_away_from_the_start_is_approached_and_a_too_fast_one_refused(
        tmp_path, capsys) -> None:
    profile = tmp_path / "jump.csv"
    x = np.r_[np.full(10, 10e-3), np.linspace(10e-3, 11e-3, 100)]
    profile.write_text("time [s],position [m]\n" + "\n".join(
        f"{i * 1e-3:.6f},{xi:.9f}" for i, xi in enumerate(x)) + "\n")
    out = tmp_path / "run"
    # starts 13 mm from the open position: moved there at 5 mm/s first, not stepped
    assert main(["run", "--profile", str(profile), "--cycles", "1", "--out", str(out),
                 "--quiet"]) == 0
    bad = tmp_path / "bad.csv"
    bad.write_text("time [s],position [m]\n0,0.0\n0.001,0.0001\n0.002,0.0002\n")
    # invalid input, refused before anything moves: exit 2, naming the file
    assert main(["run", "--profile", str(bad), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "mm/s" in err and f"--profile {bad}:" in err
    assert not Path(tmp_path / "b").exists()


def test_a_replayed_plan_reproduces_the_planners_peak(tmp_path, capsys) -> None:
    """`toggle plan --out` carries the mold, preset and friction; `hil run --profile` uses them
    (on the clamp it was planned for: the model, --no-as-built)."""
    from toggle_cli import main as toggle_main

    profile = tmp_path / "p.csv"
    assert toggle_main(["plan", "--preset", "chang2021", "--duration", "3", "--json",
                        "--out", str(profile)]) == 0
    plan = json.loads(capsys.readouterr().out)
    out = tmp_path / "run"
    assert main(["run", "--profile", str(profile), "--cycles", "1", "--no-as-built", "--out",
                 str(out), "--quiet"]) == 0
    data = read_samples(out / "samples.csv")
    forward = data.force[data.t <= plan["duration"] + 1e-9]
    assert forward.max() == pytest.approx(plan["peak_force"], rel=0.01)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["settings"]["x_contact"] == pytest.approx(plan["x_contact"], rel=1e-9)


def test_the_default_job_plans_for_the_rig_as_built(tmp_path) -> None:
    """The default job plans for the clamp it drives (the prototype as built: its as-built
    error and platen friction plus delta_r8): the run peaks where its plan does, well below
    the nominal clamp's plan replayed on the same rig (45.1 N against 55.6 N on chang2021:
    the nominal plan starts fast, where the platen's friction is largest)."""
    from controllers.limits import drive_limits
    from controllers.planner import default_duration, planner_for
    from controllers.plans import plan_config
    from controllers.profiles import predict
    from toggle.rig_tables import rig_dynamics, rig_errors

    out = tmp_path / "run"
    assert main(["run", "--cycles", "1", "--out", str(out), "--quiet"]) == 0
    meta = json.loads((out / "meta.json").read_text())
    assert "delta_r1U" in meta["profile"] and "platen_friction 4.26 N" in meta["profile"]
    assert "platen_rate 1.81" in meta["profile"] and "1.81 N" not in meta["profile"]  # a ratio
    rig = plan_config("chang2021", errors=rig_errors("chang2021", 0.0),
                      masses=rig_dynamics("chang2021"))
    planner = planner_for(rig, drive_limits(rig.mechanism))
    plan = planner.best(default_duration(planner))
    data = read_samples(out / "samples.csv")
    stroke = data.t <= plan.duration + 1e-9
    forward = data.force[stroke]
    # within 2 %: the planner's friction is steady sliding, the run's slip state turns over
    # the first 0.1 mm from rest, where the platen's friction peaks
    assert forward.max() == pytest.approx(planner.worst_peak(plan), rel=0.02)
    nominal = plan_config("chang2021")
    plain = planner_for(nominal, drive_limits(nominal.mechanism)).best(plan.duration)
    assert forward.max() < 0.85 * predict(plain.profile, rig).peak_force


def test_either_fmu_gives_the_same_run(tmp_path) -> None:
    """The pythonfmu FMU (default, or given) and the native FMU: identical summaries."""
    from fmu_src.native_build import build_native_fmu

    argv = ["run", "--speed", "40e-3", "--cycles", "1", "--quiet"]
    native = build_native_fmu(tmp_path / "native")
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    assert main([*argv, "--fmu", str(native), "--out", str(tmp_path / "b")]) == 0
    a, b = (json.loads((tmp_path / d / "summary.json").read_text()) for d in "ab")
    for key in ("stroke", "force_forward_max", "force_forward_rms", "force_backward_min",
                "force_backward_rms", "force_toggle"):
        assert a[key]["mean"] == pytest.approx(b[key]["mean"], rel=1e-9, abs=1e-9), key
    assert main([*argv, "--fmu", str(tmp_path / "none.fmu"), "--out", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "c").exists()
