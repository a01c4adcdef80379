"""The exported cam program run by a PLC runtime: pyplcopen's Structured Text VM (built
from its sdist by :mod:`plc_vm`) executes ``ClampCamIn`` from the PLCopen project, its
MC_CamTableSelect and MC_CamIn coupling the slave of its axis model to a virtual master
through the project's table (at most 64 points, which that VM interpolates linearly)."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from plc_vm import cam_vm

from controllers import cam
from controllers import cam_formats as cf
from controllers.limits import drive_limits
from controllers.planner import default_duration, planner_for
from controllers.plans import plan_config


def test_the_clamp_cam_program_runs_on_pyplcopens_vm_along_the_plan(tmp_path):
    """The PLCopen export of the default plan over a position master, 64 points: the ST
    program compiled and scanned every 125 us with the master turning 0 to 360 degrees over
    the stroke; the slave's command position is the plan's within 1 % of the stroke at every
    scan, and its velocity error (of the plan's peak; linear interpolation of 64 points) is
    reported."""
    cfg = plan_config("chang2021")
    limits = drive_limits(cfg.mechanism)
    planner = planner_for(cfg, limits)
    plan = planner.best(default_duration(planner))
    out = tmp_path / "cam.xml"
    cf.export(out, plan.profile, cfg, limits, plan.peak_force, "plcopen", {},
              master="position", points=64)
    text = out.read_text()
    # pyplcopen's cam type (PLCopen Part 1 leaves MC_CAM_REF to the supplier) and the
    # program's Start input set, as the project's task would set it
    program = ("VAR_GLOBAL\n  ClampCam : MC_CAM_TABLE_VIEW;\nEND_VAR\n"
               + cf.program_st(text).replace("MC_CAM_REF", "MC_CAM_TABLE_VIEW")
               .replace("Start : BOOL;", "Start : BOOL := TRUE;"))
    (tmp_path / "p.st").write_text(program)
    x, y, _, _ = cf.read_plcopen(text)
    assert x.size <= 64
    (tmp_path / "t.csv").write_text("".join(f"{m!r},{s!r}\n"
                                            for m, s in zip(x.tolist(), y.tolist())))
    scans = round(plan.duration / cam.DRIVE_CYCLE)
    run = subprocess.run([str(cam_vm()), str(tmp_path / "p.st"), "ClampCamIn",
                          str(tmp_path / "t.csv"), str(round(cam.DRIVE_CYCLE * 1e9)),
                          str(scans), "360"], capture_output=True, text=True, check=True)
    rows = np.array([[float(v) for v in line.split(",")] for line in run.stdout.split()])
    master, slave, in_sync, error = rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4]
    assert not error.any() and in_sync[1:].all()
    t = master / 360.0 * plan.duration
    x_plan, v_plan, _ = plan.profile.sample(t)
    stroke = x_plan[-1] - x_plan[0]
    position_error = np.max(np.abs(slave - (x_plan - x_plan[0]))) / stroke
    velocity = np.gradient(slave, t)
    velocity_error = np.max(np.abs(velocity - v_plan)) / np.max(np.abs(v_plan))
    print(f"pyplcopen VM, {x.size} points, linear, every {cam.DRIVE_CYCLE * 1e6:g} us: "
          f"position error {100 * position_error:.3f} % of the stroke, velocity error "
          f"{100 * velocity_error:.2f} % of the peak velocity")
    assert position_error <= 0.01
    assert slave[-1] == pytest.approx(stroke, rel=1e-9)
