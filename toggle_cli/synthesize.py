"""``toggle synthesize``: sensitivities, significances and tolerance allocation (seed 003).

Works on the press of Dong & Sun 2022 (``--preset dong2022``) and on the
clamp (``--preset chang2021``: upper half = left chain, lower half = right
chain, tilt over the platen-joint spacing).
"""

from __future__ import annotations

import argparse
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from toggle.files import check_writable, check_writable_dir
from toggle.params import load_preset
from toggle_cli.common import (
    CLAMP_PRESETS,
    MM,
    SAMPLES,
    SEED,
    add_json_argument,
    add_out_argument,
    add_preset_argument,
    print_json,
    table,
)

if TYPE_CHECKING:
    from toggle import synthesis


def error_model(preset: str) -> synthesis.ErrorModel:
    """The press error model for a press preset, else the clamp's."""
    from toggle import press, synthesis

    if press.is_press_preset(preset):
        return press.error_model(press.load_press(preset))
    return synthesis.clamp_error_model(load_preset(preset))


def _evaluate(model: synthesis.ErrorModel, tol: dict[str, float], samples: int,
              seed: int) -> dict[str, Any]:
    from toggle import synthesis

    return {
        "tolerances": tol,
        "cost": synthesis.cost(model, tol),
        "reliability": {
            "linear": asdict(synthesis.linear_reliability(model, tol)),
            "monte_carlo": asdict(synthesis.monte_carlo_reliability(model, tol, samples=samples,
                                                                    seed=seed)),
        },
    }


def report(model: synthesis.ErrorModel, samples: int, seed: int) -> dict[str, Any]:
    """Everything the command prints, SI units."""
    from toggle import synthesis

    rows = synthesis.sensitivity_table(model)
    st = model.settings
    alloc = synthesis.allocate(model, samples=samples)
    return {
        "preset": model.name,
        "output": model.output_label,
        "bdc": model.reference_output,
        "chain_spacing": model.nominal_spacing,
        "sensitivities": {r.source: {"left": r.left, "right": r.right} for r in rows},
        "significance": {
            "position": {r.source: r.significance_position for r in rows},
            "tilt": {r.source: r.significance_tilt for r in rows},
        },
        "requirements": {
            "position_limit": st.position_limit, "position_reliability": st.position_reliability,
            "tilt_limit": st.tilt_limit, "tilt_reliability": st.tilt_reliability,
        },
        "allocation": _evaluate(model, alloc.tolerances, samples, seed),
        "reference": _evaluate(model, synthesis.reference_tolerances(model), samples, seed),
    }


def _print_table(data: dict[str, Any]) -> None:
    print(f"preset {data['preset']}: {data['output']} = {data['bdc'] * MM:.3f} mm, "
          f"chain spacing {data['chain_spacing'] * MM:.1f} mm")
    alloc, ref = data["allocation"], data["reference"]
    rows = [(s, v["left"], v["right"], data["significance"]["position"][s],
             ref["tolerances"][s] * MM, alloc["tolerances"][s] * MM)
            for s, v in data["sensitivities"].items()]
    print(table(("source", "dS/dp left", "dS/dp right", "signif.", "ref +-mm", "alloc +-mm"),
                rows, fmt="{:>12.5f}"))
    req = data["requirements"]
    print(f"\nrequirements: P(|dS| <= {req['position_limit'] * MM:g} mm) >= "
          f"{req['position_reliability']:.0%}, P(|dbeta| <= {req['tilt_limit']:g} rad) >= "
          f"{req['tilt_reliability']:.0%}")
    out = []
    for label, block in (("reference", ref), ("allocation", alloc)):
        lin, mc = block["reliability"]["linear"], block["reliability"]["monte_carlo"]
        out.append((label, block["cost"], lin["position"], mc["position"], lin["tilt"], mc["tilt"]))
    print(table(("", "cost (1)", "P pos lin", "P pos MC", "P tilt lin", "P tilt MC"), out))
    print(f"(Monte Carlo: {alloc['reliability']['monte_carlo']['samples']} samples)")


def run(args: argparse.Namespace) -> int:
    model = error_model(args.preset)
    samples = model.settings.samples if args.samples is None else args.samples
    data = report(model, samples, args.seed)
    if args.json:
        print_json(data)
    else:
        _print_table(data)
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("synthesize", help="precision synthesis: sensitivity and tolerance "
                       "allocation by cost and reliability (press or clamp)")
    add_preset_argument(p, default="dong2022", accepts=("dong2022", *CLAMP_PRESETS),
                        why="dong2022 is a press, the others clamps")
    add_json_argument(p)
    p.add_argument("--samples", type=SAMPLES, default=None,
                   help="Monte Carlo samples of the reliability check (default: the preset's, 1e6)")
    p.add_argument("--seed", type=SEED, default=0, help="random seed of the Monte Carlo check")
    p.set_defaults(handler=run)


def plot(args: argparse.Namespace) -> int:
    import numpy as np

    from toggle import synthesis
    from toggle.plots import plt, save_figure

    check_writable_dir(args.out, "--out")
    model = error_model(args.preset)
    check_writable(args.out / f"significance_{model.name}.png", "--out")  # before the work
    rows = synthesis.sensitivity_table(model)
    pos = np.array([r.significance_position for r in rows])
    tilt = np.array([r.significance_tilt for r in rows])
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.bar(x - 0.2, pos, 0.4, label="position error ΔS (|λ| share, Fig 6)")
    ax.bar(x + 0.2, tilt, 0.4, label="tilt error Δβ (variance share, Fig 7)")
    ax.set_xticks(x, [r.source for r in rows], rotation=30)
    ax.set_ylabel("significance coefficient λ (1)")
    ax.set_title(f"{model.name}: significance of each error source ({model.output_label})")
    ax.legend()
    save_figure(fig, args.out / f"significance_{model.name}.png")
    return 0


def add_plot_parser(kinds: argparse._SubParsersAction) -> None:
    p = kinds.add_parser("synthesize",
                         help="significance of each error source (seed 003, Figs 6-7)")
    add_preset_argument(p, default="dong2022", accepts=("dong2022", *CLAMP_PRESETS),
                        why="dong2022 is a press, the others clamps")
    add_out_argument(p)
    p.set_defaults(handler=plot, checks_outputs=True)
