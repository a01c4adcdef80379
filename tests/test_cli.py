"""The ``toggle`` command line: JSON output, tables, figures and error messages."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from toggle_cli import main

MM = 1e-3


def run_json(capsys, *argv):
    assert main([*argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_kinematics_json(capsys):
    data = run_json(capsys, "kinematics", "--preset", "chang2021")
    assert data["stroke"] == pytest.approx(45.003 * MM, abs=1e-6)
    assert data["x_toggle"] == pytest.approx(51.566 * MM, abs=1e-6)
    assert data["x_open"] == pytest.approx(-3.439 * MM, abs=1e-6)
    assert math.degrees(data["theta8_toggle"]) == pytest.approx(-2.729, abs=1e-3)


def test_kinematics_table_is_in_millimetres(capsys):
    assert main(["kinematics", "--points", "3"]) == 0
    out = capsys.readouterr().out
    assert "45.0034" in out and "51.5661" in out and "x_TP mm" in out


def test_tolerance_json_has_indices_and_sensitivities(capsys):
    data = run_json(capsys, "tolerance", "--preset", "chang2021", "--it", "10",
                    "--samples", "20000")
    assert 0.5 * MM < data["dL_wor"] < 0.6 * MM
    assert data["dL_rss"] < data["dL_wor"]
    assert set(data["sensitivities"]) == {"lower", "upper"}
    assert data["sensitivities"]["upper"]["r8"] == pytest.approx(1 / math.cos(math.radians(2.7294)),
                                                                  rel=1e-4)
    assert data["monte_carlo"]["samples"] == 20000
    other = run_json(capsys, "tolerance", "--it", "10", "--x", "0.03")
    assert other["x"] == 0.03
    assert abs(other["sensitivities"]["lower"]["r3"]) > 0.01  # away from the toggle r3 matters


def test_plots_write_png_files(tmp_path, capsys):
    assert main(["plot", "kinematics", "--out", str(tmp_path)]) == 0
    assert main(["plot", "tolerance", "--it", "8", "--out", str(tmp_path)]) == 0
    for name in ("kinematics_chang2021.png", "sensitivity_IT8_chang2021.png",
                 "asymmetry_vs_it_chang2021.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_bad_input_gives_a_clear_message(capsys):
    assert main(["kinematics", "--preset", "nope"]) == 2
    assert "unknown preset 'nope'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["tolerance", "--it", "30"])
    assert info.value.code == 2
    assert "IT grade" in capsys.readouterr().err
    assert main(["tolerance", "--x", "0.2"]) == 2
    assert "cannot assemble at x = 0.2" in capsys.readouterr().err


def test_json_text_writes_null_for_non_finite_numbers():
    """JSON has no NaN or Infinity: `toggle calibrate --json` wrote "hersey_transition":
    Infinity (the film law off), which strict readers (jq, a browser) refuse."""
    from toggle.json_text import json_text

    text = json_text({"h_s": math.inf, "e": [math.nan, 1.5], "n": np.float64(-np.inf), "k": 2})
    assert json.loads(text, parse_constant=lambda c: pytest.fail(c)) == {
        "h_s": None, "e": [None, 1.5], "n": None, "k": 2}
