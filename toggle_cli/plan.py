"""``toggle plan``: the clamp stroke that minimises the drive force.

Writes the profile CSV the HIL layer executes (``hil run --profile``) and
reports the optimised peak and RMS input force against the trapezoidal and
S-curve strokes of the same duration and limits. Options are SI (m, s, N), lengths also
with a unit (0.25mm). Its options and what is made of them are in
:mod:`toggle_cli.plan_setup`; its figures (``toggle plot plan``, ``toggle plot
trade-off``, ``--duty-plot``) in :mod:`toggle_cli.plan_figures`.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from toggle.files import atomic_path, check_writable
from toggle.params import ParameterError
from toggle_cli import plan_setup
from toggle_cli.common import (
    add_arguments_later,
    print_json,
    table,
)

# the plot kinds of this command (toggle_cli.plot asks each command module for them)
from toggle_cli.plan_figures import (
    add_plot_parser,  # noqa: F401
    plot_duty,
)
from toggle_cli.plan_setup import (
    add_plan_arguments,
    dimensional_errors,
    plant_and_limits,
    progress_bar,
    protection_zone,
)

if TYPE_CHECKING:
    from controllers.limits import DriveLimits
    from controllers.planner import ClampPlanner
    from controllers.plans import Plan
    from toggle.plant import PlantConfig


def _robust(args: argparse.Namespace) -> tuple[ClampPlanner, Plan, dict[str, object]]:
    """The robust planner (``--robust``): the nominal clamp with the erroneous one as a
    variant, each weighed against its own S-curve; and the report of the robust plan, the
    nominal plan and the S-curve on each clamp."""
    from controllers.api import robust_planner
    from controllers.background import Background
    from controllers.planner import best_plan, default_duration, planner_for
    from controllers.profiles import predict

    if args.min_time or not dimensional_errors(args):
        raise ParameterError("--robust plans a fixed duration against dimensional errors: "
                             "give --delta-NAME and no --min-time")
    cfg, limits = plant_and_limits(args, errors=False)
    nominal = planner_for(cfg, limits, args.contact_speed, args.intervals,
                          protection=protection_zone(args))
    duration = args.duration or default_duration(nominal)
    planner, erroneous, curve = robust_planner(cfg, limits, dimensional_errors(args), duration,
                                               args.contact_speed, args.intervals,
                                               protection_zone(args))
    # the nominal plan, to compare, in a second process while this one plans the robust one
    # (here, after it, where the nominal problem was built now: a second process would
    # build it again, seconds of CPU for a solve of one or two), its solves in the count
    # and the ETA from the start; the bound is the nominal plant's for both (computed here
    # once, not in each process)
    bound = planner.lower_bound()
    with Background(best_plan, cfg, limits, args.contact_speed, args.intervals,
                    protection_zone(args), duration, args.objective, bound,
                    here=not nominal.problem.loaded,
                    expected=nominal.best_solves(args.objective),
                    weight=nominal.solve_weight) as nominal_plan:
        plan, plain = planner.best(duration, args.objective), nominal_plan.result()
    report = {}
    for name, plant in (("nominal", cfg), ("erroneous", erroneous)):
        report[name] = {"robust_plan_peak_force": predict(plan.profile, plant).peak_force,
                        "nominal_plan_peak_force": predict(plain.profile, plant).peak_force,
                        "s_curve_peak_force": curve[name].peak_force}
    return planner, plan, report


def _trade_off(args: argparse.Namespace, cfg: PlantConfig, limits: DriveLimits) -> int:
    """``--trade-off N``: stroke time against peak input force, printed."""
    curves = plan_setup.trade_off_curves(args, cfg, limits)
    bound = curves["mold"][0].lower_bound()
    if args.json:
        print_json({"preset": cfg.mechanism.name, "peak_force_lower_bound": bound,
                    **{f"trade_off_{name}" if name != "mold" else "trade_off":
                       [{"peak_force": p.peak_force, "duration": p.duration} for p in plans]
                       for name, (_, plans) in curves.items()}})
        return 0
    print(f"{cfg.mechanism.name}: the fastest stroke under each input-force limit, with the "
          f"mold (clamp force {curves['mold'][0].clamp_force():.5g} N; no stroke peaks below "
          f"{bound:.4g} N) and in a dry cycle (the mold at the toggle)")
    for name, (_, plans) in curves.items():
        print(name.replace("_", " "))
        print(table(("peak (N)", "time (s)"), [(p.peak_force, p.duration) for p in plans]))
    return 0


def _opening(args: argparse.Namespace, cfg: PlantConfig, limits: DriveLimits
             ) -> tuple[dict[str, object], Plan]:
    """``--cycle``: the fastest opening (break-away) stroke from the toggle back to the open
    position under the drive's force limit (and ``--force-limit``), the platen leaving the
    mold at most at ``--contact-speed`` and at most at ``--break-speed`` over the
    protection distance after it; its times, forces and binding limits."""
    import numpy as np

    from controllers.planner import planner_for
    from controllers.plans import Protection

    opener = planner_for(cfg, limits, args.contact_speed, args.intervals, opening=True,
                         protection=Protection(args.protect_distance, args.break_speed))
    plan = opener.minimum_time(args.force_limit)
    s = plan.samples
    zone = opener.protection(plan)
    return {"opening_time": plan.duration, "t_separation": plan.t_contact,
            "break_away_time": plan.t_contact, "mold_break_time": zone["time"],
            "peak_force": plan.peak_force,
            "break_away_force": float(np.max(np.abs(s.input_force[s.time <= plan.t_contact]))),
            "mold_break_peak_platen_speed": zone["peak_platen_speed"],
            "end_position": float(s.position[-1]), "end_velocity": float(s.velocity[-1]),
            "binding_limits": opener.binding_limits(plan, args.force_limit)}, plan


def _export(args: argparse.Namespace, plan: Plan, cfg: PlantConfig, limits: DriveLimits,
            settings: dict[str, object]) -> dict[str, object]:
    """``--export cam``: the plan's cam table written to ``--out``, checked as the drive
    interpolates it at ``--drive-cycle`` (:mod:`controllers.cam_formats`)."""
    from controllers import cam, cam_formats

    return cam_formats.export(args.out, plan.profile, cfg, limits, plan.peak_force,
                              args.format, settings, points=args.points, master=args.master,
                              units=args.units, interpolation=args.interpolation,
                              cycle=args.drive_cycle or cam.DRIVE_CYCLE)


def _molding_cycle(args: argparse.Namespace, plan: Plan, opening: Plan, limits: DriveLimits
                   ) -> dict[str, object]:
    """``--cycle``: the whole molding cycle with the ``--hold`` and ``--eject`` dwells, its
    times and the motor's duty over it (refused if the motor is too small for its RMS
    torque); ``--cycle-out`` writes it for ``hil run --profile``."""
    from controllers.cycle import MoldingCycle
    from controllers.duty import check_motor
    from controllers.profiles import write_profile_csv

    cycle = MoldingCycle(plan, opening, args.hold, args.eject)
    duty = cycle.duty()
    drive = plan.config.mechanism.drive
    motor = check_motor(duty, drive, limits, args.rated_torque)
    if args.duty_plot:
        plot_duty(args.duty_plot, cycle, limits)
    if args.cycle_out:
        with atomic_path(args.cycle_out) as tmp:
            write_profile_csv(tmp, cycle.samples(), {
                "preset": args.preset, "x_contact": plan.config.x_contact,
                "mu": plan.config.friction, "cycle_time": cycle.cycle_time,
                "hold": args.hold, "eject": args.eject})
    return {"phases": cycle.phases, **duty.report(), "motor": motor,
            "csv": str(args.cycle_out) if args.cycle_out else None,
            "duty_plot": str(args.duty_plot) if args.duty_plot else None}


def _planned(args: argparse.Namespace, cfg: PlantConfig, limits: DriveLimits
             ) -> tuple[ClampPlanner, Plan, dict[str, object] | None]:
    """The planner and the plan asked for (robust, minimum time or least peak) and the
    robust report (None unless ``--robust``)."""
    from controllers.planner import default_duration, planner_for

    if args.robust:
        return _robust(args)
    planner = planner_for(cfg, limits, args.contact_speed, args.intervals,
                          protection=protection_zone(args))
    if args.min_time:
        return planner, planner.minimum_time(args.force_limit), None
    return planner, planner.best(args.duration or default_duration(planner), args.objective,
                                 args.energy_weight), None


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from controllers import cam
    from controllers.duty import motor_duty
    from controllers.profiles import write_profile_csv
    from controllers.progress import describe, reporting
    from controllers.stroke_reports import baselines
    from toggle.drive import motor_torque

    if args.out:
        check_writable(args.out, "--out")  # before solving, not after
    if args.trade_off and args.cycle:
        raise ParameterError("--cycle plans one cycle: not with --trade-off")
    if args.break_speed is not None and not args.cycle:
        raise ParameterError("--break-speed caps the opening stroke: give --cycle too")
    for name in ("hold", "eject", "cycle_out", "duty_plot"):
        if getattr(args, name) and not args.cycle:
            raise ParameterError(f"--{name.replace('_', '-')} belongs to the molding cycle: "
                                 "give --cycle too")
    if args.export and not args.out:
        raise ParameterError("--export cam writes the table to --out: give --out")
    for name in ("points", "interpolation", "units", "drive_cycle"):
        if getattr(args, name) is not None and not args.export:
            raise ParameterError(f"--{name.replace('_', '-')} belongs to the cam export: "
                                 "give --export cam too")
    for name in ("cycle_out", "duty_plot"):
        if getattr(args, name):
            check_writable(getattr(args, name), f"--{name.replace('_', '-')}")
    cfg, limits = plant_and_limits(args, errors=not args.robust)
    if args.trade_off:
        return _trade_off(args, cfg, limits)
    with reporting(progress_bar(args, "closing stroke" if args.cycle else "planning")):
        planner, plan, robust = _planned(args, cfg, limits)
        bound = planner.lower_bound()
        if args.cycle:
            describe("opening stroke")
        opening, opener = _opening(args, cfg, limits) if args.cycle else (None, None)
    zone = planner.protection(plan)
    molding = _molding_cycle(args, plan, opener, limits) if opener else None
    base = baselines(cfg, limits, plan.duration)
    exported = None
    if args.export:
        exported = _export(args, plan, cfg, limits, {
            "preset": args.preset, "x_contact": cfg.x_contact, "mu": cfg.friction,
            "objective": plan.objective, "peak_force": plan.peak_force})
        exported["over_limit"] = cam.over_limits(exported["as_interpolated"])
        for over in exported["over_limit"]:
            print(f"toggle plan: warning: as the drive interpolates the cam table, its {over} "
                  f"of its limit (kept within the check's {100 * (cam.TOLERANCE - 1):g} %; a "
                  f"drive that enforces the limit exactly trips: give more --points or a "
                  f"lower limit)", file=sys.stderr)
    elif args.out:
        with atomic_path(args.out) as tmp:  # no half-written CSV
            write_profile_csv(tmp, plan.samples, {
                "preset": args.preset, "x_contact": cfg.x_contact, "mu": cfg.friction,
                "objective": plan.objective, "duration": plan.duration,
                "force_limit": args.force_limit if args.min_time else None,
                "v_max": limits.velocity, "a_max": limits.acceleration, "j_max": limits.jerk,
                "torque_max": limits.torque, "protect_distance": zone["distance"],
                "protect_speed": zone["speed_cap"], "protect_force": zone["force_cap"],
                "protection_time": zone["time"],
                "opening_time": opening and opening["opening_time"],
            })
    peak = plan.peak_force
    drive = cfg.mechanism.drive
    trap, scurve = base["trapezoidal"].peak_force, base["s_curve"].peak_force
    force_limit = min(args.force_limit or np.inf, planner.force_limit)
    # the baselines are held to the plan's limits (the input force, the motor's torque-speed
    # curve): one that breaks them is no comparison
    feasible = {name: bool(samples.peak_force <= force_limit and limits.torque_ratio(
                    drive, samples.velocity, samples.acceleration, samples.input_force) <= 1.0)
                for name, samples in base.items()}
    result = {
        "preset": cfg.mechanism.name,
        "mode": "minimum_time" if args.min_time else "fixed_duration",
        "objective": plan.objective,
        "duration": plan.duration,
        "t_contact": plan.t_contact,
        "closing_time": plan.t_contact,
        "clamp_up_time": plan.duration - plan.t_contact,
        "protection_time": zone["time"],
        "protection": zone,
        "opening": opening,
        "cycle_time": opening and plan.duration + opening["opening_time"],
        "molding_cycle": molding,
        "duty": motor_duty(plan.samples.time, plan.samples.velocity, plan.samples.acceleration,
                           plan.samples.input_force, drive).report(),
        "cam": exported,
        "x_open": planner.x_open,
        "x_contact": cfg.x_contact,
        "x_final": planner.x_final,
        "clamp_force": planner.clamp_force(),
        "peak_force": peak,
        "peak_force_lower_bound": bound,
        "gap_to_bound_percent": 100.0 * (peak - bound) / bound if bound > 0 else None,
        "dimension_errors": {f"delta_{k}": v for k, v in dimensional_errors(args).items()},
        "robust": robust,
        "rms_force": plan.rms_force,
        "baseline_peak_force": trap,
        "baseline_rms_force": base["trapezoidal"].rms_force,
        "s_curve_peak_force": scurve,
        "s_curve_rms_force": base["s_curve"].rms_force,
        "reduction_percent": 100.0 * (trap - peak) / trap,
        "s_curve_reduction_percent": 100.0 * (scurve - peak) / scurve,
        "baselines_within_limits": feasible,
        "peak_motor_torque": float(np.max(np.abs(motor_torque(
            plan.samples.input_force, drive, plan.samples.acceleration)))),
        "binding_limits": planner.binding_limits(plan, args.force_limit),
        "limits": {"velocity": limits.velocity, "acceleration": limits.acceleration,
                   "jerk": limits.jerk, "torque": limits.torque,
                   "torque_speed": [list(point) for point in limits.curve],
                   "input_force": force_limit,
                   "contact_platen_speed": args.contact_speed},
        "solve_time": plan.solve_time,
        "iterations": plan.iterations,
        "intervals": args.intervals,
        "csv": str(args.out) if args.out else None,
    }
    if args.json:
        print_json(result)
        return 0
    print(f"{cfg.mechanism.name}: {result['mode'].replace('_', ' ')} stroke of "
          f"{plan.duration:.4g} s, mold contact at {plan.t_contact:.4g} s, clamp force "
          f"{result['clamp_force']:.5g} N")
    rows = [(name, samples.peak_force, samples.rms_force)
            for name, samples in (("planned", plan.samples), ("trapezoid", base["trapezoidal"]),
                                  ("S-curve", base["s_curve"]))]
    print(table(("profile", "peak (N)", "rms (N)"), rows))
    print(f"peak reduction {result['reduction_percent']:.2f} % (trapezoid), "
          f"{result['s_curve_reduction_percent']:.2f} % (S-curve); solved in "
          f"{plan.solve_time * 1e3:.1f} ms, {plan.iterations} iterations")
    for name, ok in feasible.items():
        if not ok:
            print(f"the {name.replace('_', '-')} baseline breaks the input-force limit of "
                  f"{force_limit:.4g} N or the motor's torque-speed curve: its reduction "
                  "compares with an infeasible stroke")
    if bound > 0:
        print(f"no stroke of any duration peaks below {bound:.4g} N (lower bound; the plan "
              f"is {result['gap_to_bound_percent']:.2f} % above it)")
    else:
        print("lower bound 0 N: the clamping is too short to force any peak")
    caps = [f"{name} {value:.4g} {unit}" for name, value, unit in (
        ("platen speed", zone["speed_cap"] and zone["speed_cap"] * 1e3, "mm/s"),
        ("input force", zone["force_cap"], "N")) if value is not None]
    print(f"mold protection over the last {zone['distance'] * 1e3:.4g} mm of platen travel "
          f"(caps: {', '.join(caps) or 'none'}): {zone['time']:.4g} s, platen at most "
          f"{zone['peak_platen_speed'] * 1e3:.4g} mm/s, input force at most "
          f"{zone['peak_input_force']:.4g} N; closing {plan.t_contact:.4g} s, clamp-up "
          f"{result['clamp_up_time']:.4g} s")
    print(f"binding limits: {', '.join(result['binding_limits']) or 'none'}")
    if opening:
        print(f"opening stroke {opening['opening_time']:.4g} s (break-away to mold separation "
              f"{opening['break_away_time']:.4g} s at up to {opening['break_away_force']:.4g} N, "
              f"mold break {opening['mold_break_time']:.4g} s, peak {opening['peak_force']:.4g} "
              f"N); cycle {result['cycle_time']:.4g} s; opening binding limits: "
              f"{', '.join(opening['binding_limits']) or 'none'}")
    if molding:
        _print_molding(molding)
    if exported:
        check = exported["as_interpolated"]
        print(f"cam table ({exported['format']}, {exported['points']} points"
              f"{_found(exported)}, master {exported['master_unit']}, slave "
              f"{exported['slave_unit']}) written to {args.out}; as the drive interpolates "
              f"it ({exported['interpolation']}) for the {exported['drive_cycle'] * 1e6:g} us "
              f"drive cycle, the worst at "
              f"{', '.join(f'{c * 1e6:g}' for c in exported['checked_cycles'])} us: velocity "
              f"{100 * check['velocity']:.2f} %, acceleration {100 * check['acceleration']:.2f} "
              f"%, motor torque {100 * check['motor_torque']:.2f} % of their limits, peak input "
              f"force {100 * check['peak_force']:.2f} % of the plan's; off the plan by at most "
              f"{100 * check['position_error']:.3f} % of the stroke and "
              f"{100 * check['velocity_error']:.2f} % of its peak velocity")
    if robust:
        rows = [(name, *values.values()) for name, values in robust.items()]
        print("peak input force (N) on each clamp of the robust plan, the nominal clamp's "
              "plan and the S-curve:")
        print(table(("clamp", "robust", "nominal", "S-curve"), rows))
    return 0


def _found(exported: dict) -> str:
    """How the cam table's count was found: tried from 2 up (the fewest), or bisected."""
    if not exported["points_found"]:
        return ""
    if exported["points_fewest"]:
        return " (the fewest that keep the plan)"
    return " (the least found that keeps the plan: one fewer does not)"


def _print_molding(molding: dict) -> None:
    """The molding cycle's times and the motor's duty, printed."""
    phases = ", ".join(f"{name.replace('_', '-')} {value:.4g} s"
                       for name, value in molding["phases"].items())
    motor = molding["motor"]
    rated = (f" ({100 * motor['rms_over_rated']:.1f} % of the rated {motor['rated_torque']:.4g}"
             " N m)" if motor["rated_torque"] else " (no rated torque in the preset)")
    print(f"molding cycle {molding['cycle_time']:.4g} s: {phases}; motor RMS torque "
          f"{molding['rms_torque']:.4g} N m{rated}, peak {molding['peak_torque']:.4g} N m "
          f"({100 * motor['peak_over_curve']:.1f} % of the torque-speed curve), peak speed "
          f"{molding['peak_speed']:.4g} rad/s; shaft energy per cycle "
          f"{molding['shaft_energy_regenerating']:.4g} J with regeneration, "
          f"{molding['shaft_energy_without_regeneration']:.4g} J without")
    _print_electrical(molding["electrical"], molding["thermal"])


def _print_electrical(electrical: dict | None, thermal: dict | None) -> None:
    """The cycle's electrical energy, braking and winding temperature, printed (or why not)."""
    if electrical is None:
        print("electrical energy: the preset's [drive] gives no winding_resistance and "
              "torque_constant")
        return
    e = electrical
    brake = (f"a brake resistor of at most {e['brake_resistor_max']:.4g} ohm "
             f"({e['brake_resistor_power']:.4g} W continuous)"
             if e["brake_resistor_max"] is not None else "no brake resistor needed")
    bus = (f", or {e['bus_capacitance'] * 1e6:.4g} uF of DC bus for the largest braking event "
           f"({e['largest_braking_event']:.4g} J)" if e["bus_capacitance"] else "")
    print(f"electrical energy per cycle {e['energy_regenerating']:.4g} J with regeneration, "
          f"{e['energy_without_regeneration']:.4g} J without (copper losses "
          f"{e['copper_loss_energy']:.4g} J, mean {e['copper_loss_mean']:.4g} W); peak "
          f"regenerative power {e['peak_regenerative_power']:.4g} W, braking energy "
          f"{e['braking_energy']:.4g} J per cycle: {brake}{bus}")
    if thermal is not None:
        print(f"winding temperature rise over repeated cycles: peak "
              f"{thermal['rise_periodic_peak']:.4g} K, mean {thermal['rise_periodic_mean']:.4g} K"
              f" of the rated {thermal['rated_rise']:.4g} K (first cycle "
              f"{thermal['rise_first_cycle']:.3g} K; 95 % after "
              f"{thermal['cycles_to_settle']} cycles, time constant "
              f"{thermal['time_constant']:.4g} s)")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="plan the clamp stroke that minimises the drive force")
    add_arguments_later(p, add_plan_arguments)
    p.set_defaults(handler=run)


