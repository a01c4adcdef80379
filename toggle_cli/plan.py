"""``toggle plan``: the clamp stroke that minimises the drive force; ``toggle plot plan``.

Writes the profile CSV the HIL layer executes (``hil run --profile``) and
reports the optimised peak and RMS input force against the trapezoidal and
S-curve strokes of the same duration and limits. Options are SI (m, s, N).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from toggle.args import integer, number, path, positive
from toggle.files import atomic_path, check_writable
from toggle.params import DYNAMICS_PARAMETERS, HALVES, PAPER_NAMES, ParameterError
from toggle_cli.common import (
    FRICTION,
    LINK_ERROR,
    POSITION,
    add_arguments_later,
    add_json_argument,
    add_out_argument,
    add_preset_argument,
    declare_outputs,
    print_json,
    table,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy as np

    from controllers.cycle import MoldingCycle
    from controllers.duty import Duty
    from controllers.limits import DriveLimits
    from controllers.planner import ClampPlanner
    from controllers.plans import Plan, Protection
    from controllers.progress import Progress
    from toggle.plant import PlantConfig

if TYPE_CHECKING:
    from matplotlib.figure import Figure

MASS_FIELDS = tuple(field for field, _, _ in DYNAMICS_PARAMETERS.values())
#: The dimensional errors, named as the FMU names its delta_* parameters.
ERRORS = tuple(name for half in HALVES for name in PAPER_NAMES[half].values())
_SHOWN = ("r8",)  # the one of them --help describes
#: The dry cycle's mold contact before the toggle, m: no clamp force to speak of (mN).
DRY_CONTACT = 1e-6


def _masses(words: list[str] | None) -> dict[str, float] | None:
    """Parse ``crosshead=40,links=120,platen=500`` (kg; guide_damping in N s/m, the
    frictions in N), the items separated by commas or given as separate words."""
    if not words:
        return None
    out: dict[str, float] = {}
    for item in ",".join(words).split(","):
        name, _, value = item.partition("=")
        if name.strip() not in MASS_FIELDS:
            raise ParameterError(f"--masses: unknown field {name.strip()!r}; use {MASS_FIELDS}")
        if name.strip() in out:
            raise ParameterError(f"--masses: {name.strip()} is given twice")
        try:
            out[name.strip()] = float(value)
        except ValueError as exc:
            raise ParameterError(f"--masses: {item!r} is not name=number") from exc
    return out


def _errors(args: argparse.Namespace) -> dict[str, float]:
    """The dimensional errors given as ``--delta-NAME`` (m), by the FMU's names."""
    return {name: value for name in ERRORS
            if (value := getattr(args, f"delta_{name}", None)) is not None}


def _progress(args: argparse.Namespace, desc: str = "planning", unit: str = "solve",
              total: int = 0) -> Progress:
    """The planning's progress on stderr (:mod:`controllers.progress`), none with
    ``--json``."""
    from controllers.progress import Progress

    return Progress(desc, unit, total, enabled=not getattr(args, "json", False))


def _plant(args: argparse.Namespace, errors: bool = True) -> tuple[PlantConfig, DriveLimits]:
    """The plant (with the dimensional errors unless ``errors`` is false) and the limits."""
    from controllers.limits import drive_limits
    from controllers.plans import plan_config

    cfg = plan_config(args.preset, mu=args.mu, x_contact=args.x_contact,
                      clamp_force=args.clamp_force, masses=_masses(args.masses),
                      errors=_errors(args) if errors else None)
    limits = drive_limits(cfg.mechanism, velocity=args.v_max, acceleration=args.a_max,
                          jerk=args.j_max, torque=args.torque_max)
    return cfg, limits


def _protection(args: argparse.Namespace) -> Protection:
    """The mold-protection zone of ``--protect-distance/-speed/-force``."""
    from controllers.plans import Protection

    return Protection(args.protect_distance, args.protect_speed, args.protect_force)


def _robust(args: argparse.Namespace) -> tuple[ClampPlanner, Plan, dict[str, object]]:
    """The robust planner (``--robust``): the nominal clamp with the erroneous one as a
    variant, each weighed against its own S-curve; and the report of the robust plan, the
    nominal plan and the S-curve on each clamp."""
    from controllers.background import Background
    from controllers.planner import best_plan, default_duration, planner_for
    from controllers.profiles import predict
    from controllers.stroke_reports import baseline_stroke
    from toggle.plant import with_errors

    if args.min_time or not _errors(args):
        raise ParameterError("--robust plans a fixed duration against dimensional errors: "
                             "give --delta-NAME and no --min-time")
    cfg, limits = _plant(args, errors=False)
    erroneous = cfg.with_(mechanism=with_errors(cfg.mechanism, _errors(args))[0])
    nominal = planner_for(cfg, limits, args.contact_speed, args.intervals,
                          protection=_protection(args))
    duration = args.duration or default_duration(nominal)
    nominal.check_duration(duration)  # before predicting a baseline of that length
    stroke = baseline_stroke(cfg, limits, duration)
    curve = {"nominal": predict(stroke, cfg), "erroneous": predict(stroke, erroneous)}
    scale = curve["erroneous"].peak_force / curve["nominal"].peak_force
    planner = planner_for(cfg, limits, args.contact_speed, args.intervals, (erroneous,), (scale,),
                          _protection(args))
    # the nominal plan, to compare, in a second process while this one plans the robust one;
    # the bound is the nominal plant's for both (computed here once, not in each process)
    bound = planner.lower_bound()
    with Background(best_plan, cfg, limits, args.contact_speed, args.intervals,
                    _protection(args), duration, args.objective, bound) as nominal_plan:
        plan, plain = planner.best(duration, args.objective), nominal_plan.result()
    report = {}
    for name, plant in (("nominal", cfg), ("erroneous", erroneous)):
        report[name] = {"robust_plan_peak_force": predict(plan.profile, plant).peak_force,
                        "nominal_plan_peak_force": predict(plain.profile, plant).peak_force,
                        "s_curve_peak_force": curve[name].peak_force}
    return planner, plan, report


def _trade_off_curves(args: argparse.Namespace, cfg: PlantConfig, limits: DriveLimits,
                      meanwhile: Callable[[], object] = lambda: None
                      ) -> dict[str, tuple[ClampPlanner, list[Plan]]]:
    """``--trade-off N``: the fastest stroke under N force limits, with the mold and in a
    dry cycle (the mold at the toggle: no clamp force), each with its planner.
    ``meanwhile``: work for this process while it waits for the dry cycle's (the figure's
    imports, 0.6 s)."""
    from controllers.background import Background
    from controllers.planner import planner_for, trade_off_curve
    from toggle.elastics import clamp_stroke

    dry = cfg.with_(x_contact=clamp_stroke(cfg.mechanism)[1] - DRY_CONTACT)
    common = (limits, args.contact_speed, args.intervals, _protection(args), args.trade_off)
    planners = {name: planner_for(plant, *common[:3], protection=common[3])
                for name, plant in (("mold", cfg), ("dry_cycle", dry))}
    # seconds of IPOPT per curve: the dry cycle's in a second process (two cores), a bar
    # on stderr counting both curves' limits (by limit, not the planner's solves: no
    # reporting())
    with contextlib.closing(_progress(args, "trade-off", "limit", 2 * args.trade_off)) as bar, \
            Background(trade_off_curve, dry, *common) as dry_curve:
        seen = 0

        def tick() -> None:
            nonlocal seen
            bar.advance(1 + dry_curve.ticks() - seen)
            seen = dry_curve.ticks()

        mold = planners["mold"].trade_off(args.trade_off, tick)
        meanwhile()
        curves = {"mold": (planners["mold"], mold),
                  "dry_cycle": (planners["dry_cycle"], dry_curve.result())}
        bar.advance(dry_curve.ticks() - seen)
    return curves


def _trade_off(args: argparse.Namespace, cfg: PlantConfig, limits: DriveLimits) -> int:
    """``--trade-off N``: stroke time against peak input force, printed."""
    curves = _trade_off_curves(args, cfg, limits)
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


def _drive_cycle(text: str) -> float:
    """argparse type of ``--drive-cycle`` (:func:`controllers.cam.parse_cycle`)."""
    from controllers import cam

    try:
        return cam.parse_cycle(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


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
        _plot_duty(args.duty_plot, cycle, limits)
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
                          protection=_protection(args))
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
    cfg, limits = _plant(args, errors=not args.robust)
    if args.trade_off:
        return _trade_off(args, cfg, limits)
    with reporting(_progress(args, "closing stroke" if args.cycle else "planning")):
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
        "dimension_errors": {f"delta_{k}": v for k, v in _errors(args).items()},
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


def plot(args: argparse.Namespace) -> int:
    from controllers.profiles import read_profile_csv
    from controllers.stroke_reports import baselines
    from toggle.plots import MM, plt, save_figure

    samples = read_profile_csv(args.csv)
    cfg, limits = _plant(args)
    _check_positions(args.csv, samples.position, cfg)
    duration = float(samples.time[-1] - samples.time[0])
    base = baselines(cfg, limits, duration)
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    curves = (("planned", samples), ("trapezoid", base["trapezoidal"]),
              ("S-curve", base["s_curve"]))
    for label, s in curves:
        axes[0].plot(s.time, s.position * MM, label=label)
        axes[1].plot(s.time, s.velocity * MM, label=label)
        axes[2].plot(s.time, s.input_force, label=f"{label} (peak {s.peak_force:.4g} N)")
    axes[0].set_ylabel("crosshead position (mm)")
    axes[1].set_ylabel("crosshead velocity (mm/s)")
    axes[2].set_ylabel("input force (N)")
    axes[2].set_xlabel("time (s)")
    for ax in axes:
        ax.legend()
    axes[0].set_title(f"{cfg.mechanism.name}: planned stroke against the baselines")
    save_figure(fig, args.out / "plan.png")
    return 0


def _check_positions(csv: Path, x: np.ndarray, cfg: PlantConfig) -> None:
    """Refuse a profile whose positions leave the preset's stroke by more than a tenth of
    it: a file in mm (a 45 mm stroke read as 45 m), or one planned for another preset."""
    from toggle.elastics import clamp_stroke

    x_open, x_tp = clamp_stroke(cfg.mechanism)
    margin = 0.1 * (x_tp - x_open)
    if x.min() < x_open - margin or x.max() > x_tp + margin:
        raise ParameterError(
            f"profile {csv}: its positions span {x.min():.4g} to {x.max():.4g} m, outside "
            f"{cfg.mechanism.name}'s stroke {x_open:.4g} to {x_tp:.4g} m (a profile's "
            "positions are in m; was it planned for another --preset?)")


def plot_trade_off(args: argparse.Namespace) -> int:
    cfg, limits = _plant(args)
    curves = _trade_off_curves(args, cfg, limits,
                               meanwhile=lambda: importlib.import_module("toggle.plots"))
    from toggle.plots import plt, save_figure

    fig, ax = plt.subplots(figsize=(8, 5))
    for (name, (planner, plans)), marker in zip(curves.items(), "os"):
        label = (f"with the mold (clamp force {planner.clamp_force():.4g} N)" if name == "mold"
                 else "dry cycle (mold at the toggle)")
        ax.plot([p.duration for p in plans], [p.peak_force for p in plans], marker=marker,
                label=label)
    bound = curves["mold"][0].lower_bound()
    ax.axhline(bound, ls="--", color="k", lw=1,
               label=f"lower bound with the mold, any duration ({bound:.4g} N)")
    ax.set_xlabel("clamp stroke time (s)")
    ax.set_ylabel("peak input force (N)")
    ax.set_title(f"{cfg.mechanism.name}: fastest stroke under each input-force limit")
    ax.legend()
    save_figure(fig, args.out / "trade_off.png")
    return 0


def _plot_duty(out: Path, cycle: MoldingCycle, limits: DriveLimits) -> str:
    """``--duty-plot``: :func:`duty_figure` of the molding cycle, saved."""
    from toggle.plots import save_figure

    mech, phases = cycle.closing.config.mechanism, cycle.phases
    return save_figure(duty_figure(
        cycle.duty(), limits, mech.drive.rated_torque,
        f"{mech.name}: the motor over a {cycle.cycle_time:.4g} s molding cycle "
        f"(hold {phases['hold']:g} s, eject {phases['eject']:g} s)"), out)


#: The torque-speed plane shows the cycle at this fraction of its height at least: a motor
#: far larger than the cycle needs squashed the cycle into the axis (1.2 N m for 0.1 N m).
DUTY_FILL = 0.5


def duty_figure(duty: Duty, limits: DriveLimits, rated_torque: float | None,
                title: str) -> Figure:
    """The motor's torque and speed over a cycle, in time and on the torque-speed plane
    (SI; axes labelled with units). The plane is scaled to the cycle: the motor's curve
    and rated torque are drawn where they fall inside it, and the text says how much of
    them the cycle uses. Legends sit below the axes, never over the curves."""
    import numpy as np

    from toggle.plots import plt

    fig, (ax_t, ax_c) = plt.subplots(1, 2, figsize=(12, 5.6))
    lines = ax_t.plot(duty.time, duty.torque, color="C0", label="motor torque (N m)")
    lines.append(ax_t.axhline(duty.rms_torque, ls=":", color="C0",
                              label=f"RMS torque {duty.rms_torque:.3g} N m"))
    ax_t.set_xlabel("time (s)")
    ax_t.set_ylabel("motor torque (N m)")
    ax_s = ax_t.twinx()
    lines += ax_s.plot(duty.time, duty.speed, color="C1", label="motor speed (rad/s)")
    ax_s.set_ylabel("motor speed (rad/s)")
    ax_t.legend(handles=lines, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3,
                fontsize=9, frameon=False)
    speed = np.abs(duty.speed)
    torque = np.abs(duty.torque)
    top_w, top_t = 1.15 * max(float(speed.max()), 1e-9), 1.15 * max(float(torque.max()), 1e-9)
    curve_w = np.linspace(0.0, top_w, 200)
    usable = limits.torque_at(curve_w)
    top_t = max(top_t, min(float(np.max(usable)), top_t / DUTY_FILL))
    if rated_torque is not None and rated_torque <= top_t / DUTY_FILL:
        top_t = max(top_t, 1.1 * rated_torque)
    ax_c.plot(curve_w, usable, "k", label="usable torque (torque-speed curve)")
    if rated_torque is not None:
        ax_c.axhline(rated_torque, ls="--", color="k", lw=1,
                     label=f"rated (continuous) torque {rated_torque:.3g} N m")
    ax_c.plot(speed, torque, ".", ms=2, color="C0", label="the cycle (1 ms samples)")
    ax_c.plot([0.0], [duty.rms_torque], "o", color="C3",
              label=f"RMS torque {duty.rms_torque:.3g} N m")
    ax_c.set_xlim(0.0, top_w)
    ax_c.set_ylim(0.0, top_t)
    ax_c.set_xlabel("motor speed (rad/s)")
    ax_c.set_ylabel("motor torque (N m)")
    use = float(np.max(torque / np.maximum(limits.torque_at(speed), 1e-12)))
    said = f"peak {use:.0%} of the usable torque at its speed"
    if rated_torque is not None:
        said += f"\nRMS {duty.rms_torque / rated_torque:.0%} of the rated torque"
    above = [f"{name} {value:.3g} N m" for name, value in
             (("usable", float(np.min(usable))), ("rated", rated_torque))
             if value is not None and value > top_t]
    if above:
        said += f"\nabove this view: {', '.join(above)}"
    ax_c.text(0.98, 0.97, said, transform=ax_c.transAxes, ha="right", va="top", fontsize=9,
              bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
    ax_c.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize=9,
                frameon=False)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def _add_protection_arguments(p: argparse.ArgumentParser) -> None:
    from controllers.plans import PROTECT_FRACTION

    zone = p.add_argument_group("mold protection: the last distance of platen travel before "
                                "mold contact")
    zone.add_argument("--protect-distance", type=positive("distance in m", 10.0, 1e-6),
                      default=None, help="length of the zone, m of platen travel (default "
                      f"{PROTECT_FRACTION:g} of the platen's travel to contact)")
    zone.add_argument("--protect-speed", type=positive("speed in m/s", 10.0, 1e-6),
                      default=None, help="platen speed cap in the zone, m/s (default none)")
    zone.add_argument("--protect-force", type=positive("force in N", 1e9), default=None,
                      help="input-force cap in the zone, N: a part left in the mold stops "
                           "the clamp (default none)")


def _add_plant_arguments(p: argparse.ArgumentParser) -> None:
    add_preset_argument(p, accepts=("chang2021", "lin2003_sm55"),
                        why="li_micro has no [dynamics] (give --masses)")
    p.add_argument("--mu", type=FRICTION, default=None, help="pin friction (default: preset's)")
    mold = p.add_mutually_exclusive_group()
    mold.add_argument("--x-contact", type=POSITION, default=None,
                      help="crosshead position at mold contact, m (the mold height)")
    mold.add_argument("--clamp-force", type=positive("force in N", 1e15), default=None,
                      help="clamp force held in the locked position, N "
                           "(default: the preset's final tie-bar force)")
    p.add_argument("--masses", default=None, nargs="+", metavar="NAME=VALUE",
                   help="override or supply [dynamics]: crosshead=kg,links=kg,platen=kg"
                        "[,guide_damping=N s/m,guide_friction=N,platen_friction=N,"
                        "platen_rate=1] (commas or spaces between the items)")
    p.add_argument("--v-max", type=positive("speed in m/s", 10.0, 1e-4), default=None,
                   help="crosshead speed limit, m/s (default: the preset's drive)")
    p.add_argument("--a-max", type=positive("acceleration in m/s^2", 1e3, 1e-4), default=None,
                   help="acceleration limit, m/s^2 (default: the preset's drive)")
    p.add_argument("--j-max", type=positive("jerk in m/s^3", 1e6, 1e-4), default=None,
                   help="jerk limit, m/s^3 (default: the preset's drive)")
    p.add_argument("--torque-max", type=positive("torque in N m", 1e5, 1e-4), default=None,
                   help="motor torque at standstill, N m, scaling the torque-speed curve "
                        "(default: the preset's drive)")
    errors = p.add_argument_group("dimensional errors, m (named as the FMU's delta_* "
                                  "parameters; seed 000's names)")
    for name in ERRORS:
        errors.add_argument(f"--delta-{name}", dest=f"delta_{name}", type=LINK_ERROR,
                            default=None, metavar="M", help=argparse.SUPPRESS
                            if name not in _SHOWN else
                            f"error of {name}, m (likewise --delta-NAME for every dimension)")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="plan the clamp stroke that minimises the drive force")
    add_arguments_later(p, _add_plan_arguments)
    p.set_defaults(handler=run)


def _add_plan_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``toggle plan``, whose defaults and choices are the planner's."""
    from controllers import cam, cam_formats
    from controllers.plans import CONTACT_SPEED, INTERVALS
    from controllers.stroke_problem import OBJECTIVES

    _add_plant_arguments(p)
    p.add_argument("--duration", type=positive("duration in s", 1e4), default=None,
                   help="stroke duration, s (default: twice the kinematic minimum)")
    p.add_argument("--min-time", action="store_true",
                   help="plan the fastest stroke under --force-limit instead")
    p.add_argument("--force-limit", type=positive("force in N", 1e9), default=None,
                   help="input-force limit of --min-time, N (default: the torque limit's)")
    p.add_argument("--objective", choices=OBJECTIVES, default="peak",
                   help="minimise the peak input force, the integral of its square or the "
                        "stroke's electrical energy (energy: shaft power with the screw's "
                        "efficiency by the direction of power flow, plus copper losses) "
                        "(default peak)")
    p.add_argument("--energy-weight", type=number(0.0, 1e6, "must be a weight from 0 to 1e6"),
                   default=0.0,
                   help="with --objective peak: add this weight times the energy objective "
                        "(default 0)")
    p.add_argument("--contact-speed", type=positive("speed in m/s", 1.0, 1e-6),
                   default=CONTACT_SPEED,
                   help=f"platen speed limit at mold contact, m/s (default {CONTACT_SPEED})")
    p.add_argument("--intervals", type=integer(4, 5000, "must be 4 to 5000 intervals"),
                   default=INTERVALS,
                   help=f"time intervals N (default {INTERVALS})")
    p.add_argument("--trade-off", type=integer(2, 100, "must be 2 to 100 points"), default=None,
                   metavar="POINTS",
                   help="print the stroke time against the peak input force instead: the "
                        "fastest stroke under POINTS force limits")
    _add_protection_arguments(p)
    p.add_argument("--cycle", action="store_true",
                   help="plan the opening (break-away) stroke back to the open position too, "
                        "the fastest under the force limits, and report the cycle's times")
    p.add_argument("--break-speed", type=positive("speed in m/s", 10.0, 1e-6), default=None,
                   help="with --cycle: platen speed cap over the protection distance after "
                        "the mold separates, m/s (default none)")
    p.add_argument("--hold", type=number(0.0, 3600.0, "must be a dwell of 0 to 3600 s"),
                   default=0.0,
                   help="with --cycle: the hold dwell, mold locked (injection, cooling), s "
                        "(default 0)")
    p.add_argument("--eject", type=number(0.0, 3600.0, "must be a dwell of 0 to 3600 s"),
                   default=0.0,
                   help="with --cycle: the ejection dwell at the open position, s (default 0)")
    p.add_argument("--cycle-out", type=path, default=None,
                   help="with --cycle: the whole molding cycle's profile CSV (hil run "
                        "--profile replays it)")
    p.add_argument("--duty-plot", type=path, default=None,
                   help="with --cycle: PNG of the motor's torque and speed over the cycle, on "
                        "its torque-speed curve")
    p.add_argument("--rated-torque", type=positive("torque in N m", 1e5, 1e-6), default=None,
                   help="the motor's rated (continuous) torque the cycle's RMS torque is "
                        "held to, N m (default: the preset's [drive] rated_torque)")
    export = p.add_argument_group("cam table export (--export cam --out FILE)")
    export.add_argument("--export", choices=("cam",), default=None,
                        help="write the plan as a cam table to --out instead of the profile")
    export.add_argument("--format", choices=cam_formats.FORMATS, default="csv",
                        help="csv; plcopen: PLCopen XML (TC6 v2.01) with CODESYS SoftMotion's "
                        "XYVA cam and a program calling MC_CamTableSelect/MC_CamIn; twincat: "
                        "the same with TwinCAT's motion-function points; pvt: a drive's "
                        "position-velocity-time table in whole encoder counts (default csv)")
    export.add_argument("--points", type=integer(2, 100_000, "must be 2 to 100000 points"),
                        default=None, help="table points (default: the fewest that keep the "
                        "plan at the drive cycle; more given and breaking it: refused)")
    export.add_argument("--interpolation", choices=cam_formats.CSV_INTERPOLATIONS,
                        default=None, help="how the drive interpolates a csv table (default "
                        "cubic; plcopen and twincat are fifth-order through X, Y, V, A, pvt "
                        "cubic through P, V)")
    export.add_argument("--drive-cycle", type=_drive_cycle, default=None,
                        help="the drive's interpolation cycle the table is checked at, e.g. "
                             "125us, 1ms (default 125us)")
    export.add_argument("--master", choices=cam.MASTERS, default="time",
                        help="master: time (s) or a virtual master axis, 0-360 deg per stroke "
                             "(default time)")
    export.add_argument("--units", choices=cam.UNITS, default=None,
                        help="slave units: si (m), motor (revolutions), counts (encoder) "
                             "(default si; pvt: counts)")
    p.add_argument("--robust", action="store_true",
                   help="plan for the nominal clamp and the one with the --delta-NAME errors "
                        "at once (the worst of the two, each against its S-curve)")
    p.add_argument("--out", type=path, default=None, help="profile CSV to write (SI units)")
    add_json_argument(p)


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("plan", help="a planned profile (CSV) against the baselines")
    p.add_argument("csv", type=path, help="profile CSV written by toggle plan --out")
    _add_plant_arguments(p)
    add_out_argument(p)
    declare_outputs(p, "plan.png")
    p.set_defaults(handler=plot)
    p = kinds.add_parser("trade-off", help="stroke time against peak input force, with the "
                         "mold and in a dry cycle")
    add_arguments_later(p, _add_trade_off_arguments, add_out_argument)
    declare_outputs(p, "trade_off.png")
    p.set_defaults(handler=plot_trade_off)


def _add_trade_off_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``toggle plot trade-off`` but --out, some defaults the planner's."""
    from controllers.plans import CONTACT_SPEED, INTERVALS

    _add_plant_arguments(p)
    p.add_argument("--points", dest="trade_off", type=integer(2, 100, "must be 2 to 100 points"),
                   default=6, help="force limits per curve (default 6)")
    p.add_argument("--contact-speed", type=positive("speed in m/s", 1.0, 1e-6),
                   default=CONTACT_SPEED,
                   help=f"platen speed limit at mold contact, m/s (default {CONTACT_SPEED})")
    p.add_argument("--intervals", type=integer(4, 5000, "must be 4 to 5000 intervals"),
                   default=INTERVALS, help=f"time intervals N (default {INTERVALS})")
    _add_protection_arguments(p)
