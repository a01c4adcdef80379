"""``toggle asymmetry``: extra input force when link 8 (upper r5) is off by delta_r8.

``toggle plot asymmetry`` draws the forward and backward curves against x.
"""

from __future__ import annotations

import argparse

from toggle_cli.common import (
    LINK_ERROR,
    MM,
    SPEED,
    add_json_argument,
    add_out_argument,
    add_preset_argument,
    declare_outputs,
    mechanism,
    output,
    print_json,
)


def summary(args: argparse.Namespace) -> dict:
    """F_TP and the paper's curve statistics of the extra force (SI)."""
    import numpy as np

    from toggle.asymmetry import asymmetry, force_curves
    from toggle.kinematics import stroke_limits

    mech = mechanism(args).with_error("upper", "r5", args.delta_r8)
    x_tp = stroke_limits(mech.lower)[1]
    at_tp = asymmetry(x_tp, args.speed, mech.lower, mech.upper)
    xs, fwd, back = force_curves(mech, args.speed)
    return {
        "preset": mech.name,
        "delta_r8": args.delta_r8,
        "speed": args.speed,
        "x_toggle": x_tp,
        "force_toggle": float(at_tp.force),
        "internal_force_toggle": float(at_tp.internal_force),
        "mismatch_toggle": float(at_tp.mismatch),
        "force_forward_max": float(fwd.max()),
        "force_forward_rms": float(np.sqrt(np.mean(fwd**2))),
        "force_backward_min": float(back.min()),
        "force_backward_rms": float(np.sqrt(np.mean(back**2))),
    }


def run(args: argparse.Namespace) -> int:
    out = summary(args)
    if args.json:
        print_json(out)
        return 0
    print(f"{out['preset']}: delta_r8 = {out['delta_r8'] * MM:.3f} mm, "
          f"v = {out['speed'] * MM:g} mm/s")
    print(f"  toggle x = {out['x_toggle'] * MM:.3f} mm, mismatch L_U - L_L = "
          f"{out['mismatch_toggle'] * MM:.4f} mm, "
          f"internal force {out['internal_force_toggle']:.1f} N")
    print(f"  extra input force at the toggle F_TP = {out['force_toggle']:.2f} N")
    for way, ext, key in (("forward: ", "max", "forward_max"),
                          ("backward:", "min", "backward_min")):
        rms = out[f"force_{key.split('_')[0]}_rms"]
        print(f"  {way} {ext} {out['force_' + key]:.2f} N, rms {rms:.2f} N")
    return 0


def _add_common(p: argparse.ArgumentParser) -> None:
    add_preset_argument(p)
    p.add_argument("--speed", type=SPEED, default=5e-3,
                   help="crosshead speed, m/s (default 5e-3 m/s)")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("asymmetry",
                       help="extra input force of unequal halves (seed 000 Tables 6-8)")
    _add_common(p)
    p.add_argument("--delta-r8", type=LINK_ERROR, default=0.5e-3,
                   help="length error of link 8 (upper r5), m or with a unit: 0.5mm, "
                        "500um (default 0.5e-3 m)")
    add_json_argument(p)
    p.set_defaults(handler=run)


def plot(args: argparse.Namespace) -> int:
    from toggle.asymmetry import plot_force_curves

    plot_force_curves(mechanism(args), output(args, "asymmetry_{tag}.png"), speed=args.speed)
    return 0


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("asymmetry", help="extra input force vs x for delta_r8 = 0..0.75 mm")
    _add_common(p)
    add_out_argument(p)
    declare_outputs(p, "asymmetry_{tag}.png")
    p.set_defaults(handler=plot)
