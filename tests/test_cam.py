"""Cam tables of a plan (``toggle plan --export cam``): the limits as the drive interpolates
the table, the drive units, the CSV and PLCopen XML files, and a replay on the FMU."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controllers import cam
from controllers.limits import drive_limits
from controllers.planner import default_duration, planner_for
from controllers.plans import plan_config
from controllers.profiles import s_curve
from fmu_src.build import build_fmu
from toggle.elastics import clamp_stroke
from toggle.params import load_preset
from toggle_cli import main


@pytest.fixture(scope="module")
def default_plan():
    """chang2021's default plan (what ``toggle plan`` plans)."""
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    planner = planner_for(cfg, limits)
    return cfg, limits, planner.best(default_duration(planner))


@pytest.mark.parametrize("interpolation", cam.INTERPOLATIONS)
def test_the_default_plans_table_keeps_the_limits_as_the_drive_interpolates_it(
        default_plan, interpolation):
    """Linear (a point per 1 ms) and cubic (a point per 10 ms) tables, in every unit: the
    drive's 1 ms samples through the plant keep velocity, acceleration and motor torque
    within 1 % of their limits and the peak input force within 1 % of the plan's."""
    cfg, limits, plan = default_plan
    for units in cam.UNITS:
        table = cam.cam_table(plan.profile, cfg.mechanism.drive, units=units,
                              interpolation=interpolation)
        check = cam.check_table(table, interpolation, cfg, limits, plan.peak_force)
        assert max(check["velocity"], check["acceleration"], check["motor_torque"]) <= 1.01
        assert check["peak_force"] == pytest.approx(1.0, abs=0.01)


def test_a_coarse_linear_table_is_caught(default_plan):
    """101 points, linearly interpolated: the velocity steps between the points are
    accelerations far beyond the limit, and the check says so."""
    cfg, limits, plan = default_plan
    table = cam.cam_table(plan.profile, cfg.mechanism.drive, 101, interpolation="linear")
    check = cam.check_table(table, "linear", cfg, limits, plan.peak_force)
    assert check["acceleration"] > 5 and check["peak_force"] > 1.05


@settings(max_examples=30, deadline=None)
@given(units=st.sampled_from(cam.UNITS), master=st.sampled_from(cam.MASTERS),
       points=st.integers(2, 400))
def test_a_table_in_drive_units_is_the_same_motion(units, master, points):
    """Whatever the units and master, the table converts back to the profile's positions
    at the profile's times; the motor and counts tables are the SI one times R lead."""
    mech = load_preset("chang2021")
    x_open, x_final = clamp_stroke(mech)
    profile = s_curve(x_open, x_final, 2.0, 0.04, 0.4, 8.0)
    table = cam.cam_table(profile, mech.drive, points, master=master, units=units)
    t = table.master_time(table.master)
    np.testing.assert_allclose(t, np.linspace(0.0, 2.0, points), atol=1e-12)
    np.testing.assert_allclose(table.slave_si(table.slave), profile.sample(t)[0], atol=1e-12)
    turn = mech.drive.ratio * mech.drive.lead
    scale = {"si": 1.0, "motor": 1 / turn, "counts": mech.drive.pulses_per_rev / turn}[units]
    assert table.slave[-1] == pytest.approx((x_final - x_open) * scale)


def test_csv_and_plcopen_files_round_trip(tmp_path):
    """The CSV's columns and the PLCopen XML's CamTable give back the table exactly; the
    XML is TC6 v2.01 (its namespace, the CamPoint type, an array of N points)."""
    mech = load_preset("chang2021")
    profile = s_curve(*clamp_stroke(mech), 2.0, 0.04, 0.4, 8.0)
    table = cam.cam_table(profile, mech.drive, 57, master="position", units="counts")
    cam.write_csv(tmp_path / "t.csv", table, "cubic", {"preset": "chang2021"})
    for master, slave in (cam.read_csv(tmp_path / "t.csv"),
                          cam.read_plcopen(cam.plcopen_xml(table, "cubic", {}))):
        np.testing.assert_array_equal(master, table.master)
        np.testing.assert_array_equal(slave, table.slave)
    assert "master [deg],slave [counts]" in (tmp_path / "t.csv").read_text()
    root = ET.fromstring(cam.plcopen_xml(table, "cubic", {}))
    ns = {"p": cam.TC6}
    assert root.tag == f"{{{cam.TC6}}}project"
    assert root.find("p:types/p:dataTypes/p:dataType[@name='CamPoint']", ns) is not None
    assert root.find(".//p:dimension", ns).get("upper") == "56"


def test_the_table_replayed_on_the_fmu_reproduces_the_planned_peak(default_plan, tmp_path):
    """The cubic table as the drive interpolates it, fed to the FMU (its drive an ideal
    position source: drive_bandwidth 0 set here) every 1 ms: the peak input force is the
    plan's within 1 %."""
    from fmpy import simulate_fmu

    cfg, _, plan = default_plan
    table = cam.cam_table(plan.profile, cfg.mechanism.drive, interpolation="cubic")
    t, x, _, _ = cam.drive_samples(table, "cubic")
    h = t[1] - t[0]
    signal = np.array(list(zip(t - h, x)), dtype=[("time", float), ("x_cmd", float)])
    res = simulate_fmu(str(build_fmu(tmp_path)), start_time=0.0, stop_time=t[-1],
                       step_size=h, output_interval=h, input=signal, output=["input_force"],
                       start_values={"x_contact": cfg.x_contact, "x_cmd": x[0],
                                     "drive_bandwidth": 0.0})
    assert np.max(np.abs(res["input_force"])) == pytest.approx(plan.peak_force, rel=0.01)


def test_cli_exports_the_table_and_refuses_an_export_without_a_file(tmp_path, capsys):
    out = tmp_path / "cam.xml"
    assert main(["plan", "--export", "cam", "--format", "plcopen", "--units", "motor",
                 "--master", "position", "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    master, slave = cam.read_plcopen(out.read_text())
    assert report["cam"]["points"] == master.size and master[-1] == pytest.approx(360.0)
    assert report["cam"]["as_interpolated"]["peak_force"] == pytest.approx(1.0, abs=0.01)
    mech = load_preset("chang2021")
    x_open, x_final = clamp_stroke(mech)
    assert slave[-1] == pytest.approx((x_final - x_open) / (mech.drive.ratio * mech.drive.lead))
    with pytest.raises(SystemExit) as refused:
        main(["plan", "--export", "cam", "--format", "xls"])
    assert refused.value.code == 2
    assert main(["plan", "--export", "cam"]) == 2
    assert "--out" in capsys.readouterr().err
