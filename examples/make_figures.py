"""Run every example and copy its figure into docs/examples/ (the site shows the committed
figures: its build stays seconds and needs no solver). ``python examples/make_figures.py``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: The examples, each one job end to end, in the order the site lists them.
EXAMPLES = ("mechanical_errors", "plan_and_export", "simulated_rig", "fmu_with_fmpy",
            "design_search")
FIGURES = HERE.parent / "docs" / "examples"


def main() -> int:
    FIGURES.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="toggle-examples-") as tmp:
        for name in EXAMPLES:
            subprocess.run([sys.executable, str(HERE / f"{name}.py"), tmp], check=True,
                           cwd=HERE.parent)
            shutil.copyfile(Path(tmp) / f"{name}.png", FIGURES / f"{name}.png")
            print(f"{FIGURES / name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
