"""What every example shares: its output folder (the first argument, default
``examples/output``) and a non-interactive matplotlib."""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")


def output_folder() -> Path:
    """The folder the example writes into: ``sys.argv[1]`` or ``examples/output``."""
    folder = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("output")
    folder.mkdir(parents=True, exist_ok=True)
    return folder
