"""Outputs that were wrong or misleading, each with the check that would have caught it:
the mechanical advantage at the toggle, calibrate's relative error of a zero force, the
command line reference's sweep example (docs/cli.md)."""

from __future__ import annotations

import json
import math
import shlex
from pathlib import Path

import numpy as np
import pytest

from toggle.asymmetry import AsymmetryParams
from toggle.calibration import compare, load_force_table
from toggle.kinematics import half_motion, stroke_limits
from toggle.params import load_preset
from toggle_cli import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", ["chang2021", "lin2003_sm55"])
def test_the_mechanical_advantage_is_unbounded_at_the_toggle_never_negative(name: str) -> None:
    """It was -6.4e15 at x_TP (dL/dx rounded to -1.6e-16)."""
    dims = load_preset(name).lower
    x_open, x_tp = stroke_limits(dims)
    ma = half_motion(np.linspace(x_open, x_tp, 50), dims).mechanical_advantage
    assert ma[-1] == math.inf
    assert np.all(ma[:-1] > 0) and np.all(np.isfinite(ma[:-1]))


def test_kinematics_json_gives_null_at_the_toggle_with_a_note(
        capsys: pytest.CaptureFixture) -> None:
    assert main(["kinematics", "--points", "5", "--json"]) == 0
    profile = json.loads(capsys.readouterr().out)["profile"]
    for half in ("lower", "upper"):
        values = profile[half]["mechanical_advantage"]
        assert values[-1] is None and all(v > 0 for v in values[:-1])
    assert "unbounded at the toggle" in profile["note"]
    assert main(["kinematics", "--points", "5"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()]
    assert [r for r in rows if r and r[-1] == "inf"] and not any("e+15" in c for r in rows
                                                                   for c in r)


def test_calibrate_gives_no_relative_error_for_a_force_within_its_band_of_zero(
        capsys: pytest.CaptureFixture) -> None:
    """It printed "0.00 model, -100.00 %, in band yes" for the three delta_r8 = 0 rows."""
    table = load_force_table()
    rows = compare(table, load_preset("chang2021"), AsymmetryParams())
    for r in rows:
        zero = abs(r.measured) <= r.three_sigma
        assert math.isnan(r.relative_error) == zero
        if not zero:
            assert r.relative_error == pytest.approx((r.model - r.measured) / r.measured)
    assert any(math.isnan(r.relative_error) for r in rows)
    assert main(["calibrate"]) == 0
    out = capsys.readouterr().out
    assert "-100.00" not in out and "n/a" in out and "error N" in out


def _readme_command(name: str) -> list[str]:
    """The command line reference's example of ``toggle NAME`` (docs/cli.md, which holds
    what the README's command list was)."""
    text = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    (line,) = [ln for ln in text.splitlines() if ln.startswith(f"toggle {name} ")]
    return shlex.split(line.split("#")[0])[1:]


def test_the_readmes_sweep_example_assembles_at_every_grid_point(
        capsys: pytest.CaptureFixture) -> None:
    """It left 15 of its 25 points unassemblable (60 % of the figure blank)."""
    argv = _readme_command("sweep")
    assert main([*argv, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["failures"] == []
    counts = [int(argv[i + 4]) for i, a in enumerate(argv) if a == "--dim"]  # NAME START STOP N
    for grid in data["criteria"].values():
        assert np.array(grid, dtype=float).shape == tuple(counts)
        assert np.all(np.isfinite(np.array(grid, dtype=float)))
