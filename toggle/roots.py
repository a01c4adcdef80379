"""Brent's root bracketing, step for step as ``scipy.optimize.brentq`` takes it.

The kinematics find the stroke limits of every half by Brent's method; importing
``scipy.optimize`` for it costs a command 0.3 s of CPU (its package loads linear
programming, the FFT and the docstrings of everything), more than a 1e7-sample Monte
Carlo's statistics. This is the same method (Brent 1973, *Algorithms for minimization
without derivatives*, ch. 4: inverse quadratic interpolation or secant steps, bisection
where they are not short enough) with scipy's choices of steps and tolerance
(xtol + rtol |x|), so the roots are scipy's to the bit (``tests/test_roots.py`` checks it on
every preset's stroke limits and on test functions).
"""

from __future__ import annotations

import math
from collections.abc import Callable

#: scipy's default tolerances and iteration cap.
XTOL, RTOL, MAXITER = 2e-12, 4 * 2.220446049250313e-16, 100


def brentq(f: Callable[[float], float], a: float, b: float, xtol: float = XTOL,
           rtol: float = RTOL, maxiter: int = MAXITER) -> float:
    """A root of ``f`` in [a, b], where f(a) and f(b) differ in sign, to within
    xtol + rtol |x|; ValueError where they do not differ or f is NaN, RuntimeError where
    ``maxiter`` steps do not converge."""
    if xtol <= 0 or rtol < RTOL:
        raise ValueError(f"brentq needs xtol > 0 and rtol >= {RTOL}, got {xtol}, {rtol}")

    def value(x: float) -> float:
        y = float(f(x))
        if math.isnan(y):
            raise ValueError(f"the function is NaN at x = {x!r}")
        return y

    x_pre, x_cur = float(a), float(b)
    f_pre, f_cur = value(x_pre), value(x_cur)
    if math.copysign(1.0, f_pre) == math.copysign(1.0, f_cur) and f_pre != 0 and f_cur != 0:
        raise ValueError("f(a) and f(b) must have different signs")
    if f_pre == 0:
        return x_pre
    if f_cur == 0:
        return x_cur
    x_blk = f_blk = s_pre = s_cur = 0.0
    for _ in range(maxiter):
        if f_pre != 0 and f_cur != 0 and (
                math.copysign(1.0, f_pre) != math.copysign(1.0, f_cur)):
            x_blk, f_blk = x_pre, f_pre
            s_pre = s_cur = x_cur - x_pre
        if abs(f_blk) < abs(f_cur):  # the better end becomes the current estimate
            x_pre, x_cur, x_blk = x_cur, x_blk, x_cur
            f_pre, f_cur, f_blk = f_cur, f_blk, f_cur
        delta = (xtol + rtol * abs(x_cur)) / 2
        s_bis = (x_blk - x_cur) / 2
        if f_cur == 0 or abs(s_bis) < delta:
            return x_cur
        interpolated = False  # bisection unless interpolation gives a short enough step
        if abs(s_pre) > delta and abs(f_cur) < abs(f_pre):
            if x_pre == x_blk:  # secant
                trial = -f_cur * (x_cur - x_pre) / (f_cur - f_pre)
            else:  # inverse quadratic
                d_pre = (f_pre - f_cur) / (x_pre - x_cur)
                d_blk = (f_blk - f_cur) / (x_blk - x_cur)
                trial = -f_cur * (f_blk * d_blk - f_pre * d_pre) / (d_blk * d_pre * (f_blk - f_pre))
            interpolated = 2 * abs(trial) < min(abs(s_pre), 3 * abs(s_bis) - delta)
            if interpolated:
                s_pre, s_cur = s_cur, trial
        if not interpolated:
            s_pre = s_cur = s_bis
        x_pre, f_pre = x_cur, f_cur
        x_cur += s_cur if abs(s_cur) > delta else (delta if s_bis > 0 else -delta)
        f_cur = value(x_cur)
    raise RuntimeError(f"brentq did not converge in {maxiter} iterations")
