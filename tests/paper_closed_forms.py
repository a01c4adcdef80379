"""Seed 000's closed-form equations, kept as independent test oracles.

Eqs 3, 5, 16, 17 (the upper half written directly, not as a mirror) and the
kinematic error equations 20-27 / 30-37 with the signs lost in the extracted
text restored (derived by hand from Eq 2 and Eqs 4, 6-8, 12):

    dL/dtheta = r_b (cos theta_in tan theta_out - sin theta_in)
    dtheta4/dp = -(d alpha4 + d gamma1 + d gamma2)/dp  (lower)
    dtheta7/dp = +(d alpha7 + d gamma1U + d gamma2U)/dp  (upper)
"""

from __future__ import annotations

import math

from toggle.params import HalfDims


def upper_pose(x: float, d: HalfDims) -> dict[str, float]:
    """Upper half by Eqs 3, 5, 9-11, 13, 16, 17 as printed (signs per seed-notes)."""
    lU = math.hypot(x, d.r1 - d.r2)
    g1 = math.asin(x / lU)
    g2 = math.acos((lU**2 + d.r4a**2 - d.r3**2) / (2 * lU * d.r4a))
    a7 = math.acos((d.r4a**2 + d.r4b**2 - d.r4c**2) / (2 * d.r4a * d.r4b))
    t7 = 1.5 * math.pi + (a7 + g1 + g2)
    L = d.r4b * math.cos(t7) + math.sqrt(d.r5**2 - (d.r4b * math.sin(t7) + d.e) ** 2)
    t6 = 0.5 * math.pi + g1 - math.acos((lU**2 + d.r3**2 - d.r4a**2) / (2 * lU * d.r3))
    t8 = -math.asin((d.r4b * math.sin(t7) + d.e) / d.r5)
    return {"L": L, "theta6": t6, "theta7": t7, "theta8": t8, "gamma1": g1, "gamma2": g2,
            "alpha": a7, "l": lU}


def error_coefficients(d: HalfDims, g1: float, g2: float, alpha: float, l: float,
                       t_in: float, t_out: float, chain_sign: float) -> dict[str, float]:
    """dL/dp of Eqs 20-27 (chain_sign = -1, lower) or Eqs 30-37 (+1, upper)."""
    K = d.r4b * (math.cos(t_in) * math.tan(t_out) - math.sin(t_in))
    s, c, cot2 = math.sin(g1), math.cos(g1), 1 / math.tan(g2)
    # d(alpha + gamma1 + gamma2)/dp for each dimension
    dr1 = -s / l + c * (cot2 / l - 1 / (d.r4a * math.sin(g2)))
    chain = {
        "r1": dr1,
        "r2": -dr1,
        "r3": d.r3 / (l * d.r4a * math.sin(g2)),
        "r4a": (d.r4b * math.cos(alpha) - d.r4a) / (d.r4a * d.r4b * math.sin(alpha))
        + (l * math.cos(g2) - d.r4a) / (d.r4a * l * math.sin(g2)),
        "r4b": (d.r4a * math.cos(alpha) - d.r4b) / (d.r4a * d.r4b * math.sin(alpha)),
        "r4c": d.r4c / (d.r4a * d.r4b * math.sin(alpha)),
    }
    out = {k: K * chain_sign * v for k, v in chain.items()}
    out["r4b"] += math.cos(t_in) + math.sin(t_in) * math.tan(t_out)
    out["r5"] = 1 / math.cos(t_out)  # Eq 26 / 36: sec theta
    out["e"] = -math.tan(t_out) if chain_sign < 0 else math.tan(t_out)  # Eq 27 / 37
    return out
