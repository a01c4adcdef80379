"""A lower bound on the peak input force of any clamping stroke: what no profile can beat.

After mold contact the platen rests and the input force is
F(x, v, a) = m_in a + F(x, v, 0), with m_in the crosshead's share of the mass
(``dF/da``, from the plant) and F(x, v, 0) the damping plus the thrust
against the tie bars with pin friction. Written in the crosshead position x,
the kinetic energy per unit mass E = v^2 / 2 obeys dE/dx = a. A stroke whose
|F| stays below s must therefore keep, at every x from contact to the toggle,

    -a_max <= dE/dx <= (s - F(x, v, 0)) / m_in,    v_creep <= v <= v_max,

so braking (dE/dx < 0) relieves the thrust, bought with speed gained before
(inertia relief). :func:`peak_lower_bound` bisects on s: s is possible only if
the reachable set of speeds, swept from contact (any speed up to v_max) to
the toggle on a grid, stays non-empty. The sweep over-approximates the
reachable set (each step takes the force's least value over the step and
widens the set by a grid cell), so the bound is conservative. It relaxes the
plan's problem (no jerk limit, no duration, no platen-speed limit at contact):
it holds for every duration. It assumes the crosshead does not creep below
the planner's floor (``CREEP_FACTOR`` times the friction model's smoothing
speed) through the clamping, where the smooth friction model would fade out.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from toggle.plant import PlantConfig, plant_outputs

#: The inertia m_in = dF/da is sampled at every this many grid positions and speeds.
_COARSE = 10


def _sweep(s: float, F0: np.ndarray, m_in: float, E: np.ndarray, dx: np.ndarray,
           a_max: float) -> bool:
    """Whether the energies E (grid) let a stroke pass every step under the peak s."""
    reach = np.ones(E.size, bool)  # at contact any speed up to v_max
    cell = np.diff(E, prepend=E[0], append=E[-1])
    widen = np.maximum(cell[:-1], cell[1:])
    for k in range(dx.size):
        a_up = (s - F0[k]) / m_in  # largest acceleration within the peak at each speed
        ok = reach & (a_up >= -a_max)
        if not ok.any():
            return False
        lo = np.min(E[ok] - a_max * dx[k] - widen[ok])
        hi = np.max(E[ok] + a_up[ok] * dx[k] + widen[ok])
        reach = (E >= lo) & (E <= hi)
        if not reach.any():
            return False
    return True


def peak_lower_bound(cfg: PlantConfig, x_final: float, v_max: float, a_max: float,
                     v_creep: float, *, positions: int = 300, speeds: int = 150,
                     tol: float = 1e-4) -> float:
    """A lower bound (N) on the peak input force of any stroke from mold contact
    (``cfg.x_contact``) to rest at ``x_final`` within the speed limits [``v_creep``,
    ``v_max``] and the deceleration limit ``a_max`` (module docstring)."""
    xs = np.linspace(cfg.x_contact, x_final, positions + 1)
    v = np.geomspace(v_creep, v_max, speeds)
    X, V = np.meshgrid(xs, v, indexing="ij")
    F = np.asarray(plant_outputs(X, V, 0.0, cfg).input_force, float)
    # dF/da is the same over the grid (to 1e-14 relative on chang2021, with or without
    # other masses or friction): every tenth point gives its mean, the plant evaluated at
    # 1 % of the grid's points, not all of them again (0.4 s of a 1.1 s bound)
    coarse = (slice(None, None, _COARSE), slice(None, None, _COARSE))
    m_in = float(np.mean(np.asarray(plant_outputs(X[coarse], V[coarse], 1.0, cfg).input_force)
                         - F[coarse]))
    F0 = np.minimum(F[:-1], F[1:])  # the least force over each step, each speed
    E, dx = v**2 / 2, np.diff(xs)
    return least_possible(lambda s: _sweep(s, F0, m_in, E, dx, a_max), float(F.max()),
                          float(np.abs(F[0]).max()), tol)


def least_possible(possible: Callable[[float], bool], top: float, start: float, tol: float
                   ) -> float:
    """The bisection of [0, ``top``] for the least peak ``possible`` allows, to ``tol``
    relative: the last value found impossible (0 if every one is possible).

    It starts at the largest force on the grid, which near the toggle is many orders above
    the bound (hundreds of halvings). Whether a peak is possible grows with the peak (a
    larger one allows every stroke a smaller one does), so a bracket found by doubling
    from ``start`` (the force at contact) decides the early steps without a sweep: the
    same steps, the same answer, a twentieth of the sweeps. Where every peak is possible
    (no mold force to build: the dry cycle) the bisection would walk down to the smallest
    float, a thousand sweeps, to answer 0.
    """
    if possible(0.0):
        return 0.0
    below, above = 0.0, max(start, tol)
    while above < top and not possible(above):
        below, above = above, 2 * above
    lo, hi = 0.0, top
    while hi - lo > tol * hi:
        mid = (lo + hi) / 2
        feasible = mid >= above or (mid > below and possible(mid))
        lo, hi = (lo, mid) if feasible else (mid, hi)
    return lo
