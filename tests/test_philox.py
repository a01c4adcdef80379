"""The Monte Carlo's generator (toggle.philox): Philox4x32-10 against Random123's
known answers, the C kernel's draws against numpy's, the normals' statistics, and the
tolerance statistics against the generator it replaced (numpy's default_rng)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from toggle import mc_kernel, philox
from toggle.kinematics import toggle_position
from toggle.params import DIMENSIONS, HALVES
from toggle.tolerance import MonteCarloResult, Statistics, _scale, it_tolerances, monte_carlo

#: Random123's tests/kat_vectors for philox4x32_10: counter, key, output.
KNOWN_ANSWERS = [
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
     (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1)),
]
#: Level of each statistical test below (the seed is fixed: a failure is a real change).
ALPHA = 1e-3
Z = stats.norm.isf(ALPHA / 2)  # 3.29 standard errors


@pytest.fixture(scope="module")
def kernel() -> mc_kernel.Kernel:
    kernel = mc_kernel.load()
    assert kernel is not None  # gcc is on this machine: the comparisons below are real
    return kernel


@pytest.mark.parametrize("counter, key, expected", KNOWN_ANSWERS)
def test_philox_gives_random123s_known_answers_in_numpy_and_in_c(kernel, counter, key,
                                                                   expected):
    assert tuple(int(w) for w in philox.philox4x32(counter, key)) == expected
    assert kernel.philox4x32(counter, key) == expected


@pytest.mark.parametrize("start", [0, 2**32 - 300, 2**40 + 7])  # the high counter word too
@pytest.mark.parametrize("stream", [0, 1])
def test_the_kernels_draws_are_numpys(kernel, start, stream):
    """Uniform draws (exact arithmetic on the integers) equal bit for bit; normal draws
    within a few ulps (libmvec's and numpy's log, sin, cos differ in the last bits)."""
    key = philox.key(2024)
    for distribution in ("uniform", "normal"):
        c = kernel.draws(key, start, 600, stream, distribution)
        py = philox.draws(key, start, 600, stream, distribution)
        assert c.shape == py.shape == (len(DIMENSIONS), 600)
        if distribution == "uniform":
            np.testing.assert_array_equal(c, py)
        else:
            np.testing.assert_allclose(c, py, rtol=0, atol=1e-14)


def test_the_draws_depend_on_the_sample_alone():
    """Counter-based: any split gives the same draws; seeds and halves are apart."""
    key = philox.key(1)
    whole = philox.draws(key, 0, 1000, 0, "normal")
    np.testing.assert_array_equal(whole[:, 400:], philox.draws(key, 400, 600, 0, "normal"))
    assert not np.any(whole == philox.draws(key, 0, 1000, 1, "normal"))
    assert not np.any(whole == philox.draws(philox.key(2), 0, 1000, 0, "normal"))
    assert philox.key(7) == philox.key(7) != philox.key(None)


@pytest.mark.parametrize("stream", [0, 1])
def test_the_normals_are_standard_normal(stream):
    """Each dimension's 200 000 draws: mean, variance, skewness and kurtosis within their
    standard errors times Z (two-sided level ALPHA), a Kolmogorov-Smirnov test against
    N(0, 1) at level ALPHA, and the dimensions uncorrelated (the 28 pairs' correlations at
    level ALPHA together: each at ALPHA / 28, Bonferroni)."""
    n = 200_000
    draws = philox.draws(philox.key(11), 0, n, stream, "normal")
    for d in draws:
        assert abs(d.mean()) < Z / math.sqrt(n)
        assert abs(d.var() - 1.0) < Z * math.sqrt(2.0 / n)
        assert abs(stats.skew(d)) < Z * math.sqrt(6.0 / n)
        assert abs(stats.kurtosis(d)) < Z * math.sqrt(24.0 / n)
        assert stats.kstest(d, "norm").pvalue > ALPHA
    corr = np.corrcoef(draws)[np.triu_indices(len(DIMENSIONS), 1)]
    assert np.all(np.abs(corr) < stats.norm.isf(ALPHA / 2 / corr.size) / math.sqrt(n))


def test_the_uniforms_are_uniform_on_minus_one_one():
    draws = philox.draws(philox.key(12), 0, 200_000, 0, "uniform")
    assert draws.min() >= -1.0 and draws.max() < 1.0
    for d in draws:
        assert stats.kstest(d, "uniform", args=(-1.0, 2.0)).pvalue > ALPHA


def test_a_monte_carlo_does_not_depend_on_its_chunks(chang):
    tol = it_tolerances(chang, 9)
    a = monte_carlo(chang, tol, samples=30_000, seed=3, chunk=1000)
    assert a == monte_carlo(chang, tol, samples=30_000, seed=3, chunk=65_536)
    assert a != monte_carlo(chang, tol, samples=30_000, seed=4, chunk=1000)


def numpy_generator(mech, tol, samples: int, seed: int) -> MonteCarloResult:
    """monte_carlo() as it was before toggle.philox: numpy's default_rng draws all 16
    dimensions chunk by chunk, the kernel evaluates them."""
    rng, x, chunk = np.random.default_rng(seed), toggle_position(mech.lower), 65_536
    out = {h: np.empty(samples) for h in HALVES}
    for start in range(0, samples, chunk):
        n = min(chunk, samples - start)
        for h in HALVES:
            draws = rng.standard_normal((len(DIMENSIONS), n))
            out[h][start:start + n] = mc_kernel.load().outputs(
                x, np.array(mech.half(h).as_tuple()), _scale(tol[h], "normal"), draws)[0]
    nominal = {h: float(mc_kernel.load().outputs(x, np.array(mech.half(h).as_tuple()),
                                                 np.zeros(len(DIMENSIONS)),
                                                 np.zeros((len(DIMENSIONS), 1)))[0][0])
               for h in HALVES}
    asym = out["upper"] - out["lower"]
    return MonteCarloResult(x, samples, Statistics.of(out["lower"] - nominal["lower"]),
                            Statistics.of(out["upper"] - nominal["upper"]),
                            Statistics.of(asym))


def test_the_statistics_agree_with_numpys_generator_within_their_error(chang):
    """Two independent runs of n: the means differ by less than Z sqrt(2) sigma/sqrt(n),
    the sigmas by Z sqrt(2) sigma/sqrt(2n), the 3-sigma bounds (p0.135, p99.865) by
    Z sqrt(2) times a quantile's standard error sqrt(p(1-p)/n)/f(q) for a normal density
    f; the bounds 3 sigma off the mean as a normal's (the errors are nearly linear)."""
    n, tol = 400_000, it_tolerances(chang, 10)
    new = monte_carlo(chang, tol, samples=n, seed=5)
    old = numpy_generator(chang, tol, n, seed=5)
    p = 0.00135
    q_error = math.sqrt(p * (1 - p) / n) / stats.norm.pdf(stats.norm.isf(p))
    for part in ("lower", "upper", "asymmetry"):
        a, b = getattr(new, part), getattr(old, part)
        sigma = b.std
        assert abs(a.mean - b.mean) < Z * math.sqrt(2) * sigma / math.sqrt(n), part
        assert abs(a.std - b.std) < Z * math.sqrt(2) * sigma / math.sqrt(2 * n), part
        for q in ("p0.135", "p99.865"):
            assert abs(a.percentiles[q] - b.percentiles[q]) < Z * math.sqrt(2) * q_error * sigma
            assert abs(a.percentiles[q] - a.mean) == pytest.approx(3 * a.std, rel=0.05)
