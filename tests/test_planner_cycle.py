"""The planner's cycle: mold protection (the zone's platen speed and force caps, between the
nodes too), the opening stroke, and ``toggle plan --cycle`` with its protection report and
its refusals of bad protection values."""

from __future__ import annotations

import json

import numpy as np
import pytest
from planner_support import DURATION

from controllers.planner import planner_for
from controllers.plans import Protection
from controllers.profiles import read_profile_settings
from toggle.plant import plant_outputs
from toggle_cli import main


def _in_zone(planner, plan):
    """The 1 ms samples of the closing plan inside the mold-protection zone, judged by the
    platen's own position (the last protect_distance of its travel before contact)."""
    s = plan.samples
    free = planner.config.with_(x_contact=None)
    contact = float(plant_outputs(planner.config.x_contact, 0.0, 0.0, free).platen_position)
    out = plant_outputs(s.position, s.velocity, s.acceleration, free)
    inside = (out.platen_position >= contact - planner.protect_distance - 1e-12) & (
        s.time <= plan.t_contact)
    return inside, out.platen_velocity


def test_mold_protection_caps_hold_between_the_nodes(chang_plan):
    """The zone's platen speed and input-force caps hold on the 1 ms samples through the
    plant; the protection time reported is the time the platen spends in the zone."""
    cfg, limits, _, plan = chang_plan
    caps = Protection(speed=8e-3, force=1.0)
    guarded = planner_for(cfg, limits, protection=caps)
    assert guarded.protect_distance == pytest.approx(4.4985e-3, rel=1e-3)  # 10 % of 45 mm
    safe = guarded.solve(DURATION, start=plan)
    inside, platen_speed = _in_zone(guarded, safe)
    assert platen_speed[inside].max() <= caps.speed * (1 + 1e-6)
    assert np.abs(safe.samples.input_force[inside]).max() <= caps.force * (1 + 1e-6)
    assert guarded.protection(safe)["time"] == pytest.approx(inside.sum() * 1e-3, abs=2e-3)
    free_time = planner_for(cfg, limits).protection(plan)["time"]  # no caps: reported too
    assert free_time == pytest.approx(_in_zone(guarded, plan)[0].sum() * 1e-3, abs=2e-3)
    free_inside, free_speed = _in_zone(guarded, plan)  # the plan without caps is faster there
    assert free_speed[free_inside].max() > caps.speed


def test_mold_protection_speed_cap_binds_and_lengthens_the_stroke(chang_plan):
    """On a coarse problem (60 intervals): the cap, the longer stroke and the protection
    time as at the default 200, in a quarter of the time (two minimum-time continuations)."""
    cfg, limits, _, _ = chang_plan
    planner = planner_for(cfg, limits, intervals=60)
    fast = planner.minimum_time(15.0)
    capped = planner_for(cfg, limits, intervals=60, protection=Protection(speed=5e-3))
    assert capped.problem is planner.problem  # the caps are parameters: no rebuild
    slow = capped.minimum_time(15.0, start=fast)
    inside, speed = _in_zone(capped, slow)
    assert speed[inside].max() <= 5e-3 * (1 + 1e-6) and slow.peak_force <= 15.0
    assert slow.duration > fast.duration + 0.1
    assert capped.protection(slow)["time"] > planner.protection(fast)["time"] + 0.2
    assert any("mold-protection platen speed" in b for b in capped.binding_limits(slow, 15.0))


def test_opening_stroke_breaks_away_and_ends_open_at_rest(chang_plan):
    """The opening stroke: from rest at the toggle back to rest at the open position, the
    drive pulling against the pin friction of the clamped toggle (the tie bars' push back is
    small there), within the force limit, the platen leaving the mold slowly."""
    cfg, limits, planner, _ = chang_plan
    opener = planner_for(cfg, limits, opening=True, protection=Protection(speed=5e-3))
    plan = opener.minimum_time()
    s = plan.samples
    assert s.position[0] == pytest.approx(planner.x_final, abs=1e-9)
    assert s.position[-1] == pytest.approx(planner.x_open, abs=1e-9)
    assert abs(s.velocity[-1]) < 1e-9 and abs(s.acceleration[-1]) < 1e-7
    # the speed limit holds at the nodes and midpoints; the cubics between overshoot a little
    assert s.velocity.max() <= 1e-9 and s.velocity.min() >= -limits.velocity * (1 + 3e-3)
    assert plan.peak_force <= opener.force_limit
    assert s.input_force[s.time <= plan.t_contact].min() < -1.0  # it pulls to break away
    x_sep = plan.profile.sample(np.array([plan.t_contact]))[0]
    assert float(x_sep[0]) == pytest.approx(cfg.x_contact, abs=1e-9)
    after = (s.time >= plan.t_contact) & (s.position >= opener.x_zone)
    platen = plant_outputs(s.position[after], s.velocity[after], s.acceleration[after],
                           cfg.with_(x_contact=None)).platen_velocity
    assert np.abs(platen).max() <= 5e-3 * (1 + 1e-6)
    assert opener.protection(plan)["time"] == pytest.approx(after.sum() * 1e-3, abs=2e-3)
    # a refusal names the stroke it is about (it said "clamping" for the opening too)
    assert "no stroke opening from a clamp force of" in opener._unreachable(0.5, plan)
    assert "no stroke clamping to" in planner._unreachable(0.5, None)


def test_cli_cycle_and_protection_report(tmp_path, capsys):
    out = tmp_path / "cycle.csv"
    assert main(["plan", "--cycle", "--protect-speed", "0.008", "--json",
                 "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["closing_time"] + report["clamp_up_time"] == pytest.approx(report["duration"])
    assert 0 < report["protection_time"] < report["closing_time"]
    opening = report["opening"]
    assert report["cycle_time"] == pytest.approx(report["duration"] + opening["opening_time"])
    assert opening["end_position"] == pytest.approx(report["x_open"], abs=1e-9)
    settings = read_profile_settings(out)
    assert settings["protection_time"] == pytest.approx(report["protection_time"])
    assert settings["protect_speed"] == 0.008
    assert report["protection"]["peak_platen_speed"] <= 0.008 * (1 + 1e-6)


@pytest.mark.parametrize("argv, message", [
    (["--protect-distance", "1"], "protection distance"),
    (["--protect-speed", "0"], "--protect-speed"),
    (["--protect-force", "-1"], "--protect-force"),
    (["--cycle", "--trade-off", "2"], "--cycle"),
    (["--break-speed", "0.005"], "--cycle"),
])
def test_cli_refuses_bad_protection_values_in_one_line(argv, message, capsys):
    try:
        code = main(["plan", "--intervals", "4", *argv])
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and message in err[-1] and "error:" in err[-1]
    assert not any("Traceback" in line for line in err)
