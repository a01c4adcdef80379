"""Tables and figures of docs/design.md: seed 004's groups against the front, and a design
for seed 001's SM-55 targets. Run from the repository: ``.venv/bin/python
docs/design_report.py`` (a few minutes on a local Dask cluster; the searches are recorded
in build/design/ and resumed from there). Prints the Markdown tables; writes the figures
to docs/design/ and the chosen SM-55 design to design/examples/sm55_design.toml.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from design.figures import front_figure, parallel_figure
from design.objectives import OBJECTIVES
from design.output import write_preset
from design.placement import improvements, place
from design.search import run_search
from design.targets import load_targets

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES, FIGURES, RECORDS = ROOT / "design" / "examples", ROOT / "docs" / "design", \
    ROOT / "build" / "design"
SEARCH = {"generations": 40, "population": 60, "seed": 0}
SEARCH_SM55 = {**SEARCH, "generations": 80}


def _cell(key: str, value: float) -> str:
    return f"{math.degrees(value):.2f} deg" if OBJECTIVES[key].unit == "rad" else f"{value:.5g}"


def seed_004() -> None:
    targets = load_targets(EXAMPLES / "li_micro.toml")
    result = run_search(targets, RECORDS / "li_micro", **SEARCH)
    placements = place(targets, result.front)
    keys = targets.objectives
    print(f"li_micro: {len(result.evaluations)} designs, {len(result.feasible)} feasible, "
          f"{len(result.front)} in the Pareto set\n")
    headers = [f"{k} (deg)" if OBJECTIVES[k].unit == "rad" else OBJECTIVES[k].header
               for k in keys]
    print("| group | " + " | ".join(headers)
          + " | place | dominated by | least gain |")
    print("|---" * (len(keys) + 4) + "|")
    for p in placements:
        by = f"design-{p.dominated_by.key[:12]}" if p.dominated_by else "-"
        gain = (f"{100 * p.margin:.2f} %" if p.dominated_by
                else f"nearest design-{p.nearest.key[:12]} is {100 * p.shortfall:.2f} % short")
        print(f"| {p.name} | " + " | ".join(_cell(k, p.reference.metrics[k]) for k in keys)
              + f" | {p.status} | {by} | {gain} |")
        if p.dominated_by:
            print(f"| ↳ design-{p.dominated_by.key[:12]} | "
                  + " | ".join(f"{_cell(k, p.dominated_by.metrics[k])} "
                               f"({100 * p.improvements[k]:+.1f} %)" for k in keys)
                  + " | | | |")
    front_figure(FIGURES / "li_micro_front.png", keys, result.feasible, result.front,
                 placements)
    # the parallel coordinates of the designs named in the table, not all 1400
    named = {d.key: d for p in placements for d in (p.dominated_by, p.nearest) if d}
    parallel_figure(FIGURES / "li_micro_parallel.png", keys, list(named.values()), placements)


def sm55() -> None:
    targets = load_targets(EXAMPLES / "sm55.toml")
    result = run_search(targets, RECORDS / "sm55", **SEARCH_SM55)
    (reference,) = place(targets, result.front)
    keys = targets.objectives

    def gains_of(design: object) -> list[float]:
        return list(improvements(design, reference.reference, keys).values())

    # better by more than 1 % on at least two objectives; of those, the one whose worst
    # loss is least (then the largest total gain)
    eligible = [d for d in result.front if sum(g > 0.01 for g in gains_of(d)) >= 2]
    best = min(eligible, key=lambda d: (max(0.0, -min(gains_of(d))), -sum(gains_of(d))))
    write_preset(EXAMPLES / "sm55_design.toml", targets, best, name="sm55_design")
    gains = improvements(best, reference.reference, keys)
    print(f"\nsm55: {len(result.evaluations)} designs, {len(result.feasible)} feasible, "
          f"{len(result.front)} in the Pareto set; SM-55: {reference.status}\n")
    print("| quantity | SM-55 | sm55_design | change |\n|---|---|---|---|")
    for k in (*keys, "platen_stroke", "crosshead_stroke", "x_open", "stroke_ratio",
              "force_amplification_clamp"):
        a, b = reference.reference.metrics[k], best.metrics[k]
        unit = OBJECTIVES[k].unit if k in OBJECTIVES else ("1" if "ratio" in k
                                                          or "amplification" in k else "m")
        note = f" ({100 * gains[k]:+.1f} % better)" if k in gains else ""
        print(f"| {k} ({unit}) | {a:.5g} | {b:.5g} | {100 * (b - a) / abs(a):+.2f} %{note} |")
    print("\n| variable | SM-55 | sm55_design |\n|---|---|---|")
    for v, a in reference.reference.variables.items():
        print(f"| {v} | {a:.5g} | {best.variables[v]:.5g} |")
    chosen = replace(reference, name="sm55_design", reference=best, dominated_by=None)
    front_figure(FIGURES / "sm55_front.png", keys, result.feasible, result.front,
                 [replace(reference, dominated_by=best), chosen])


def shrink(path: Path) -> None:
    """A 64-colour palette PNG: a tenth of the size, for the repository."""
    from PIL import Image
    Image.open(path).convert("RGB").quantize(64).save(path, optimize=True)


if __name__ == "__main__":
    FIGURES.mkdir(parents=True, exist_ok=True)
    seed_004()
    sm55()
    for png in FIGURES.glob("*.png"):
        shrink(png)
