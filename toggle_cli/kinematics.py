"""``toggle kinematics``: stroke, toggle and open positions, L(x) of both halves."""

from __future__ import annotations

import argparse
import math

from toggle.args import integer
from toggle.files import check_writable, check_writable_dir
from toggle.params import HALVES, Mechanism
from toggle_cli.common import (
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


def summary(mech: Mechanism) -> dict:
    """Stroke data of each half; top-level values are the lower half's (SI; angles wrapped
    into (-pi, pi] rad, as the table's into (-180, 180] deg: a pose can carry whole
    turns)."""
    from toggle.kinematics import half_pose, mirror_angles, stroke_limits

    halves = {}
    for h in HALVES:
        dims = mech.half(h)
        x_open, x_tp = stroke_limits(dims)
        pose_tp, pose_open = half_pose(x_tp, dims), half_pose(x_open, dims)
        theta_out = float(mirror_angles(pose_tp)[2]) if h == "upper" else float(pose_tp.theta5)
        halves[h] = {
            "x_open": x_open,
            "x_toggle": x_tp,
            "L_open": float(pose_open.L),
            "L_toggle": float(pose_tp.L),
            "stroke": float(pose_tp.L - pose_open.L),
            # angle of the platen-side link at the toggle: theta5 (lower) or theta8 (upper)
            "platen_link_angle_toggle": wrapped(theta_out),
        }
    upper_tp = stroke_limits(mech.upper)[1]
    theta8 = float(mirror_angles(half_pose(upper_tp, mech.upper))[2])
    lower = halves["lower"]
    return {
        "preset": mech.name,
        "x_open": lower["x_open"],
        "x_toggle": lower["x_toggle"],
        "stroke": lower["stroke"],
        "theta8_toggle": wrapped(theta8),
        "halves": halves,
    }


def profile(mech: Mechanism, points: int) -> dict:
    """L, dL/dx and mechanical advantage of both halves over the stroke."""
    import numpy as np

    from toggle.kinematics import half_motion, stroke_limits

    x_open, x_tp = stroke_limits(mech.lower)
    xs = np.linspace(x_open, x_tp, points)
    out = {"x": xs.tolist()}
    for h in HALVES:
        m = half_motion(xs, mech.half(h), label=f"{h} half")
        out[h] = {"L": m.L.tolist(), "dL_dx": m.dL_dx.tolist(),
                  "mechanical_advantage": m.mechanical_advantage.tolist()}
    out["note"] = ("mechanical_advantage is dx/dL, unbounded at the toggle: null there "
                   "(+inf in the text table)")
    return out


def run(args: argparse.Namespace) -> int:
    mech = mechanism(args)
    data = summary(mech)
    if args.points:
        data["profile"] = profile(mech, args.points)
    if args.json:
        print_json(data)
        return 0
    print(f"preset {mech.name}: {mech.description}")
    rows = [(h, v["x_open"] * MM, v["x_toggle"] * MM, v["stroke"] * MM,
             "theta5" if h == "lower" else "theta8", _wrapped_deg(v["platen_link_angle_toggle"]))
            for h, v in data["halves"].items()]
    print(table(("half", "x_open mm", "x_TP mm", "stroke mm", "angle", "at TP deg"), rows))
    if args.points:
        p = data["profile"]
        rows = [(x * MM, p["lower"]["L"][i] * MM, p["upper"]["L"][i] * MM, p["lower"]["dL_dx"][i],
                 p["lower"]["mechanical_advantage"][i]) for i, x in enumerate(p["x"])]
        print()
        print(table(("x mm", "L_L mm", "L_U mm", "dL/dx (1)", "MA (1)"), rows))
        print("(MA = dx/dL, unbounded at the toggle: inf there)")
    return 0


def wrapped(rad: float) -> float:
    """An angle within (-pi, pi] rad (a pose can carry whole turns: the lower half's
    theta5 at the toggle came out as 6.3308 rad, the upper's theta8 as -0.0476)."""
    value = math.remainder(rad, math.tau)
    return math.pi if value == -math.pi else value


def _wrapped_deg(rad: float) -> float:
    """An angle in degrees within (-180, 180]."""
    return deg(wrapped(rad))


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("kinematics", help="stroke, open and toggle positions of both halves")
    add_preset_argument(p)
    add_json_argument(p)
    p.add_argument("--points", type=integer(0, 100_000, "must be a count from 0 to 100000"),
                   default=0, help="also tabulate L(x), dL/dx and MA at this many points over "
                                   "the stroke (default 0: no table)")
    p.set_defaults(handler=run)


def plot(args: argparse.Namespace) -> int:
    from toggle.plots import plot_kinematics

    plot_kinematics(mechanism(args), output(args, "kinematics_{tag}.png"))
    return 0


def linkage(args: argparse.Namespace) -> int:
    from toggle.linkage import animate_linkage, plot_linkage

    png, gif = output(args, "linkage_{tag}.png"), output(args, "linkage_{tag}.gif")
    check_writable_dir(args.out, "--out")
    for name in (png, gif) if args.animate else (png,):  # before the drawing
        check_writable(name, "--out")
    mech = mechanism(args)
    plot_linkage(mech, png, args.x)
    if args.animate:
        animate_linkage(mech, gif, args.frames)
    return 0


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("kinematics", help="L(x), dL/dx and MA of both halves (seed 000 Fig 6)")
    add_preset_argument(p)
    add_out_argument(p)
    declare_outputs(p, "kinematics_{tag}.png")
    p.set_defaults(handler=plot)
    p = kinds.add_parser(
        "linkage", help="the mechanism drawn to scale, both halves, joints labelled as seed 000 "
                        "(linkage.png; --animate: linkage.gif over the stroke)")
    add_preset_argument(p, accepts=("chang2021", "lin2003_sm55", "li_micro"),
                        why="a design's presets/design-KEY.toml too")
    add_out_argument(p)
    p.add_argument("--x", type=POSITION, default=None,
                   help="crosshead position, m (default: open, mid-stroke and toggle side by side)")
    p.add_argument("--animate", action="store_true",
                   help="also write linkage.gif: one closing and opening over the stroke")
    p.add_argument("--frames", type=integer(2, 1000, "must be a frame count from 2 to 1000"),
                   default=40, help="frames of the animation")
    p.set_defaults(handler=linkage, checks_outputs=True)
