"""``toggle clamp``: real-mold clamping with pin friction; ``toggle plot clamp``: Figs 4-7(-8).

Lin & Hsiao 2003: thrust, clamping and tie-bar forces from mold contact to the
straight toggle, for one friction coefficient (table in mm, deg, kN and kgf;
``--json`` in SI). The figures reproduce the paper's Figs 4-7 for several mu and,
when the preset has a drive, the motor torque at constant motor speed (Fig 8).
"""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING

from toggle.args import positive
from toggle.params import Mechanism
from toggle_cli.common import (
    FORCE,
    FRICTION,
    MM,
    POSITION,
    add_json_argument,
    add_out_argument,
    add_preset_argument,
    declare_outputs,
    deg,
    mechanism,
    output,
    print_json,
    table,
)

if TYPE_CHECKING:
    from toggle.elastics import ClampingResult

KGF = 9.80665  # N per kgf, for tables and figures only
PAPER_MUS = (0.0, 0.01, 0.05, 0.10, 0.17)


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def summary(mech: Mechanism, result: ClampingResult) -> dict:
    """SI summary of one clamping run (the ``--json`` payload)."""
    from toggle.drive import encoder_pulses, motor_torque

    out = {
        "preset": mech.name,
        "mu": result.mu,
        "mu_static": result.mu_static,
        "x_contact": result.x_contact,
        "x_final": result.x_final,
        "alpha_contact": result.alpha_contact,
        "alpha_final": result.alpha_final,
        "tiebar_stretch": result.final.tiebar_stretch,
        "toggle_stretch": result.final.toggle_stretch,
        "crosshead_travel": result.crosshead_travel,
        "thrust_max": result.thrust_max,
        "x_at_thrust_max": result.x_at_thrust_max,
        "alpha_at_thrust_max": result.alpha_at_thrust_max,
        "thrust_final": result.final.thrust,
        "thrust_hold": result.hold.thrust,
        "clamp_force_final": result.final.clamp_force,
        "tiebar_force_final": result.final.tiebar_force,
        # null when unbounded (frictionless straight toggle)
        "mechanical_advantage_final": _finite_or_none(result.mechanical_advantage_final),
    }
    if mech.drive is not None:
        out["motor_torque_max"] = float(motor_torque(result.thrust_max, mech.drive))
        out["encoder_pulses"] = float(encoder_pulses(result.crosshead_travel, mech.drive))
    return out


def _print_table(mech: Mechanism, data: dict) -> None:
    print(f"preset {mech.name}: real-mold clamping, "
          f"mu = {data['mu']:g} (mu_s = {data['mu_static']:g})")
    rows: list[tuple] = [(label, deg(data[k]), "deg", "") for k, label in (
        ("alpha_contact", "alpha_C"), ("alpha_final", "alpha_final"),
        ("alpha_at_thrust_max", "alpha@F0max"))]
    rows += [(label, data[k] * MM, "mm", "") for k, label in (
        ("x_contact", "x_contact"), ("x_final", "x_final"), ("tiebar_stretch", "S_C tiebar"),
        ("toggle_stretch", "S_bar"), ("crosshead_travel", "U_E"))]
    rows += [(label, data[k] / 1e3, "kN", data[k] / KGF) for k, label in (
        ("thrust_max", "F0_max"), ("thrust_final", "F0_final"), ("thrust_hold", "F0_hold"),
        ("clamp_force_final", "F_cl_final"), ("tiebar_force_final", "F_c_final"))]
    ma = data["mechanical_advantage_final"]
    rows.append(("MA_final", math.inf if ma is None else ma, "-", ""))
    if "motor_torque_max" in data:
        rows.append(("T_m_max", data["motor_torque_max"], "N m", ""))
        rows.append(("pulses_N_c", data["encoder_pulses"], "-", ""))
    print(table(("quantity", "value", "unit", "kgf"), rows))


def run(args: argparse.Namespace) -> int:
    from toggle import clamping_force

    mech = mechanism(args)
    result = clamping_force(mech, args.mu, clamp_force=args.clamp_force, x_contact=args.contact)
    data = summary(mech, result)
    if args.json:
        print_json(data)
    else:
        _print_table(mech, data)
    return 0


def _common_options(p: argparse.ArgumentParser) -> None:
    add_preset_argument(p, default="lin2003_sm55", accepts=("lin2003_sm55", "chang2021"),
                        why="li_micro has no [clamp] data (pins, sections, tie bars)")
    p.add_argument("--clamp-force", type=FORCE, default=None, metavar="N",
                   help="final total tie-bar force, N (default: the preset's)")
    p.add_argument("--contact", type=POSITION, default=None, metavar="M",
                   help="mold-contact crosshead position x, m (a mold height) instead of a force")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("clamp", help="real-mold clamping with pin friction (Lin & Hsiao 2003)")
    _common_options(p)
    p.add_argument("--mu", type=FRICTION, default=None,
                   help="kinetic friction coefficient at the pins (default: the preset's)")
    add_json_argument(p)
    p.set_defaults(handler=run)


# --- figures ---------------------------------------------------------------------------


def plot(args: argparse.Namespace) -> int:
    import numpy as np

    from toggle.drive import torque_history, travel_per_radian
    from toggle.elastics import analyse_clamping, clamping_curves
    from toggle.plots import plt, save_figure

    mech = mechanism(args)
    results = [analyse_clamping(mech, mu, tiebar_force=args.clamp_force, x_contact=args.contact)
               for mu in args.mu]
    curves = [clamping_curves(mech, r) for r in results]
    # every figure's data before the first file, so that a refusal leaves no figure behind
    mus = np.linspace(0.0, max(max(args.mu), 0.2), 21)
    peaks = [analyse_clamping(mech, m, tiebar_force=args.clamp_force,
                              x_contact=args.contact).thrust_max for m in mus]
    histories = []
    if mech.drive is not None:
        speed = args.rpm * 2 * math.pi / 60
        for r in results:  # 1.25 times the clamping travel's duration, at least 1 ms of hold
            t_end = max(1.25 * r.crosshead_travel / (speed * travel_per_radian(mech.drive)),
                        1e-3)
            histories.append((r, torque_history(mech, r, np.linspace(0.0, t_end, 400), speed)))
    panels = [
        ("fig4_tiebar_force_{tag}.png", "Total tie-bar force $F_c$ (kN)",
         lambda c: c.state.tiebar_force / 1e3, False),
        ("fig5_mechanical_advantage_{tag}.png", "Mechanical advantage $F_{cl}/F_0$ (1)",
         lambda c: c.mechanical_advantage, True),
        ("fig6_thrust_{tag}.png", "Crosshead thrust $F_0$ (kN)",
         lambda c: c.state.thrust / 1e3, False),
    ]
    for name, ylabel, value, log in panels:
        fig, ax = plt.subplots(figsize=(6, 4))
        for r, c in zip(results, curves):
            ax.plot(np.degrees(c.alpha), value(c), label=f"$\\mu$ = {r.mu:g}")
        ax.set_xlabel(r"Toggle angle $\alpha$ (deg)")
        ax.set_ylabel(ylabel)
        if log:
            ax.set_yscale("log")
        ax.invert_xaxis()  # clamping runs from alpha_C down to the straight toggle
        ax.legend()
        ax.set_title(f"{mech.name}: real-mold clamping")
        save_figure(fig, output(args, name))
        plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(mus, np.array(peaks) / 1e3, marker="o")
    ax.set_xlabel(r"Friction coefficient $\mu$ (1)")
    ax.set_ylabel(r"Maximum thrust $F_{0,\max}$ (kN)")
    ax.set_title(f"{mech.name}: maximum crosshead thrust")
    save_figure(fig, output(args, "fig7_thrust_max_{tag}.png"))
    plt.close(fig)

    if histories:
        fig, ax = plt.subplots(figsize=(6, 4))
        for r, h in histories:
            ax.plot(h.t, h.torque, label=f"$\\mu_d$ = {r.mu:g}")
        ax.set_xlabel("Time since mold contact (s)")
        ax.set_ylabel("Motor torque $T_m$ (N m)")
        ax.legend()
        ax.set_title(f"{mech.name}: {args.rpm:g} rpm, $\\eta$ = {mech.drive.efficiency:g}")
        save_figure(fig, output(args, "fig8_motor_torque_{tag}.png"))
        plt.close(fig)
    return 0


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("clamp", help="Figs 4-7 of Lin & Hsiao 2003 (and motor torque) as PNG")
    _common_options(p)
    p.add_argument("--mu", type=FRICTION, nargs="+", default=list(PAPER_MUS),
                   help="friction coefficients of the curves (default: the paper's, "
                        f"{' '.join(map(str, PAPER_MUS))})")
    p.add_argument("--rpm", type=positive("motor speed in rpm", 1e5), default=200.0,
                   help="motor speed of the torque figure, rpm (default 200 rpm)")
    add_out_argument(p)
    declare_outputs(p, "fig4_tiebar_force_{tag}.png", "fig5_mechanical_advantage_{tag}.png",
                    "fig6_thrust_{tag}.png", "fig7_thrust_max_{tag}.png",
                    "fig8_motor_torque_{tag}.png")
    p.set_defaults(handler=plot)
