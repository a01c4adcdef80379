"""``toggle plot plan`` and ``toggle plot trade-off``, and ``toggle plan --duty-plot``'s
figure: a planned profile against the baselines (with the settings its CSV header was
planned with), the stroke time against the peak input force, the motor over a cycle.
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path
from typing import TYPE_CHECKING

from toggle.args import path
from toggle.params import ParameterError
from toggle_cli import plan_setup
from toggle_cli.common import (
    add_arguments_later,
    add_out_argument,
    declare_outputs,
    output,
)
from toggle_cli.plan_setup import add_plant_arguments, add_trade_off_arguments, plant_and_limits

if TYPE_CHECKING:

    import numpy as np
    from matplotlib.figure import Figure

    from controllers.cycle import MoldingCycle
    from controllers.duty import Duty
    from controllers.limits import DriveLimits
    from toggle.plant import PlantConfig


def plot(args: argparse.Namespace) -> int:
    from controllers.profiles import read_profile_csv
    from controllers.stroke_reports import baselines
    from toggle.plots import MM, plt, save_figure

    samples = read_profile_csv(args.csv)
    cfg, limits = plant_and_limits(args)
    check_positions(args.csv, samples.position, cfg)
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
    save_figure(fig, output(args, "plan_{tag}.png"))
    return 0


def check_positions(csv: Path, x: np.ndarray, cfg: PlantConfig) -> None:
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
    cfg, limits = plant_and_limits(args)
    curves = plan_setup.trade_off_curves(args, cfg, limits,
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
    save_figure(fig, output(args, "trade_off_{tag}.png"))
    return 0


def plot_duty(out: Path, cycle: MoldingCycle, limits: DriveLimits) -> str:
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


#: Settings of a profile's ``# key = value`` header (as toggle plan writes it) that ``toggle
#: plot plan`` takes where no option gives them, as ``hil run --profile`` does.
HEADER_SETTINGS = ("preset", "x_contact", "mu", "v_max", "a_max", "j_max", "torque_max")


def adopt_header(args: argparse.Namespace) -> None:
    """The clamp a profile was planned for, from its header: each setting no option gives
    is the header's (the preset first: ``sm.csv`` of lin2003_sm55 needs no --preset); an
    option that disagrees with the header is refused, as ``hil run --profile`` refuses it;
    no preset anywhere: chang2021."""
    from controllers.profiles import read_profile_settings

    planned = read_profile_settings(args.csv)
    for key in (*HEADER_SETTINGS, *sorted(k for k in planned if k.startswith("delta_"))):
        if key not in planned or (key == "x_contact" and args.clamp_force is not None):
            continue
        given = getattr(args, key, None)
        if given is None:
            setattr(args, key, planned[key])
        elif given != planned[key]:
            raise ParameterError(f"profile {args.csv} was planned with {key} = "
                                 f"{planned[key]!r}, but --{key.replace('_', '-')} gives "
                                 f"{given!r}; drop the option or re-plan")
    if args.preset is None:
        args.preset = "chang2021"


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("plan", help="a planned profile (CSV) against the baselines",
                         description="A planned profile against the baselines, on the clamp "
                                     "its header says it was planned for (preset, mold, "
                                     "friction, limits); an option overrides none of them "
                                     "but fills what the header lacks.")
    p.add_argument("csv", type=path, help="profile CSV written by toggle plan --out")
    add_plant_arguments(p)
    preset = p._option_string_actions["--preset"]  # noqa: SLF001 - argparse has no setter
    preset.default = None
    preset.help = ("shipped preset (chang2021, lin2003_sm55) or a TOML file (default: the "
                   "profile's own, from its '# preset = ...' header; else chang2021)")
    add_out_argument(p)
    declare_outputs(p, "plan_{tag}.png")
    p.set_defaults(handler=plot, prepare=adopt_header)
    p = kinds.add_parser("trade-off", help="stroke time against peak input force, with the "
                         "mold and in a dry cycle")
    add_arguments_later(p, add_trade_off_arguments, add_out_argument)
    declare_outputs(p, "trade_off_{tag}.png")
    p.set_defaults(handler=plot_trade_off)


