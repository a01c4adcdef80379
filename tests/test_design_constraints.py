"""A designer's limits (issue 38), each against a hand computation for the SM-55: the joints
are placed along the model's angles (toggle.kinematics.half_pose) and the forces are the
model's (toggle.elastics); the transmission angles, envelope, tie-bar clearance, buckling
loads, pin pressures and the halves' clearance at the axis are computed here from those,
not by design.constraints."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from design import constraints as checks
from design.objectives import Evaluator
from design.placement import design_values
from design.targets import DESIGN_LIMITS, load_targets, targets_from_dict
from toggle.elastics import ClampingError, analyse_clamping, at_mold_height, clamp_state
from toggle.kinematics import half_pose, stroke_limits
from toggle.params import ParameterError, load_preset
from toggle.statics import OPENING

SM55 = Path(__file__).resolve().parents[1] / "design" / "examples" / "sm55.toml"


@pytest.fixture(scope="module")
def sm55() -> tuple:
    mech = load_preset("lin2003_sm55")
    evaluator = Evaluator(load_targets(SM55))
    ref = evaluator(evaluator.vector(design_values(mech)))
    return mech, evaluator, ref


def _joints(mech, points: int = 2001, x_open: float | None = None) -> dict[str, np.ndarray]:
    """C, E, D, B, A of the lower half over the stroke (2 x n, m), placed by hand."""
    h = mech.lower
    x_open = mech.clamp.x_open if x_open is None else x_open
    xs = np.linspace(x_open, stroke_limits(h)[1], points)
    pose = half_pose(xs, h)
    arm = pose.theta4 + pose.alpha4
    return {"E": np.stack([xs, np.full_like(xs, h.r1 - h.r2)]),
            "D": np.stack([h.r4a * np.cos(arm), h.r4a * np.sin(arm)]),
            "B": np.stack([h.r4b * np.cos(pose.theta4), h.r4b * np.sin(pose.theta4)]),
            "A": np.stack([pose.L, np.full_like(xs, h.e)]),
            "C": np.zeros((2, points))}


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    cos = np.sum(u * v, axis=0) / np.linalg.norm(u, axis=0) / np.linalg.norm(v, axis=0)
    a = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    return np.minimum(a, 180 - a)


def test_transmission_angles_of_the_sm55_by_hand(sm55) -> None:
    mech, _, ref = sm55
    j = _joints(mech)
    assert np.allclose(np.linalg.norm(j["D"] - j["E"], axis=0), mech.lower.r3)  # D closes
    at_d = _angle(j["D"] - j["E"], j["D"] - j["C"]).min()  # link 3 against the arm
    at_a = 90 - _angle(j["A"] - j["B"], np.array([[1.0], [0.0]])).max()  # link 5, platen line
    assert at_d == pytest.approx(65.80, abs=0.01)  # issue 38: 65.8 deg
    assert at_a == pytest.approx(90 - 37.0, abs=0.01)  # link 1 at 37 deg at open
    assert math.degrees(ref.metrics["transmission_D"]) == pytest.approx(at_d, abs=0.02)
    assert math.degrees(ref.metrics["transmission_A"]) == pytest.approx(at_a, abs=0.02)
    assert ref.metrics["platen_side_load"] == pytest.approx(math.tan(math.radians(90 - at_a)),
                                                            rel=1e-3)


def test_radial_envelope_and_tiebar_clearance_of_the_sm55_by_hand(sm55) -> None:
    mech, _, ref = sm55
    j = _joints(mech)
    ys = np.concatenate([p[1] for p in j.values()])
    assert j["D"][1].max() * 1e3 == pytest.approx(133.17, abs=0.01)  # issue 38's arm tip
    assert ref.metrics["radial_envelope"] == pytest.approx(ys.max() - ys.min(), abs=1e-5)
    # both halves' links fill |z| <= w / 2 side by side and |y| <= 135 + 22.5 mm (pivot C
    # and its pin: the farthest boss from the axis), the bars (d = 60 mm) at +-185 mm
    w = 3 * 0.028 + 2 * 0.039  # at B: 3 links 1 and 2 plates of link 2 per half
    reach = 0.135 + 0.0225
    bar = math.sqrt(2827e-6 / math.pi)
    expect = math.hypot(0.185 - w / 2, 0.185 - reach) - bar
    assert expect == pytest.approx(0.0776, abs=1e-4)
    assert ref.metrics["tiebar_clearance"] == pytest.approx(expect, abs=1e-9)


def _axis_gap(mech, x_open: float | None = None) -> dict[str, tuple[float, float]]:
    """Per joint D, B, A of the lower half: its least distance from the clamp axis (y = r1
    of the half's frame, the upper half its mirror image) over the stroke on a fine grid,
    and the joint's own x where it is least, m."""
    j = _joints(mech, 8001, x_open)
    assert np.allclose(np.linalg.norm(j["D"] - j["E"], axis=0), mech.lower.r3)  # D closes
    assert np.allclose(np.linalg.norm(j["A"] - j["B"], axis=0), mech.lower.r5)  # B closes
    out = {}
    for name in ("D", "B", "A"):
        gap = mech.lower.r1 - j[name][1]
        i = int(np.argmin(gap))
        out[name] = (float(gap[i]), float(j[name][0][i]))
    return out


#: link_clearance has no default (opt-in, for halves whose links share one plane): 1 mm here
LINK_CLEARANCE = 1e-3


@pytest.fixture(scope="module")
def in_one_plane() -> tuple:
    """The SM-55's targets asking for link_clearance, the SM-55 evaluated on them."""
    import tomllib
    table = tomllib.loads(SM55.read_text())  # preset by name: the same from a dict
    table.setdefault("targets", {})["link_clearance"] = LINK_CLEARANCE
    evaluator = Evaluator(targets_from_dict(table, str(SM55)))
    mech = load_preset("lin2003_sm55")
    return mech, evaluator, evaluator(evaluator.vector(design_values(mech)))


def test_link_clearance_is_off_unless_the_targets_ask(sm55, in_one_plane) -> None:
    assert DESIGN_LIMITS["link_clearance"].default is None
    assert "link_clearance" not in sm55[1].limits and "link_clearance" not in sm55[2].constraints
    assert sm55[2].metrics["link_clearance"] == in_one_plane[2].metrics["link_clearance"]
    assert in_one_plane[1].limits["link_clearance"] == LINK_CLEARANCE


def test_link_clearance_of_the_sm55_and_its_redesign_by_hand(in_one_plane) -> None:
    mech, evaluator, ref = in_one_plane
    sm = _axis_gap(mech)  # the SM-55 opened to its preset's x_open = -70 mm
    assert ref.metrics["x_open"] == pytest.approx(mech.clamp.x_open, abs=1e-9)
    least = min(gap for gap, _ in sm.values())
    assert ref.metrics["link_clearance"] == pytest.approx(least, abs=2e-6)
    assert least < 0 and ref.constraints["link_clearance"] > 0  # its elbows B cross
    assert sm["B"][0] == least
    # the redesign: issue 38's review found at the open position the elbows B 0.9 mm beyond
    # the axis at x = 37.4 mm and the arms' pins D 2.1 mm at -16.4 mm; over the stroke D
    # goes further
    design_mech = load_preset(str(SM55.parent / "sm55_design.toml"))
    design = evaluator(evaluator.vector(design_values(design_mech)))
    assert design.metrics["x_open"] == pytest.approx(design_mech.clamp.x_open, abs=1e-9)
    j = _joints(design_mech, 2)  # the open position first
    for name, gap, at in (("B", -0.9e-3, 37.4e-3), ("D", -2.1e-3, -16.4e-3)):
        assert design_mech.lower.r1 - j[name][1][0] == pytest.approx(gap, abs=0.1e-3)
        assert j[name][0][0] == pytest.approx(at, abs=0.1e-3)
    hand = _axis_gap(design_mech)
    assert hand["D"][0] < design_mech.lower.r1 - j["D"][1][0]  # worse inside the stroke
    assert design.metrics["link_clearance"] == pytest.approx(
        min(gap for gap, _ in hand.values()), abs=2e-6)
    assert design.constraints["link_clearance"] > 0
    assert design.reason.startswith("link_clearance:")


def test_the_sm55_meets_link_clearance_opened_less_and_each_half_counts(sm55) -> None:
    mech = sm55[0]
    h, x_toggle = mech.lower, stroke_limits(mech.lower)[1]
    limit = LINK_CLEARANCE
    x_open = brentq(lambda x: min(g for g, _ in _axis_gap(mech, x).values()) - limit,
                    mech.clamp.x_open, 0.0, xtol=1e-7)
    assert checks.link_clearance(h, h, x_open, x_toggle) == pytest.approx(limit, abs=2e-6)
    assert checks.link_clearance(h, h, x_open + 1e-4, x_toggle) > limit
    # both halves with their own dimensions: the upper half's longer arm decides
    upper = replace(h, r4a=h.r4a + 0.004)
    alone = checks.link_clearance(upper, upper, x_open, x_toggle)
    assert alone < limit
    assert checks.link_clearance(h, upper, x_open, x_toggle) == pytest.approx(alone, abs=1e-12)
    assert checks.link_clearance(upper, h, x_open, x_toggle) == pytest.approx(alone, abs=1e-12)


def _johnson_euler(depth: float, thickness: float, length: float, e: float, sy: float
                   ) -> float:
    slender = length * math.sqrt(12) / min(depth, thickness)
    if slender ** 2 >= 2 * math.pi ** 2 * e / sy:
        return math.pi ** 2 * e * depth * thickness / slender ** 2
    return depth * thickness * (sy - (sy * slender / (2 * math.pi)) ** 2 / e)


def test_buckling_and_pin_pressure_of_the_sm55_by_hand(sm55) -> None:
    mech, _, ref = sm55
    h, result = mech.lower, analyse_clamping(mech)
    e, sy = 172528393450.0, 370e6
    p5 = _johnson_euler(0.078, 0.028, h.r5, e, sy)  # link 1: 231 mm, 78 x 28 mm
    p3 = _johnson_euler(0.050, 0.030, h.r3, e, sy)
    assert 7.5e5 < p5 < 8.0e5  # Johnson's parabola: slenderness 28.6 against 95.9
    peak = clamp_state(result.x_at_thrust_max, result.x_contact, mech)
    states = (peak, result.final, result.hold)
    buckling = 3 * max(max(s.link1_force / p5, s.crosshead_link_force / p3) for s in states)
    assert ref.metrics["buckling_utilisation"] == pytest.approx(buckling, rel=1e-9)
    # pins: link 1 on pin B (45 mm) over 28 mm; the triangle's two plates take the three
    # links 1 of a half over 39 mm each; link 3 on pin D (30 mm)
    hold = result.hold
    pressures = [hold.link1_force / (0.045 * 0.028), 6 / 4 * hold.link1_force / (0.045 * 0.039),
                 hold.crosshead_link_force / (0.030 * 0.030)]
    assert max(pressures) == pytest.approx(77.15e6, rel=1e-3)
    assert ref.metrics["pin_pressure"] == pytest.approx(max(pressures), rel=1e-9)


def test_mold_height_sensitivity_and_self_locking_by_finite_differences(sm55) -> None:
    mech, _, ref = sm55
    h, result = mech.lower, analyse_clamping(mech)
    dh = 1e-6  # the mold 1 um thicker: contact 1 um of platen travel earlier
    l_c = float(half_pose(result.x_contact, h).L)
    x_c = brentq(lambda x: float(half_pose(x, h).L) - (l_c - dh), result.x_contact - 1e-3,
                 result.x_contact)
    thicker = analyse_clamping(mech, x_contact=x_c)
    per_m = (thicker.final.clamp_force / result.final.clamp_force - 1) / dh
    assert ref.metrics["clamp_force_sensitivity"] == pytest.approx(per_m, rel=2e-3)
    assert 0.25 < per_m * 1e-4 < 0.27  # 25.9 % per 0.1 mm
    travel = ref.metrics["self_locking_travel"]
    mu_s = mech.clamp.static_factor * mech.clamp.mu

    def opening(x: float) -> float:
        return float(clamp_state(x, result.x_contact, mech, mu_s, OPENING).thrust)

    assert opening(result.x_final - 0.99 * travel) < 0 < opening(result.x_final - 1.01 * travel)
    assert ref.metrics["breakaway_force"] == pytest.approx(-opening(result.x_final), rel=1e-12)


def _final_tiebar_force_contact(mech, x_final: float, force: float) -> float:
    """Where the molds must touch for the final tie-bar force ``force``, by bisection on the
    model's clamp state (not toggle.elastics.contact_position)."""
    x_open = mech.clamp.x_open
    return brentq(lambda xc: float(clamp_state(x_final, xc, mech).tiebar_force) - force,
                  x_open, x_final - 1e-9, xtol=1e-15)


def test_die_height_range_of_the_sm55_by_hand(sm55) -> None:
    """The tailstock's range (150-350 mm, the tie bars' 1250 mm span at 250 mm): at the
    thinnest mold the span is 100 mm shorter, the bars' stretch at the same tie-bar force
    F L / (n A E) (Eq 24) 23.4 um less, so the sensitivity 1 / S_bar rises from 2586 to
    2752 /m; at the thickest the peak thrust is the larger. Both against the motor's force
    and the sensitivity's limit give the constraint."""
    mech, evaluator, ref = sm55
    die, bars, force = mech.clamp.die_height, mech.clamp.tiebars, mech.clamp.final_tiebar_force
    assert (die.min, die.max, die.reference) == (0.150, 0.350, 0.250)
    s_ref = 1.0 / ref.metrics["clamp_force_sensitivity"]
    thin = s_ref + force * (die.min - die.reference) / (bars.count * bars.area * bars.modulus)
    assert ref.metrics["die_height_sensitivity"] == pytest.approx(1.0 / thin, rel=1e-6)
    assert 1.0 / thin == pytest.approx(2752.0, abs=1.0)
    x_final = stroke_limits(mech.lower)[1]
    peaks = []
    for height in (die.min, die.max):  # the bars' span set by hand, the peak by scanning
        span = bars.length + height - die.reference
        adjusted = replace(mech, clamp=replace(mech.clamp, tiebars=replace(bars, length=span)))
        xc = _final_tiebar_force_contact(adjusted, x_final, force)
        xs = np.linspace(xc, x_final, 200001)
        peaks.append(float(np.max(clamp_state(xs, xc, adjusted).thrust)))
    assert peaks[1] > peaks[0] and peaks[1] > ref.metrics["thrust_peak"]
    assert ref.metrics["die_height_thrust"] == pytest.approx(max(peaks), rel=1e-6)
    motor = evaluator._limits.force(mech.drive)
    util = max(max(peaks) / motor, 1.0 / thin / DESIGN_LIMITS["clamp_force_sensitivity"].default)
    assert ref.metrics["die_height_range"] == pytest.approx(util, rel=1e-6)
    assert ref.constraints["die_height_range"] == pytest.approx(util - 1.0, rel=1e-6)
    assert 0.9 < util < 1.0  # the SM-55 meets it, its thinnest mold near the limit


def test_die_height_range_is_a_targets_key_and_a_preset_table(tmp_path: Path) -> None:
    bounds = {v: 0.1 for v in ("d", "r3", "r4a", "r4b", "r5")}
    bounds.update(e=0.005, alpha4=0.5, alpha_open=1.0)
    table = {"preset": "lin2003_sm55", "objectives": ["thrust_peak", "link_mass"],
             "targets": {"die_height_range": 0.8}, "bounds": bounds}
    evaluator = Evaluator(targets_from_dict(table))
    assert evaluator.limits["die_height_range"] == 0.8
    mech = load_preset("lin2003_sm55")
    values = design_values(mech)
    e = evaluator(evaluator.vector(values))
    assert e.constraints["die_height_range"] > 0 and not e.feasible
    with pytest.raises(ClampingError, match="outside the die-height range"):
        at_mold_height(mech, 0.4)
    assert at_mold_height(mech, 0.15).clamp.tiebars.length == pytest.approx(1.15)
    text = (Path(__file__).resolve().parents[1] / "toggle" / "presets"
            / "lin2003_sm55.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("min = 0.150", "min = 0.400"))
    with pytest.raises(ParameterError, match="die height min 0.4 m must be below max"):
        load_preset(str(bad))
    bare = tmp_path / "bare.toml"
    bare.write_text(re.sub(r"\[clamp\.die_height\][^\[]*", "", text))
    table["preset"] = str(bare)
    assert "die_height_range" not in Evaluator(targets_from_dict(table)).limits


def test_link_masses_scale_with_length(sm55) -> None:
    mech, evaluator, ref = sm55
    assert ref.metrics["link_mass"] == pytest.approx(mech.dynamics.links, rel=1e-12)
    values = design_values(mech)
    longer = {k: v * 1.1 if k in ("r3", "r4a", "r4b", "r5") else v for k, v in values.items()}
    bigger = evaluator.mechanism(evaluator.values(evaluator.vector(longer)))
    assert bigger.dynamics.links == pytest.approx(1.1 * mech.dynamics.links, rel=1e-9)


def test_the_sm55_meets_every_default_and_the_old_design_does_not(sm55) -> None:
    mech, evaluator, ref = sm55
    defaults = {k for k, lim in DESIGN_LIMITS.items() if k != "link_clearance"}
    assert defaults <= set(evaluator.active)  # all but the opt-in link_clearance
    assert ref.feasible, ref.reason
    old = load_preset(str(SM55.parent / "sm55_old_design.toml"))
    design = evaluator(evaluator.vector(design_values(old)))
    assert design.constraints["transmission_angle"] > 0  # 38.4 deg at A (link 1 at 51.6)
    assert design.constraints["radial_envelope"] > 0  # the arm tip 37 mm over its pin line
    assert design.metrics["link_clearance"] < -0.030  # that arm tip across the axis


def test_a_target_overrides_a_default_and_missing_data_turns_a_limit_off(tmp_path: Path
                                                                         ) -> None:
    bounds = {v: 0.1 for v in ("d", "r3", "r4a", "r4b", "r5")}
    bounds.update(e=0.005, alpha4=0.5, alpha_open=1.0)
    table = {"preset": "lin2003_sm55", "objectives": ["thrust_peak", "link_mass"],
             "targets": {"pin_pressure": 80e6}, "bounds": bounds}
    assert Evaluator(targets_from_dict(table)).limits["pin_pressure"] == 80e6
    table["targets"] = {"link_clearance": 0.042}  # halves in one plane: half a section
    assert Evaluator(targets_from_dict(table)).limits["link_clearance"] == 0.042
    table.update(preset="chang2021", objectives=["stroke_ratio", "transmission_angle"],
                 targets={})
    limits = Evaluator(targets_from_dict(table)).limits  # no [clamp], no [sections]
    assert "transmission_angle" in limits and "pin_pressure" not in limits
    assert "link_clearance" not in limits  # no drawn links: the halves may not share planes
    with pytest.raises(ParameterError, match="targets.pin_pressure must be > 0"):
        targets_from_dict(dict(table, targets={"pin_pressure": -1.0}))


def test_seed_004_mp_is_eq_6_as_the_paper_gives_it() -> None:
    """Eq 6 is Mp = S0 / Sm, the crosshead over the platen stroke from lock-up (Eq 2 over
    Eq 1), not Eq 5's instantaneous 1 / Mv: for group 1 at 1 deg the paper's 8.19 (to its
    two decimals, so within 0.005); 1 / Mv is 4.09 there."""
    targets = load_targets(SM55.parent / "li_micro.toml")
    evaluator = Evaluator(targets)
    group = design_values(load_preset("li_micro/1"), targets.bounds["alpha_open"][0])
    e = evaluator(evaluator.vector(group))
    assert e.metrics["force_amplification"] == pytest.approx(8.19, abs=0.005)
    assert e.metrics["mechanical_advantage_lock"] == pytest.approx(4.09, abs=0.005)


def test_the_duty_is_the_planners_and_does_at_least_the_clamping_work(sm55) -> None:
    """The search's duty is the minimum-time plan at 40 intervals: within 1 % of the
    planner's default 200 (``toggle plan --min-time``; interpreted here, as the search
    runs it, to spare the test a compile), its duration above the bound, its energy at
    least the clamp-up's work through the screw."""
    from controllers.duty import motor_duty
    from controllers.limits import drive_limits
    from controllers.plans import INTERVALS
    from design.timing import fastest_stroke
    from toggle.plant import PlantConfig

    mech, evaluator, ref = sm55
    duty = evaluator.close_duty(ref.variables, ref.metrics["x_open"])
    assert duty["close_time"] == pytest.approx(ref.metrics["close_time"], rel=1e-12)
    assert duty["close_plan_time"] > duty["close_time"]  # the bound is a bound
    result = analyse_clamping(mech)
    cfg = PlantConfig(mech, x_contact=result.x_contact)
    plan = fastest_stroke(cfg, drive_limits(mech), intervals=INTERVALS)
    s = plan.samples
    fine = motor_duty(s.time, s.velocity, s.acceleration, s.input_force, mech.drive)
    assert duty["close_rms_torque"] == pytest.approx(fine.rms_torque, rel=0.01)
    assert duty["close_energy"] == pytest.approx(fine.shaft_energy_without_regeneration,
                                                 rel=0.01)
    assert duty["close_plan_time"] == pytest.approx(fine.cycle_time, rel=0.01)
    xs = np.linspace(result.x_contact, result.x_final, 801)
    thrust = np.asarray(clamp_state(xs, result.x_contact, mech).thrust, dtype=float)
    work = float(np.sum(0.5 * (thrust[1:] + thrust[:-1]) * np.diff(xs)))
    assert duty["close_energy"] >= work / mech.drive.efficiency > 0  # the clamp-up's share


def test_the_cycle_duty_holds_the_closing_stroke_and_the_dwells(sm55) -> None:
    """The molding cycle's duty: the closing plan, the targets' hold and ejection dwells and
    an opening stroke (its duration what is left: the closing one's within 5 %, the same
    path under the same speed, acceleration and jerk limits, which bind the SM-55 both
    ways); its torque-squared integral and energy more than the closing stroke's, its RMS
    torque diluted by the dwells."""
    _, evaluator, ref = sm55
    settings = evaluator.targets.settings
    assert (settings["hold"], settings["eject"]) == (8.0, 1.5)  # the stated defaults
    duty = evaluator.close_duty(ref.variables, ref.metrics["x_open"])
    opening = duty["cycle_time"] - duty["close_plan_time"] - settings["hold"] - settings["eject"]
    assert opening == pytest.approx(duty["close_plan_time"], rel=0.05)
    close_sq = duty["close_rms_torque"] ** 2 * duty["close_plan_time"]
    cycle_sq = duty["cycle_rms_torque"] ** 2 * duty["cycle_time"]
    assert cycle_sq > close_sq
    assert duty["cycle_rms_torque"] < duty["close_rms_torque"]  # diluted by the dwells
    assert duty["cycle_energy"] > duty["close_energy"]
