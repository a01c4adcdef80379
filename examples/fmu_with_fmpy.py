"""Build the clamp's FMU and simulate it with fmpy: a crosshead ramp to the toggle.

Run: ``python examples/fmu_with_fmpy.py [OUT]``; writes ``OUT/ToggleClamp.fmu`` and
``OUT/fmu_with_fmpy.png``.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from _common import output_folder
from fmpy import simulate_fmu

import toggle
from fmu_src import build_fmu

out = output_folder()
fmu = build_fmu(out, "chang2021", overwrite=True)
print(f"built {fmu}")
k = toggle.clamp_kinematics("chang2021")
x_contact = k.x_toggle - 0.5e-3  # the mold touches 0.5 mm of crosshead travel before the toggle
t = np.linspace(0.0, 4.0, 401)
x_cmd = k.x_open + (k.x_toggle - 1e-6 - k.x_open) * np.clip(t / 3.0, 0.0, 1.0)
signal = np.array(list(zip(t, x_cmd)), dtype=[("time", float), ("x_cmd", float)])
result = simulate_fmu(str(fmu), stop_time=4.0, output_interval=0.01, input=signal,
                      start_values={"x_contact": x_contact},
                      output=["x", "platen_position", "input_force", "clamp_force"])
print(f"simulated {len(result)} points: peak input force "
      f"{np.max(np.abs(result['input_force'])):.2f} N, final clamp force "
      f"{result['clamp_force'][-1]:.1f} N")

fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(7, 4.5), dpi=90)
ax1.plot(result["time"], result["x"] * 1e3, label="crosshead x")
ax1.plot(result["time"], result["platen_position"] * 1e3, label="platen")
ax1.set_ylabel("position (mm)")
ax1.legend()
ax2.plot(result["time"], result["input_force"], label="input force")
ax2.plot(result["time"], result["clamp_force"], label="clamp force")
ax2.set(xlabel="time (s)", ylabel="force (N)")
ax2.legend()
ax1.set_title("ToggleClamp.fmu in fmpy: a 3 s ramp to the toggle")
fig.tight_layout()
fig.savefig(out / "fmu_with_fmpy.png")
print(f"results in {out}")
