"""What ``toggle plan`` and its figures make of their arguments: the options (declared
when the command line names the command: their defaults are the planner's), the plant and
its drive limits, the mold-protection zone, the dimensional errors, the progress bar, and
the trade-off curves both ``toggle plan --trade-off`` and ``toggle plot trade-off`` plan.
"""

from __future__ import annotations

import argparse
import contextlib
from typing import TYPE_CHECKING

from toggle.args import integer, length, number, path, positive
from toggle.params import DYNAMICS_PARAMETERS, HALVES, PAPER_NAMES, ParameterError
from toggle_cli.common import (
    FRICTION,
    LINK_ERROR,
    POSITION,
    add_json_argument,
    add_preset_argument,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from controllers.limits import DriveLimits
    from controllers.planner import ClampPlanner
    from controllers.plans import Plan, Protection
    from controllers.progress import Progress
    from toggle.plant import PlantConfig


MASS_FIELDS = tuple(field for field, _, _ in DYNAMICS_PARAMETERS.values())
#: The dimensional errors, named as the FMU names its delta_* parameters.
ERRORS = tuple(name for half in HALVES for name in PAPER_NAMES[half].values())
_SHOWN = ("r8",)  # the one of them --help describes
#: The dry cycle's mold contact before the toggle, m: no clamp force to speak of (mN).
DRY_CONTACT = 1e-6


def parse_masses(words: list[str] | None) -> dict[str, float] | None:
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


def dimensional_errors(args: argparse.Namespace) -> dict[str, float]:
    """The dimensional errors given as ``--delta-NAME`` (m), by the FMU's names."""
    return {name: value for name in ERRORS
            if (value := getattr(args, f"delta_{name}", None)) is not None}


def progress_bar(args: argparse.Namespace, desc: str = "planning", unit: str = "solve",
              total: int = 0) -> Progress:
    """The planning's progress on stderr (:mod:`controllers.progress`), none with
    ``--json``."""
    from controllers.progress import Progress

    return Progress(desc, unit, total, enabled=not getattr(args, "json", False))


def plant_and_limits(args: argparse.Namespace, errors: bool = True
                     ) -> tuple[PlantConfig, DriveLimits]:
    """The plant (with the dimensional errors unless ``errors`` is false) and the limits."""
    from controllers.limits import drive_limits
    from controllers.plans import plan_config

    cfg = plan_config(args.preset, mu=args.mu, x_contact=args.x_contact,
                      clamp_force=args.clamp_force, masses=parse_masses(args.masses),
                      errors=dimensional_errors(args) if errors else None)
    limits = drive_limits(cfg.mechanism, velocity=args.v_max, acceleration=args.a_max,
                          jerk=args.j_max, torque=args.torque_max)
    return cfg, limits


def protection_zone(args: argparse.Namespace) -> Protection:
    """The mold-protection zone of ``--protect-distance/-speed/-force``."""
    from controllers.plans import Protection

    return Protection(args.protect_distance, args.protect_speed, args.protect_force)


def trade_off_curves(args: argparse.Namespace, cfg: PlantConfig, limits: DriveLimits,
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
    common = (limits, args.contact_speed, args.intervals, protection_zone(args), args.trade_off)
    planners = {name: planner_for(plant, *common[:3], protection=common[3])
                for name, plant in (("mold", cfg), ("dry_cycle", dry))}
    # seconds of IPOPT per curve: the dry cycle's in a second process (two cores), a bar
    # on stderr counting both curves' limits (by limit, not the planner's solves: no
    # reporting())
    with contextlib.closing(progress_bar(args, "trade-off", "limit", 2 * args.trade_off)) as bar, \
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


def drive_cycle(text: str) -> float:
    """argparse type of ``--drive-cycle`` (:func:`controllers.cam.parse_cycle`)."""
    from controllers import cam

    try:
        return cam.parse_cycle(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_protection_arguments(p: argparse.ArgumentParser) -> None:
    from controllers.plans import PROTECT_FRACTION

    zone = p.add_argument_group("mold protection: the last distance of platen travel before "
                                "mold contact")
    zone.add_argument("--protect-distance", type=length(1e-6, 10.0, "must be a distance from "
                                                               "1 um to 10 m"),
                      default=None, help="length of the zone, m of platen travel or with a "
                      "unit (0.01, 10mm; default "
                      f"{PROTECT_FRACTION:g} of the platen's travel to contact)")
    zone.add_argument("--protect-speed", type=positive("speed in m/s", 10.0, 1e-6),
                      default=None, help="platen speed cap in the zone, m/s (default none)")
    zone.add_argument("--protect-force", type=positive("force in N", 1e9), default=None,
                      help="input-force cap in the zone, N: a part left in the mold stops "
                           "the clamp (default none)")


def add_plant_arguments(p: argparse.ArgumentParser) -> None:
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


def add_plan_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``toggle plan``, whose defaults and choices are the planner's."""
    from controllers import cam, cam_formats
    from controllers.plans import CONTACT_SPEED, INTERVALS
    from controllers.stroke_problem import OBJECTIVES

    add_plant_arguments(p)
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
                   help=f"platen speed limit at mold contact, m/s (default {CONTACT_SPEED} m/s)")
    p.add_argument("--intervals", type=integer(4, 5000, "must be 4 to 5000 intervals"),
                   default=INTERVALS,
                   help=f"time intervals N (default {INTERVALS})")
    p.add_argument("--trade-off", type=integer(2, 100, "must be 2 to 100 points"), default=None,
                   metavar="POINTS",
                   help="print the stroke time against the peak input force instead: the "
                        "fastest stroke under POINTS force limits")
    add_protection_arguments(p)
    p.add_argument("--cycle", action="store_true",
                   help="plan the opening (break-away) stroke back to the open position too, "
                        "the fastest under the force limits, and report the cycle's times")
    p.add_argument("--break-speed", type=positive("speed in m/s", 10.0, 1e-6), default=None,
                   help="with --cycle: platen speed cap over the protection distance after "
                        "the mold separates, m/s (default none)")
    p.add_argument("--hold", type=number(0.0, 3600.0, "must be a dwell of 0 to 3600 s"),
                   default=0.0,
                   help="with --cycle: the hold dwell, mold locked (injection, cooling), s "
                        "(default 0 s)")
    p.add_argument("--eject", type=number(0.0, 3600.0, "must be a dwell of 0 to 3600 s"),
                   default=0.0,
                   help="with --cycle: the ejection dwell at the open position, s (default 0 s)")
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
    export.add_argument("--drive-cycle", type=drive_cycle, default=None,
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


def add_trade_off_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``toggle plot trade-off`` but --out, some defaults the planner's."""
    from controllers.plans import CONTACT_SPEED, INTERVALS

    add_plant_arguments(p)
    p.add_argument("--points", dest="trade_off", type=integer(2, 100, "must be 2 to 100 points"),
                   default=6, help="force limits per curve (default 6)")
    p.add_argument("--contact-speed", type=positive("speed in m/s", 1.0, 1e-6),
                   default=CONTACT_SPEED,
                   help=f"platen speed limit at mold contact, m/s (default {CONTACT_SPEED} m/s)")
    p.add_argument("--intervals", type=integer(4, 5000, "must be 4 to 5000 intervals"),
                   default=INTERVALS, help=f"time intervals N (default {INTERVALS})")
    add_protection_arguments(p)
