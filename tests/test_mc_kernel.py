"""The compiled Monte Carlo kernel (toggle.mc_kernel) gives the numpy path's statistics.

Same seed, same draws (toggle.philox: made in C by the kernel, in numpy by the fallback;
the same uniforms bit for bit, normals within a few ulps): the statistics of monte_carlo()
with the kernel equal those of the numpy path to 1e-9 relative (with a floor of 1e-9 of the
sample's spread plus 1e-15 m, for a mean or median that is nearly zero), for every clamp
preset and over random tolerances; samples that cannot assemble behave exactly as before.
"""

from __future__ import annotations

import math
from unittest import mock

import numpy as np
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from toggle import mc_kernel, philox
from toggle.kinematics import AssemblyError, half_pose, output_position, stroke_limits
from toggle.params import (
    DIMENSIONS,
    HALVES,
    ParameterError,
    load_preset,
    preset_groups,
    preset_names,
)
from toggle.tolerance import MonteCarloResult, _outputs, it_tolerances, monte_carlo

REL = 1e-9
#: Where a statistic is (nearly) zero: the rounding of the positions themselves (a few
#: ulps of a 0.1 m position, vector libm within 4 ulps of numpy's).
ROUNDING = 1e-15  # m


def clamp_presets() -> list[str]:
    """Every shipped clamp mechanism (each group of a family; not the press)."""
    names = []
    for name in preset_names():
        for group in preset_groups(name) or [None]:
            label = name if group is None else f"{name}/{group}"
            try:
                load_preset(label)
            except ParameterError:  # a preset of another machine (the toggle press)
                continue
            names.append(label)
    return names


def numpy_path(*args, **kwargs) -> MonteCarloResult:
    """monte_carlo() as it was: the kinematics in numpy."""
    with mock.patch("toggle.mc_kernel.load", return_value=None):
        return monte_carlo(*args, **kwargs)


def assert_same(a: MonteCarloResult, b: MonteCarloResult) -> None:
    for part in ("lower", "upper", "asymmetry"):
        sa, sb = getattr(a, part), getattr(b, part)
        floor = REL * sb.std + ROUNDING
        assert sa.std == pytest.approx(sb.std, rel=REL, abs=ROUNDING), part
        assert sa.mean == pytest.approx(sb.mean, rel=REL, abs=floor), part
        assert sa.percentiles.keys() == sb.percentiles.keys()
        for q, value in sb.percentiles.items():
            assert sa.percentiles[q] == pytest.approx(value, rel=REL, abs=floor), (part, q)


@pytest.fixture(params=["vectorised", "scalar"])
def kernel(request, monkeypatch, tmp_path):
    """The kernel as built here (vectorised with libmvec), and its scalar fallback build."""
    if request.param == "scalar":
        monkeypatch.setenv("TOGGLE_CACHE_DIR", str(tmp_path))
        monkeypatch.setattr(mc_kernel, "_VARIANTS", mc_kernel._VARIANTS[1:])
    mc_kernel.load.cache_clear()
    yield mc_kernel.load()
    mc_kernel.load.cache_clear()


def test_the_kernel_is_compiled_and_equals_the_kinematics_per_sample(chang, kernel):
    assert kernel is not None  # gcc is on this machine: the comparisons below are real
    x = stroke_limits(chang.lower)[1]
    nominal = np.array(chang.lower.as_tuple())
    scale = np.array(list(it_tolerances(chang, 10)["lower"].values())) / 3.0
    draws = np.random.default_rng(5).standard_normal((len(DIMENSIONS), 10_000))
    out, bad = kernel.outputs(x, nominal, scale, draws)
    expected = output_position(x, list(nominal[:, None] + scale[:, None] * draws))
    assert bad == 0
    np.testing.assert_allclose(out, expected, rtol=4 * np.finfo(float).eps, atol=0)
    key, start = philox.key(5), 2**32 - 5000  # across the counter's high word
    for distribution in ("normal", "uniform"):
        drawn = np.empty(10_000)
        assert kernel.sampled(x, nominal, scale, key, start, 1, distribution, drawn) == 0
        draws = kernel.draws(key, start, drawn.size, 1, distribution)
        expected = output_position(x, list(nominal[:, None] + scale[:, None] * draws))
        np.testing.assert_allclose(drawn, expected, rtol=4 * np.finfo(float).eps, atol=0)


@pytest.mark.parametrize("preset", clamp_presets())
@pytest.mark.parametrize("distribution", ["normal", "uniform"])
def test_statistics_equal_the_numpy_path_for_every_preset(preset, distribution):
    mech = load_preset(preset)
    tol = it_tolerances(mech, 8)
    x_open, x_tp = stroke_limits(mech.lower)
    for x in (x_tp, 0.5 * (x_open + x_tp)):
        kw = dict(x=x, samples=20_000, distribution=distribution, seed=11, chunk=8192)
        assert_same(monte_carlo(mech, tol, **kw), numpy_path(mech, tol, **kw))


@settings(max_examples=60, deadline=None)
@given(fractions=st.lists(st.floats(0.0, 1.0), min_size=2 * len(DIMENSIONS),
                          max_size=2 * len(DIMENSIONS)),
       widest=st.sampled_from([3e-5, 3e-4, 3e-3, 1e-2]),
       where=st.floats(0.0, 1.0), seed=st.integers(0, 2**32 - 1),
       distribution=st.sampled_from(["normal", "uniform"]))
def test_statistics_equal_the_numpy_path_over_tolerances(chang, fractions, widest, where,
                                                         seed, distribution):
    """Any tolerances, up to 10 mm (wide enough that samples cannot assemble): the same
    statistics, or the same error."""
    bands = [f * widest for f in fractions]
    tol = {h: dict(zip(DIMENSIONS, bands[i::2])) for i, h in enumerate(HALVES)}
    x_open, x_tp = stroke_limits(chang.lower)
    kw = dict(x=x_open + where * (x_tp - x_open), samples=3000, seed=seed,
              distribution=distribution)
    try:
        expected = numpy_path(chang, tol, **kw)
    except AssemblyError as error:
        event("cannot assemble")
        with pytest.raises(AssemblyError) as raised:
            monte_carlo(chang, tol, **kw)
        assert str(raised.value) == str(error)
        return
    assert_same(monte_carlo(chang, tol, **kw), expected)


@pytest.mark.parametrize("band", [8e-3, math.nan, math.inf])
def test_samples_that_cannot_assemble_raise_the_same_error(chang, band):
    """r4b beyond r4a + r4c (5.6 mm more) breaks the triangular link 4 in some samples; a
    NaN or infinite tolerance in all of them."""
    tol = {h: {**it_tolerances(chang, 8)[h], "r4b": band} for h in HALVES}
    with pytest.raises(AssemblyError) as numpy_error:
        numpy_path(chang, tol, samples=50_000)
    with pytest.raises(AssemblyError) as kernel_error:
        monte_carlo(chang, tol, samples=50_000)
    assert str(kernel_error.value) == str(numpy_error.value)
    assert "lower half (sampled) cannot assemble" in str(kernel_error.value)


def test_a_rounding_level_excursion_is_clipped_as_numpy_does(chang):
    """A half whose crosshead-loop acos argument is 1 + 5e-13 is NaN in plain C; numpy
    clips it (within the 1e-12 slack): that chunk is taken from numpy, its draws too."""
    x = stroke_limits(chang.lower)[1]
    d, r4a = chang.lower.r1 - chang.lower.r2, chang.lower.r4a
    l = math.hypot(x, d)
    r3 = math.sqrt((l - r4a) ** 2 - 2 * l * r4a * 5e-13)  # argument 1 + 5e-13
    edge = chang.lower.replace(r3=r3)
    with np.errstate(invalid="ignore"):
        assert math.isnan(float(half_pose(x, edge, check=False).L))
    assert math.isfinite(float(output_position(x, edge)))
    nominal = np.array(edge.as_tuple())
    scale = np.full(len(DIMENSIONS), 1e-16)  # every sample at the edge, within rounding
    key = philox.key(3)
    out = np.empty(100)
    assert mc_kernel.load().sampled(x, nominal, scale, key, 0, 0, "normal", out) >= 1
    _outputs(x, edge, scale, key, 0, 0, "normal", out, "lower")
    draws = philox.draws(key, 0, out.size, 0, "normal")
    np.testing.assert_array_equal(out, output_position(
        x, list(nominal[:, None] + scale[:, None] * draws)))


@pytest.fixture
def no_compiler(tmp_path, monkeypatch):
    monkeypatch.setenv("TOGGLE_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    mc_kernel.load.cache_clear()
    yield tmp_path
    mc_kernel.load.cache_clear()


def test_without_a_compiler_numpy_runs_with_one_warning(chang, no_compiler, monkeypatch):
    tol = it_tolerances(chang, 9)
    with pytest.warns(UserWarning, match="no working C compiler") as caught:
        without = monte_carlo(chang, tol, samples=20_000, seed=4)
        monte_carlo(chang, tol, samples=20_000, seed=4)
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    assert not list(no_compiler.glob("*.so"))
    monkeypatch.delenv("CC")
    mc_kernel.load.cache_clear()
    assert mc_kernel.load() is not None
    assert_same(monte_carlo(chang, tol, samples=20_000, seed=4), without)
