"""Load a preset and analyse its kinematics and mechanical errors (seed 000).

Run: ``python examples/mechanical_errors.py [OUT]``; writes ``OUT/mechanical_errors.png``.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from _common import output_folder

import toggle

mech = toggle.load_preset("chang2021")
k = toggle.clamp_kinematics(mech, points=201)
print(f"{mech.name}: stroke {k.stroke * 1e3:.4f} mm from x_open {k.x_open * 1e3:.4f} mm "
      f"to the toggle {k.x_toggle * 1e3:.4f} mm")

errors = toggle.mechanical_errors(mech, grade=10, samples=20_000)
r = errors.report
print(f"IT{errors.grade} at the toggle: asymmetry worst case {r.dL_wor * 1e6:.1f} um, "
      f"RSS {r.dL_rss * 1e6:.1f} um, exact {r.dL_exact * 1e6:.1f} um; Monte Carlo "
      f"3 sigma {3 * errors.monte_carlo.asymmetry.std * 1e6:.1f} um")

fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=90)
ax1.plot(k.x * 1e3, k.platen * 1e3)
ax1.set(xlabel="crosshead position x (mm)", ylabel="platen position L (mm)",
        title="kinematics of a half")
ma = np.where(np.isfinite(k.mechanical_advantage), k.mechanical_advantage, np.nan)
ax1b = ax1.twinx()
ax1b.semilogy(k.x * 1e3, ma, color="tab:red")
ax1b.set_ylabel("mechanical advantage (1)", color="tab:red")
parts = r.lower.contributions  # dL/dp times the dimension's IT band, m
ax2.barh(list(parts), [abs(v) * 1e6 for v in parts.values()])
ax2.set(xlabel="|dL/dp| x tolerance at the toggle (um)",
        title=f"lower half's error budget, IT{errors.grade}")
fig.tight_layout()
out = output_folder() / "mechanical_errors.png"
fig.savefig(out)
print(f"results in {out}")
