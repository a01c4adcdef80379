"""The Monte Carlo's one-pass statistics (toggle/mc_summary.py) and ``toggle tolerance``'s
run of it: the statistics of all the samples without keeping them (the percentiles to the
bit, mean and σ to rounding), the kernel's C accumulating as numpy does (to the bit), a
window that misses falling back to all the samples, the same seed giving the same
numbers, and the progress as lines on a pipe with an error the last line."""

from __future__ import annotations

import functools
import json
import math
import subprocess
import sys

import numpy as np
import pytest
from cli_fuzz import run_command

from toggle import mc_kernel, mc_summary, philox, tolerance
from toggle.kinematics import AssemblyError, output_position, toggle_position
from toggle.mc_summary import OUTPUTS, PILOT, Summary
from toggle.params import HALVES
from toggle.tolerance import Statistics, _outputs, _scale, it_tolerances, monte_carlo
from toggle_cli import main

answer = functools.partial(run_command, main)  # (argv, capsys) -> (code, stdout, stderr)
N = PILOT + 54_464  # the pilot and more: the windows are used


def all_samples(mech, tol, n: int, seed: int) -> dict[str, Statistics]:
    """The statistics as monte_carlo() made them before toggle.mc_summary: every sample's
    outputs kept (the same draws and kinematics), then summarised."""
    x, key = toggle_position(mech.lower), philox.key(seed)
    out = {}
    for stream, h in enumerate(HALVES):
        out[h] = np.empty(n)
        _outputs(x, mech.half(h), _scale(tol[h], "normal"), key, 0, stream, "normal", out[h],
                 h)
    nominal = {h: float(output_position(x, mech.half(h))) for h in HALVES}
    values = (out["lower"] - nominal["lower"], out["upper"] - nominal["upper"],
              out["upper"] - out["lower"])
    return {k: Statistics.of(v) for k, v in zip(OUTPUTS, values)}


def test_the_statistics_are_those_of_all_the_samples(chang):
    tol = it_tolerances(chang, 10)
    got = monte_carlo(chang, tol, samples=N, seed=11)
    for part, expected in all_samples(chang, tol, N, 11).items():
        stats = getattr(got, part)
        assert stats.percentiles == expected.percentiles, part  # the same order statistics
        assert stats.mean == pytest.approx(expected.mean, rel=1e-12, abs=1e-12 * expected.std)
        assert stats.std == pytest.approx(expected.std, rel=1e-12)


def test_the_kernels_accumulation_is_numpys_to_the_bit():
    """Chunks that straddle the sums' blocks, values in and out of every window."""
    if mc_kernel.load() is None:
        pytest.skip("no C compiler")
    rng = np.random.default_rng(5)
    n, nominal = 3 * PILOT + 123, (0.1, 0.1002)
    lower = nominal[0] + 6e-5 * rng.standard_normal(n)
    upper = nominal[1] + 6e-5 * rng.standard_normal(n)
    runs = []
    for kernel in (mc_kernel.load(), None):
        summary = Summary(n, nominal, lower[:PILOT], upper[:PILOT])
        for start, end in ((0, PILOT), (PILOT, PILOT + 5000), (PILOT + 5000, n)):
            summary.add(start, lower[start:end], upper[start:end], kernel)
        runs.append(summary)
    c, py = runs
    for name in ("sums", "below", "filled"):
        assert np.array_equal(getattr(c, name), getattr(py, name)), name
    for j in range(c.cap.size):
        kept = slice(c.base[j], c.base[j] + c.filled[j])
        assert np.array_equal(c.kept[kept], py.kept[kept]), j
    assert c.statistics().keys() == py.statistics().keys()
    for k, (mean, std, pct) in c.statistics().items():
        assert (mean, std) == py.statistics()[k][:2]
        assert np.array_equal(pct, py.statistics()[k][2])
        values = {"lower": lower - nominal[0], "upper": upper - nominal[1],
                  "asymmetry": upper - lower}[k]
        assert np.array_equal(pct, np.percentile(values, mc_summary.QUANTILES))
        assert std == pytest.approx(values.std(ddof=1), rel=1e-12)


def test_a_window_that_misses_falls_back_to_all_the_samples(chang, monkeypatch):
    """Windows of no width around the pilot's quantiles miss the run's: the percentiles
    are then selected from all the samples, the same values."""
    tol = it_tolerances(chang, 10)
    expected = monte_carlo(chang, tol, samples=N, seed=2)
    monkeypatch.setattr(mc_summary, "WINDOW_Z", 0.0)
    calls = []
    monkeypatch.setattr(tolerance, "percentiles",
                        lambda v: calls.append(v.size) or mc_summary.percentiles(v))
    assert monte_carlo(chang, tol, samples=N, seed=2) == expected
    assert N in calls  # the fallback ran


def test_tied_outputs_overflow_their_windows_and_still_summarise(chang):
    """No tolerance at all: every output is the nominal one (all tied)."""
    tol = {h: dict.fromkeys(t, 0.0) for h, t in it_tolerances(chang, 10).items()}
    got = monte_carlo(chang, tol, samples=N, seed=1)
    for part in OUTPUTS:
        stats = getattr(got, part)
        assert stats.std == 0.0
        assert len(set(stats.percentiles.values())) == 1
        assert math.isclose(stats.mean, next(iter(stats.percentiles.values())), abs_tol=1e-18)


def tolerance_json(capsys, *args: str) -> dict:
    code, out, _ = answer(["tolerance", "--samples", "70000", "--json", *args], capsys)
    assert code == 0
    return json.loads(out)["monte_carlo"]


def test_the_same_seed_gives_the_same_statistics(chang, capsys):
    first = tolerance_json(capsys, "--seed", "3")
    assert tolerance_json(capsys, "--seed", "3") == first
    assert tolerance_json(capsys, "--seed", "4") != first
    mc = monte_carlo(chang, it_tolerances(chang, 10), samples=70_000, seed=3)
    assert first["lower"]["percentiles"] == mc.lower.percentiles


@pytest.fixture
def every_count_shown(monkeypatch):
    """Progress shown from the start (stderr is not a terminal: a line at the first count,
    then every LINE_EVERY s, and the last count at the end)."""
    from controllers import progress
    monkeypatch.setattr(progress, "SHOW_AFTER", 0.0)


def test_on_a_pipe_the_progress_is_lines_with_count_and_eta(every_count_shown, capsys):
    code, out, err = answer(["tolerance", "--samples", "200000"], capsys)
    assert code == 0 and "Monte Carlo (200000 samples" in out
    assert "\r" not in err
    lines = err.splitlines()
    assert lines and all(line.startswith("Monte Carlo: ") for line in lines)
    assert len(lines) >= 2 and lines[0].startswith(f"Monte Carlo: {PILOT}/200000 samples done")
    assert lines[-1].startswith("Monte Carlo: 200000/200000 samples done")
    assert all(" elapsed, ETA " in line for line in lines)


def test_an_error_after_progress_lines_is_the_last_line(every_count_shown, capsys,
                                                         monkeypatch):
    """A sample that cannot assemble in a late chunk: the progress lines, then the error."""
    def failing(x, dims, scale, key, start, *args):
        if start >= PILOT + 65_536:
            raise AssemblyError("lower half (sampled): cannot assemble")
        return outputs(x, dims, scale, key, start, *args)

    outputs = tolerance._outputs
    monkeypatch.setattr(tolerance, "_outputs", failing)
    code, _, err = answer(["tolerance", "--samples", "300000"], capsys)
    assert code == 2
    lines = err.splitlines()
    assert len(lines) >= 2 and lines[0].startswith("Monte Carlo: ")
    assert lines[-1] == "toggle tolerance: error: lower half (sampled): cannot assemble"
    assert "\r" not in err


def test_the_command_loads_neither_scipy_nor_tqdm():
    """``toggle tolerance --samples N`` (fresh process): scipy.optimize alone cost 0.3 s of
    CPU, a third of a 1e7-sample run; tqdm draws only a terminal's bar."""
    probe = ("import json, sys, contextlib, io, toggle_cli\n"
             "with contextlib.redirect_stdout(io.StringIO()):\n"
             "    code = toggle_cli.main(['tolerance', '--samples', '70000'])\n"
             "print(code, json.dumps(sorted({m.split('.')[0] for m in sys.modules}\n"
             "                              & {'scipy', 'tqdm', 'matplotlib'})))\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True).stdout.split(maxsplit=1)
    assert out[0] == "0" and json.loads(out[1]) == []
