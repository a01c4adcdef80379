"""Plan the least-peak-force closing stroke and export it: the profile CSV the rig replays
and a PLCopen cam table for a drive.

Run: ``python examples/plan_and_export.py [OUT]``; writes ``OUT/plan.csv``,
``OUT/cam.xml`` and ``OUT/plan_and_export.png``.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
from _common import output_folder

from controllers import plan_stroke

out = output_folder()
plan = plan_stroke("chang2021", duration=3.0)  # least peak input force in 3 s
print(f"{plan.objective} plan: {plan.duration:.3g} s, mold contact at {plan.t_contact:.3g} s, "
      f"peak {plan.peak_force:.2f} N (no stroke peaks below {plan.lower_bound:.2f} N), "
      f"rms {plan.rms_force:.2f} N")
fastest = plan_stroke("chang2021", "min_time", force_limit=15.0)
print(f"fastest stroke within 15 N: {fastest.duration:.3g} s")
print(plan.export(out / "plan.csv", overwrite=True))
print(plan.export(out / "cam.xml", "plcopen", overwrite=True))

fig, axes = plt.subplots(3, 1, sharex=True, figsize=(7, 5.5), dpi=90)
for p, label in ((plan, "least peak, 3 s"), (fastest, "minimum time, 15 N")):
    s = p.samples
    axes[0].plot(s.time, s.position * 1e3, label=label)
    axes[1].plot(s.time, s.velocity * 1e3)
    axes[2].plot(s.time, s.input_force)
axes[0].set_ylabel("crosshead (mm)")
axes[1].set_ylabel("velocity (mm/s)")
axes[2].set(ylabel="input force (N)", xlabel="time (s)")
axes[0].legend()
axes[0].set_title("chang2021: planned closing strokes")
fig.tight_layout()
fig.savefig(out / "plan_and_export.png")
print(f"results in {out}")
