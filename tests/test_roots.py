"""toggle.roots.brentq takes scipy.optimize.brentq's steps: the same roots to the bit (and
the same failures), on test functions and on every preset's stroke limits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize

from toggle import kinematics
from toggle.params import ParameterError, load_preset, preset_names
from toggle.roots import brentq

TIGHT = {"xtol": 1e-15, "rtol": 4 * np.finfo(float).eps}  # the kinematics' tolerances


def outcome(solver, f, a: float, b: float, **kw) -> float | str:
    try:
        return solver(f, a, b, **kw)
    except RuntimeError:
        return "no convergence"
    except ValueError:
        return "no sign change"


def functions() -> list[tuple]:
    fs = [(lambda x: x**3 - 2 * x - 5, 2.0, 3.0), (math.cos, 0.0, 3.0),
          (lambda x: math.exp(x) - 10, -1.0, 5.0), (lambda x: x - 1e-3, 0.0, 1.0),
          (lambda x: (x - 0.3) ** 5, 0.0, 1.0), (lambda x: math.atan(x - 0.7), -50.0, 50.0),
          (lambda x: x * x + 1, -1.0, 1.0), (lambda x: x, 0.0, 1.0)]
    rng = np.random.default_rng(1)
    for _ in range(200):
        c, r = rng.uniform(-1, 1, 3), rng.uniform(-0.9, 0.9)
        fs.append((lambda x, c=c, r=r: (x - r) * (1 + c[0] ** 2 + c[1] * x * x)
                   + c[2] * (x - r) ** 3, -1.0, 1.0))
    return fs


@pytest.mark.parametrize("kw", [{}, TIGHT])
def test_the_roots_are_scipys_to_the_bit(kw):
    for f, a, b in functions():
        assert outcome(brentq, f, a, b, **kw) == outcome(optimize.brentq, f, a, b, **kw), (a, b)


def test_every_presets_stroke_limits_are_those_scipy_finds(monkeypatch):
    halves = []
    for name in preset_names():
        try:
            mech = load_preset(name)
        except ParameterError:  # another machine's preset
            continue
        halves += [mech.lower, mech.upper]
    kinematics.stroke_limits.cache_clear()
    ours = [kinematics.stroke_limits(h) for h in halves]
    kinematics.stroke_limits.cache_clear()
    monkeypatch.setattr(kinematics, "brentq", optimize.brentq)
    assert [kinematics.stroke_limits(h) for h in halves] == ours
    kinematics.stroke_limits.cache_clear()


def test_a_nan_or_no_sign_change_is_a_clear_error():
    with pytest.raises(ValueError, match="different signs"):
        brentq(lambda x: x * x + 1, -1.0, 1.0)
    with pytest.raises(ValueError, match="NaN"):
        brentq(lambda x: math.nan if x > 0.4 else x - 0.5, 0.0, 1.0)
