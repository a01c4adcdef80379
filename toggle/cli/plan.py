"""``toggle plan``: the clamp stroke that minimises the drive force; ``toggle plot plan``.

Writes the profile CSV the HIL layer executes (``hil run --profile``) and
reports the optimised peak and RMS input force against the trapezoidal and
S-curve strokes of the same duration and limits. Options are SI (m, s, N).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from controllers.limits import DriveLimits, drive_limits
from controllers.planner import (
    CONTACT_SPEED,
    INTERVALS,
    OBJECTIVES,
    baselines,
    default_duration,
    plan_config,
    planner_for,
)
from controllers.profiles import read_profile_csv, write_profile_csv
from hil.cli_args import atomic_path, check_writable, integer, path, positive
from toggle.cli.common import (
    FRICTION,
    POSITION,
    add_json_argument,
    add_preset_argument,
    print_json,
    table,
)
from toggle.drive import motor_torque
from toggle.params import ParameterError
from toggle.plant import PlantConfig

MASS_FIELDS = ("crosshead", "links", "platen", "guide_damping")


def _masses(text: str | None) -> dict[str, float] | None:
    """Parse ``crosshead=40,links=120,platen=500`` (kg; guide_damping in N s/m)."""
    if not text:
        return None
    out = {}
    for item in text.split(","):
        name, _, value = item.partition("=")
        if name.strip() not in MASS_FIELDS:
            raise ParameterError(f"--masses: unknown field {name.strip()!r}; use {MASS_FIELDS}")
        try:
            out[name.strip()] = float(value)
        except ValueError as exc:
            raise ParameterError(f"--masses: {item!r} is not name=number") from exc
    return out


def _plant(args: argparse.Namespace) -> tuple[PlantConfig, DriveLimits]:
    cfg = plan_config(args.preset, mu=args.mu, x_contact=args.x_contact,
                      clamp_force=args.clamp_force, masses=_masses(args.masses))
    limits = drive_limits(cfg.mechanism, velocity=args.v_max, acceleration=args.a_max,
                          jerk=args.j_max, torque=args.torque_max)
    return cfg, limits


def run(args: argparse.Namespace) -> int:
    if args.out:
        check_writable(args.out, "--out")  # before solving, not after
    cfg, limits = _plant(args)
    planner = planner_for(cfg, limits, args.contact_speed, args.intervals)
    if args.min_time:
        plan = planner.minimum_time(args.force_limit)
    else:
        plan = planner.solve(args.duration or default_duration(planner), args.objective)
    base = baselines(cfg, limits, plan.duration)
    if args.out:
        with atomic_path(args.out) as tmp:  # no half-written CSV
            write_profile_csv(tmp, plan.samples, {
                "preset": args.preset, "x_contact": cfg.x_contact, "mu": cfg.friction,
                "objective": plan.objective, "duration": plan.duration,
                "force_limit": args.force_limit if args.min_time else None,
                "v_max": limits.velocity, "a_max": limits.acceleration, "j_max": limits.jerk,
                "torque_max": limits.torque,
            })
    peak = plan.peak_force
    trap, scurve = base["trapezoidal"].peak_force, base["s_curve"].peak_force
    result = {
        "preset": cfg.mechanism.name,
        "mode": "minimum_time" if args.min_time else "fixed_duration",
        "objective": plan.objective,
        "duration": plan.duration,
        "t_contact": plan.t_contact,
        "x_open": planner.x_open,
        "x_contact": cfg.x_contact,
        "x_final": planner.x_final,
        "clamp_force": planner.clamp_force(),
        "peak_force": peak,
        "rms_force": plan.rms_force,
        "baseline_peak_force": trap,
        "baseline_rms_force": base["trapezoidal"].rms_force,
        "s_curve_peak_force": scurve,
        "s_curve_rms_force": base["s_curve"].rms_force,
        "reduction_percent": 100.0 * (trap - peak) / trap,
        "s_curve_reduction_percent": 100.0 * (scurve - peak) / scurve,
        "peak_motor_torque": float(motor_torque(peak, cfg.mechanism.drive)),
        "binding_limits": planner.binding_limits(plan),
        "limits": {"velocity": limits.velocity, "acceleration": limits.acceleration,
                   "jerk": limits.jerk, "torque": limits.torque,
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
          f"{result['clamp_force'] / 1e3:.4g} kN")
    rows = [(name, samples.peak_force, samples.rms_force)
            for name, samples in (("planned", plan.samples), ("trapezoid", base["trapezoidal"]),
                                  ("S-curve", base["s_curve"]))]
    print(table(("profile", "peak (N)", "rms (N)"), rows))
    print(f"peak reduction {result['reduction_percent']:.2f} % (trapezoid), "
          f"{result['s_curve_reduction_percent']:.2f} % (S-curve); solved in "
          f"{plan.solve_time * 1e3:.1f} ms, {plan.iterations} iterations")
    if args.out:
        print(f"profile written to {args.out}")
    return 0


def plot(args: argparse.Namespace) -> int:
    from toggle.plots import MM, plt, save_figure

    samples = read_profile_csv(args.csv)
    cfg, limits = _plant(args)
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
    print(save_figure(fig, args.out))
    return 0




def _add_plant_arguments(p: argparse.ArgumentParser) -> None:
    add_preset_argument(p, accepts=("chang2021",),
                        why="lin2003_sm55 and li_micro have no [dynamics] (give --masses)")
    p.add_argument("--mu", type=FRICTION, default=None, help="pin friction (default: preset's)")
    mold = p.add_mutually_exclusive_group()
    mold.add_argument("--x-contact", type=POSITION, default=None,
                      help="crosshead position at mold contact, m (the mold height)")
    mold.add_argument("--clamp-force", type=positive("force in N", 1e15), default=None,
                      help="clamp force held in the locked position, N "
                           "(default: the preset's final tie-bar force)")
    p.add_argument("--masses", default=None,
                   help="override or supply [dynamics]: crosshead=kg,links=kg,platen=kg"
                        "[,guide_damping=N s/m]")
    p.add_argument("--v-max", type=positive("speed in m/s", 10.0, 1e-4), default=None,
                   help="crosshead speed limit, m/s (default: the preset's drive)")
    p.add_argument("--a-max", type=positive("acceleration in m/s^2", 1e3, 1e-4), default=None,
                   help="acceleration limit, m/s^2 (default: the preset's drive)")
    p.add_argument("--j-max", type=positive("jerk in m/s^3", 1e6, 1e-4), default=None,
                   help="jerk limit, m/s^3 (default: the preset's drive)")
    p.add_argument("--torque-max", type=positive("torque in N m", 1e5, 1e-4), default=None,
                   help="motor torque limit, N m (default: the preset's drive)")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="plan the clamp stroke that minimises the drive force")
    _add_plant_arguments(p)
    p.add_argument("--duration", type=positive("duration in s", 1e4), default=None,
                   help="stroke duration, s (default: twice the kinematic minimum)")
    p.add_argument("--min-time", action="store_true",
                   help="plan the fastest stroke under --force-limit instead")
    p.add_argument("--force-limit", type=positive("force in N", 1e9), default=None,
                   help="input-force limit of --min-time, N (default: the torque limit's)")
    p.add_argument("--objective", choices=OBJECTIVES, default="peak",
                   help="minimise the peak input force or the integral of its square "
                        "(default peak)")
    p.add_argument("--contact-speed", type=positive("speed in m/s", 1.0, 1e-6),
                   default=CONTACT_SPEED,
                   help=f"platen speed limit at mold contact, m/s (default {CONTACT_SPEED})")
    p.add_argument("--intervals", type=integer(4, 5000, "must be 4 to 5000 intervals"),
                   default=INTERVALS,
                   help=f"time intervals N (default {INTERVALS})")
    p.add_argument("--out", type=path, default=None, help="profile CSV to write (SI units)")
    add_json_argument(p)
    p.set_defaults(handler=run)


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("plan", help="a planned profile (CSV) against the baselines")
    p.add_argument("csv", type=path, help="profile CSV written by toggle plan --out")
    _add_plant_arguments(p)
    p.add_argument("--out", type=path, default=Path("plan.png"), help="PNG file (default plan.png)")
    p.set_defaults(handler=plot)
