"""Plan a stroke, run it on the simulated rig (the FMU) and plot the run.

Run: ``python examples/simulated_rig.py [OUT]``; writes two run directories,
``OUT/rig-run/`` (the model's clamp) and ``OUT/rig-run-as-built/`` (the prototype as built:
its fitted link error and platen friction, the simulated rig's default), each with
samples.csv, meta.json, summary.json and force_curves.png, and ``OUT/simulated_rig.png``.
The real rig is the same call with ``real=True, port=...``.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
from _common import output_folder

from controllers import plan_stroke
from hil import read_run, run_on_rig

out = output_folder()
plan = plan_stroke("chang2021", duration=3.0)
profile = plan.export(out / "rig-plan.csv", overwrite=True)
runs = {}
for name, as_built in (("model's clamp", False), ("prototype as built", True)):
    folder = out / ("rig-run-as-built" if as_built else "rig-run")
    run = run_on_rig(profile, cycles=1, as_built=as_built, out=folder, overwrite=True)
    runs[name] = read_run(run.dir)  # the same run, read back from its directory
    print(f"{name}: exit {run.exit_code}, {run.time.size} samples, stroke "
          f"{run.summary['stroke']['mean'] * 1e3:.4f} mm, peak closing force "
          f"{run.summary['force_forward_max']['mean']:.2f} N (planned {plan.peak_force:.2f} N)")

fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(7, 4.5), dpi=90)
run = runs["model's clamp"]
ax1.plot(run.time, run.x_cmd * 1e3, label="commanded crosshead")
ax1.plot(run.time, run.platen * 1e3, label="platen")
ax1.set_ylabel("position (mm)")
ax1.legend()
for name, run in runs.items():
    ax2.plot(run.time, run.force, label=f"measured: {name}")
ax2.plot(plan.samples.time, plan.samples.input_force, "--", label="planned (closing)")
ax2.set(xlabel="time (s)", ylabel="input force (N)")
ax2.legend(fontsize="small")
ax1.set_title("chang2021 on the simulated rig: one cycle (close, open)")
fig.tight_layout()
fig.savefig(out / "simulated_rig.png")
print(f"results in {out}")
