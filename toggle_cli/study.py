"""``toggle study`` and ``toggle sweep``: seed 004's design comparison and two-parameter sweeps.

``toggle study --preset li_micro`` measures every group of a preset family over
the toggle-angle range and ranks them; ``toggle sweep`` varies two dimensions
of one half over a grid. ``toggle plot study`` draws seed 004's Figures 3-6,
``toggle plot sweep`` contour plots of the four criteria.
"""

from __future__ import annotations

import argparse
import functools
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from toggle.args import integer, length, number
from toggle.params import DIMENSIONS, HALVES, ParameterError, load_preset
from toggle_cli.common import (
    MM,
    POINTS,
    add_arguments_later,
    add_json_argument,
    add_out_argument,
    add_preset_argument,
    declare_outputs,
    deg,
    output,
    print_json,
    table,
)

if TYPE_CHECKING:
    import numpy as np

    from toggle.study import GroupResult, SweepResult

#: Labels of the criteria in tables and figures (angles in degrees).
_SHORT = {"stroke_ratio": "Ms", "velocity_ratio": "Mv peak", "force_amplification": "Mp lock",
          "coping_angle_min": "psi min deg"}


#: A toggle angle as typed, deg.
ANGLE = number(0.0, 180.0, "must be a toggle angle between 0 and 180 deg", "deg")


def _range_arguments(preset: str) -> Callable[[argparse.ArgumentParser], None]:
    """Adds the preset and toggle-angle range options (default ``preset``), whose help needs
    :mod:`toggle.study` (for :func:`toggle_cli.common.add_arguments_later`)."""
    return functools.partial(_add_range_arguments, preset=preset)


def _add_range_arguments(p: argparse.ArgumentParser, preset: str) -> None:
    from toggle.study import MIN_ANGLE

    add_preset_argument(p, default=preset, why="a family (li_micro) compares its groups; "
                        "family/group makes that group the baseline")
    p.add_argument("--half", choices=HALVES, default="lower", help="half to study (default lower)")
    p.add_argument("--alpha-lock", type=ANGLE, default=1.0,
                   help="smallest toggle angle, deg: where Mp counts as near lock-up "
                        f"(default 1 deg; at least {math.degrees(MIN_ANGLE):.2g} deg)")
    p.add_argument("--alpha-max", type=ANGLE, default=90.0,
                   help="largest toggle angle (open clamp), deg (default 90 deg; seed 004 gives "
                        "none)")
    p.add_argument("--points", type=POINTS, default=90,
                   help="toggle angles in the range (default 90)")


def _alphas(args: argparse.Namespace) -> np.ndarray:
    from toggle.study import MIN_ANGLE, angle_grid

    least = math.degrees(MIN_ANGLE)
    if not least <= args.alpha_lock < args.alpha_max < 180:
        raise ParameterError(f"need {least:.2g} <= --alpha-lock < --alpha-max < 180 deg, got "
                             f"{args.alpha_lock:g} and {args.alpha_max:g} deg (closer to "
                             f"lock-up the stroke ratio is lost in rounding)")
    return angle_grid(math.radians(args.alpha_lock), math.radians(args.alpha_max), args.points)


def _shown(key: str, value: float) -> float:
    return deg(value) if key == "coping_angle_min" else value


def _run_study(args: argparse.Namespace) -> tuple[list[GroupResult], str]:
    from toggle.study import preset_halves, study_groups

    halves, baseline = preset_halves(args.preset, args.half)
    return study_groups(halves, _alphas(args)), baseline


def study_payload(args: argparse.Namespace) -> dict[str, Any]:
    """JSON of ``toggle study`` (SI): the groups with their measures, and the ranking."""
    from toggle.study import rank_groups

    results, baseline = _run_study(args)
    groups = []
    for r in results:
        entry: dict[str, Any] = {"group": r.group, "valid": r.valid,
                                 "dims": dict(zip(DIMENSIONS, r.dims.as_tuple()))}
        if r.valid:
            entry["criteria"] = r.criteria
            entry["measures"] = {k: v.tolist() for k, v in r.measures._asdict().items()}
        else:
            entry["alpha_limit"] = getattr(r.error, "alpha_limit", None)
            entry["error"] = str(r.error)
        groups.append(entry)
    return {"preset": args.preset, "half": args.half, "alpha": _alphas(args).tolist(),
            "baseline": baseline, "groups": groups, "ranking": rank_groups(results, baseline)}


def _print_ranking(data: dict[str, Any], alpha_max: float, alpha_lock: float) -> None:
    from toggle.study import CRITERIA

    rk = data["ranking"]
    rows = []
    for g in data["groups"]:
        if g["valid"]:
            m, c = g["measures"], g["criteria"]
            rows.append((g["group"], m["crosshead_stroke"][-1] * MM, m["platen_stroke"][-1] * MM,
                         *(_shown(k, c[k]) for k in _SHORT), rk["rank_sum"][g["group"]],
                         rk["place"][g["group"]]))
    print(table(("group", "S0 mm", "Sm mm", *_SHORT.values(), "sum", "place"), rows))
    print(f"\nranking, higher is better on each criterion (S0, Sm, Ms at {alpha_max:g} deg; "
          f"Mp at {alpha_lock:g} deg); equal values share a place:")
    for c in CRITERIA:
        order = sorted(rk["places"][c.key], key=rk["places"][c.key].get)
        shown = ", ".join(f"{g} ({_shown(c.key, rk['values'][g][c.key]):.4g})" for g in order)
        print(f"  {c.label}: {shown}")
    print("  overall (sum of places, smaller is better): "
          + ", ".join(f"{g} ({rk['rank_sum'][g]})" for g in rk["order"]))
    if "baseline" in rk:
        print(f"\nversus baseline group {rk['baseline']}:")
        for g, keys in rk["better_than_baseline"].items():
            print(f"  {g} better on: {', '.join(keys) or 'nothing'}")
        dom = rk["dominates_baseline"]
        print("  better on all criteria: " + (", ".join(dom) if dom else "no group"))
    for bad in rk["invalid"]:
        print(f"\ninvalid group {bad['group']}: {bad['error']}")


def run_study(args: argparse.Namespace) -> int:
    data = study_payload(args)
    if not any(g["valid"] for g in data["groups"]):
        reached = ", ".join(
            f"{g['group']}: {math.degrees(g['alpha_limit']):.1f} deg" if g["alpha_limit"]
            is not None else f"{g['group']}: {g['error']}" for g in data["groups"])
        raise ParameterError(f"no group of {args.preset} opens to --alpha-max "
                             f"{args.alpha_max:g} deg (largest toggle angle of each: {reached})")
    if args.json:
        print_json(data)
        return 0
    print(f"preset {args.preset}, {args.half} half, toggle angle {args.alpha_lock:g} to "
          f"{args.alpha_max:g} deg ({args.points} points), baseline group {data['baseline']}")
    _print_ranking(data, args.alpha_max, args.alpha_lock)
    return 0


_LENGTH = length(-10.0, 10.0, "must be a length within 10 m")
_COUNT = integer(2, 200, "must be a count of values from 2 to 200")


def _axis(spec: list[str]) -> tuple[str, np.ndarray]:
    """``[name, start_m, stop_m, count]`` -> (name, values in m)."""
    import numpy as np

    name, start, stop, count = spec
    if name not in DIMENSIONS:
        raise ParameterError(f"--dim: unknown dimension {name!r}; known: {', '.join(DIMENSIONS)}")
    try:
        return name, np.linspace(_LENGTH(start), _LENGTH(stop), _COUNT(count))
    except argparse.ArgumentTypeError as exc:
        raise ParameterError(f"--dim {name}: {exc}") from exc


def _run_sweep(args: argparse.Namespace) -> SweepResult:
    from toggle.study import sweep

    if len(args.dim) != 2:
        raise ValueError(f"--dim must be given exactly twice, got {len(args.dim)}")
    dims = load_preset(args.preset).half(args.half)
    return sweep(dims, _axis(args.dim[0]), _axis(args.dim[1]), _alphas(args))


def sweep_payload(args: argparse.Namespace, result: SweepResult) -> dict[str, Any]:
    """JSON of ``toggle sweep`` (SI); failed cells are null and listed with the reason."""
    import numpy as np

    return {
        "preset": args.preset, "half": args.half, "alpha": _alphas(args).tolist(),
        "dims": list(result.names), "values": [v.tolist() for v in result.values],
        "criteria": {k: [[None if v is np.ma.masked else float(v) for v in row] for row in a]
                     for k, a in result.criteria.items()},
        "failures": [{"i": i, "j": j, "error": e} for i, j, e in result.failures],
    }


def run_sweep(args: argparse.Namespace) -> int:
    from toggle.study import CRITERIA

    result = _run_sweep(args)
    if args.json:
        print_json(sweep_payload(args, result))
        return 0
    (n1, n2), (v1, v2) = result.names, result.values
    print(f"preset {args.preset}, {args.half} half: rows {n1} (mm), columns {n2} (mm)")
    for c in CRITERIA:
        grid = result.criteria[c.key]
        rows = [(f"{p * MM:.3f}", *("--" if grid.mask[i, j] else _shown(c.key, float(grid[i, j]))
                                    for j in range(len(v2)))) for i, p in enumerate(v1)]
        print(f"\n{c.label} ({_SHORT[c.key]}):")
        print(table((f"{n1}\\{n2}", *(f"{q * MM:.3f}" for q in v2)), rows))
    for i, j, err in result.failures:
        print(f"\n{n1} = {v1[i] * MM:.3f} mm, {n2} = {v2[j] * MM:.3f} mm: {err}")
    return 0


def _add_dim_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dim", nargs=4, action="append", required=True,
                   metavar=("NAME", "START", "STOP", "COUNT"),
                   help=f"a swept dimension ({', '.join(DIMENSIONS)}) from START to STOP m in "
                        "COUNT values; give exactly two")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="seed 004 design study: rank the groups of a preset family")
    add_arguments_later(p, _range_arguments("li_micro"), add_json_argument)
    p.set_defaults(handler=run_study)
    s = sub.add_parser("sweep", help="the study's criteria over a grid of two dimensions")
    add_arguments_later(s, _range_arguments("li_micro/1"), _add_dim_argument, add_json_argument)
    s.set_defaults(handler=run_sweep)


def plot_study(results: list[GroupResult], title: str, path: Path) -> Path:
    """Seed 004's Figures 3-6 for every valid group: Ms, Mv, Mp and psi against alpha."""
    import numpy as np

    from toggle.plots import plt, save_figure

    panels = (("stroke_ratio", "stroke ratio Ms (1)", 1.0, False),
              ("velocity_ratio", "velocity ratio Mv (1)", 1.0, False),
              ("force_amplification", "force amplification Mp (1)", 1.0, True),
              ("coping_angle", "coping angle psi (deg)", 180 / math.pi, False))
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), sharex=True)
    for ax, (key, label, scale, log) in zip(axes.ravel(), panels):
        for r in results:
            if r.valid:
                m = r.measures
                ax.plot(np.degrees(m.alpha), getattr(m, key) * scale, label=f"group {r.group}")
        ax.set_yscale("log" if log else "linear")
        ax.set_ylabel(label)
    for ax in axes[1]:
        ax.set_xlabel("toggle angle alpha (deg)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)


def plot_sweep(result: SweepResult, title: str, path: Path) -> Path:
    """Filled contours of the four criteria over the two swept dimensions (mm)."""
    from toggle.plots import plt, save_figure
    from toggle.study import CRITERIA

    (n1, n2), (v1, v2) = result.names, result.values
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    for ax, c in zip(axes.ravel(), CRITERIA):
        grid = result.criteria[c.key] * (180 / math.pi if c.unit == "rad" else 1.0)
        cs = ax.contourf(v2 * MM, v1 * MM, grid, levels=12)
        fig.colorbar(cs, ax=ax, label=f"{_SHORT[c.key].removesuffix(' deg')} "
                                      f"({'deg' if c.unit == 'rad' else '1'})")
        ax.set_title(c.label, fontsize=10)
        ax.set_xlabel(f"{n2} (mm)")
        ax.set_ylabel(f"{n1} (mm)")
    fig.suptitle(title)
    return save_figure(fig, path)


def _plot_study(args: argparse.Namespace) -> int:
    results, _ = _run_study(args)
    title = (f"{args.preset} ({args.half} half): seed 004 Figs 3-6, "
             f"alpha {args.alpha_lock:g} to {args.alpha_max:g} deg")
    plot_study(results, title, output(args, "study_{tag}.png"))
    return 0


def _plot_sweep(args: argparse.Namespace) -> int:
    result = _run_sweep(args)  # checks --dim first
    title = f"{args.preset} ({args.half} half): criteria over {' and '.join(result.names)}"
    plot_sweep(result, title, output(args, "sweep_{tag}.png"))
    return 0


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("study", help="Ms, Mv, Mp, psi against toggle angle (seed 004 Figs 3-6)")
    add_arguments_later(p, _range_arguments("li_micro"), add_out_argument)
    declare_outputs(p, "study_{tag}.png")
    p.set_defaults(handler=_plot_study)
    s = kinds.add_parser("sweep", help="contours of the study's criteria over two dimensions")
    add_arguments_later(s, _range_arguments("li_micro/1"), _add_dim_argument, add_out_argument)
    declare_outputs(s, "sweep_{tag}.png")
    s.set_defaults(handler=_plot_sweep)
