"""The packages' layers: toggle (the plant and its analysis) <- controllers (the planner)
<- hil (the rig), and toggle <- controllers <- design (the clamp's synthesis). A lower layer
imports nothing of a higher one, and design and hil nothing of each other."""

from __future__ import annotations

import subprocess
import sys

import pytest

LAYERS = {
    "toggle": ("toggle.plant", "toggle.plots", "toggle.rig_tables", "toggle.fmu_build",
               "toggle.cli.args"),
    "controllers": ("controllers.planner", "controllers.profiles", "controllers.bounds"),
    "design": ("design.search", "design.runner", "design.output", "design.placement",
               "design.figures", "design.timing"),
    "hil": ("hil.cli", "hil.experiment", "hil.backends"),
}
HIGHER = {"toggle": ("controllers", "hil", "design"), "controllers": ("hil", "design"),
          "design": ("hil",), "hil": ("design",)}


@pytest.mark.parametrize("layer", sorted(LAYERS))
def test_a_layer_imports_nothing_above_it(layer: str) -> None:
    code = (f"import sys\nimport {', '.join(LAYERS[layer])}\n"
            "print(sorted({m.split('.')[0] for m in sys.modules}))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True).stdout
    assert not [pkg for pkg in HIGHER[layer] if f"'{pkg}'" in loaded], loaded
