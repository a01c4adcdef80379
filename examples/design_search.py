"""A small design search: seed 004's micro clamp, a Sobol design of experiments.

Run: ``python examples/design_search.py [OUT]``; writes ``OUT/design/`` (pareto.csv,
all.csv, presets/, front.png, parallel.png) and ``OUT/design_search.png``.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
from _common import output_folder

from design import search_designs

out = output_folder()
targets = "design/examples/li_micro.toml"
result = search_designs(targets, out / "design", doe="sobol", samples=64, workers=0)
print(f"{len(result.evaluations)} designs, {len(result.feasible)} feasible, "
      f"{len(result.front)} on the Pareto front")
for p in result.placements:
    print(f"{p.name}: {p.status}")

keys = result.targets.objectives[:2]
fig, ax = plt.subplots(figsize=(6, 4.2), dpi=90)
ax.scatter([e.metrics[keys[0]] for e in result.feasible],
           [e.metrics[keys[1]] for e in result.feasible], s=12, color="0.7", label="feasible")
ax.scatter([e.metrics[keys[0]] for e in result.front],
           [e.metrics[keys[1]] for e in result.front], s=18, label="Pareto front")
ax.set(xlabel=f"{keys[0]} (1)", ylabel=f"{keys[1]} (1)",
       title="li_micro: 64 Sobol candidates")
ax.legend()
fig.tight_layout()
fig.savefig(out / "design_search.png")
print(f"results in {out}")
