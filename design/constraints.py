"""What a clamp designer checks beyond the objectives: transmission, envelope, strength,
buckling, pin pressure, lock-up, mold-height sensitivity, the die-height range and link
masses of one candidate.

Every position comes from the one model (:func:`toggle.kinematics.half_pose` gives the
angles; the joints are placed along them) and every force from the real-mold clamping of
:mod:`toggle.elastics` (per member, compression positive). The joints of a half, in its
frame (the triangular link's pivot C at the origin, the crosshead pin line at y = d):

* E, the crosshead pin (x, d); D, the arm's pin, E + r3 (cos theta3, sin theta3) (also
  r4a at theta4 + alpha4 from C); B, r4b at theta4 from C; A, the platen joint (L, e).

The limits, their keys in ``[targets]`` and their defaults with their sources are in
:data:`design.targets.DESIGN_LIMITS`; docs/design.md lists them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.optimize import brentq

from toggle.elastics import ClampingResult, analyse_clamping, at_mold_height, clamp_state
from toggle.kinematics import clamp_joints, half_pose
from toggle.params import HalfDims, LinkSection, Mechanism
from toggle.statics import OPENING

#: Factors of the structural limits (their sources in :data:`design.targets.DESIGN_LIMITS`).
YIELD_FACTOR, BUCKLING_FACTOR = 2.0, 3.0


class Paths(NamedTuple):
    """Joint positions of a half over the stroke (each an array of shape (2, n), m)."""

    x: np.ndarray
    E: np.ndarray
    D: np.ndarray
    B: np.ndarray
    A: np.ndarray
    theta3: np.ndarray
    theta4: np.ndarray
    theta5: np.ndarray
    alpha4: float


def joint_paths(dims: HalfDims, x_open: float, x_toggle: float, points: int = 121) -> Paths:
    """Where the joints of a half go from the open position to the toggle."""
    xs = np.linspace(x_open, x_toggle, points)
    pose = half_pose(xs, dims)
    t3, t4, t5 = (np.asarray(a, dtype=float) for a in (pose.theta3, pose.theta4, pose.theta5))
    E = np.stack([xs, np.full_like(xs, dims.d)])
    D = E + dims.r3 * np.stack([np.cos(t3), np.sin(t3)])
    B = dims.r4b * np.stack([np.cos(t4), np.sin(t4)])
    A = np.stack([np.asarray(pose.L, dtype=float), np.full_like(xs, dims.e)])
    return Paths(xs, E, D, B, A, t3, t4, t5, float(pose.alpha4))


def _acute(angle: np.ndarray) -> np.ndarray:
    """The angle between two lines (0 to 90 deg) from the angle between their directions."""
    a = np.mod(angle, math.pi)
    return np.minimum(a, math.pi - a)


def transmission_angles(paths: Paths) -> dict[str, float]:
    """Least transmission angle over the stroke at D (between link 3 and the arm r4a) and at
    A (90 deg less link 5's inclination to the platen's line), rad."""
    at_d = _acute(paths.theta3 - (paths.theta4 + paths.alpha4))
    at_a = 0.5 * math.pi - _acute(paths.theta5)
    return {"transmission_D": float(at_d.min()), "transmission_A": float(at_a.min())}


def platen_side_load(paths: Paths) -> float:
    """Largest transverse over axial force at the platen joint (tan of link 5's inclination)."""
    return float(np.max(np.abs(np.tan(paths.theta5))))


def radial_envelope(paths: Paths) -> float:
    """Radial height the half's pins sweep over the stroke (C at 0 included), m."""
    ys = np.concatenate([paths.E[1], paths.D[1], paths.B[1], paths.A[1], [0.0]])
    return float(ys.max() - ys.min())


def link_clearance(lower: HalfDims, upper: HalfDims, x_open: float, x_toggle: float,
                   points: int = 401) -> float:
    """Least distance of the two halves' moving joints from the clamp axis over the stroke,
    m (each half's own side positive; < 0: a joint crosses into the other half's side and
    meets its mirror image), from :func:`toggle.kinematics.clamp_joints` on ``points``
    crosshead positions. The joints: D (link 3 on the triangle), B (link 5 on the
    triangle) and A (link 5 on the platen). The links between joints are straight, so their
    distance from the axis is least at a joint; the crosshead pin E is left out (it rides
    the crosshead, one body on the axis for both halves)."""
    joints = clamp_joints(np.linspace(x_open, x_toggle, points), lower, upper)
    return min(float(np.min(side * np.asarray(point[1])))
               for half, side in (("lower", -1.0), ("upper", 1.0))
               for point in (joints[half].corner, joints[half].elbow, joints[half].platen))


def linkage_width(mech: Mechanism) -> float:
    """Side-by-side width of a half's links at its widest joint (B or D), m."""
    s, n = mech.sections, mech.clamp.counts
    at_b = n.n1 / 2 * s.platen_link.thickness + n.n2 / 2 * s.triangle.thickness
    at_d = n.n3 / 2 * s.crosshead_link.thickness + n.n2 / 2 * s.triangle.thickness
    return max(at_b, at_d)


def tiebar_clearance(mech: Mechanism, paths: Paths) -> float:
    """Least distance from a tie bar to the links' box, m: the links of both halves fill
    |lateral| <= width / 2 and |radius| <= the farthest pin boss from the axis (the axis at
    y = r1 of the half's frame); the bars stand at the corners of a square of side
    ``tiebars.spacing``."""
    dims, pins, bars = mech.lower, mech.clamp.pins, mech.clamp.tiebars
    bosses = ((paths.E, pins.D), (paths.D, pins.D), (paths.B, pins.B), (paths.A, pins.B),
              (np.zeros((2, 1)), pins.C))
    reach = max(float(np.max(np.abs(dims.r1 - p[1]))) + r for p, r in bosses)
    half = bars.spacing / 2
    gap = math.hypot(max(0.0, half - linkage_width(mech) / 2), max(0.0, half - reach))
    return gap - math.sqrt(bars.area / math.pi)


def link_mass(dims: HalfDims, mech: Mechanism) -> float:
    """Mass of all the links of the clamp from their lengths and sections, kg (the
    triangular link as its three sides)."""
    s, n = mech.sections, mech.clamp.counts

    def kg(section: LinkSection, length: float, count: int) -> float:
        return section.density * section.area * length * count

    return (kg(s.crosshead_link, dims.r3, n.n3) + kg(s.platen_link, dims.r5, n.n1)
            + kg(s.triangle, dims.r4a + dims.r4b + dims.r4c, n.n2))


def buckling_load(section: LinkSection, length: float) -> float:
    """Critical load of a pinned-pinned rectangular column, N: Euler above the transition
    slenderness sqrt(2 pi^2 E / Sy), Johnson's parabola below (Shigley), about the weaker
    axis."""
    weak = min(section.depth, section.thickness)
    slender = length / (weak / math.sqrt(12.0))
    e, sy, area = section.modulus, section.yield_strength, section.area
    if slender >= math.sqrt(2 * math.pi ** 2 * e / sy):
        return math.pi ** 2 * e * area / slender ** 2
    return area * (sy - (sy * slender / (2 * math.pi)) ** 2 / e)


def _states(mech: Mechanism, result: ClampingResult) -> list:
    """(x, state) of the clamp's states that load the links most: at the peak thrust,
    final, held."""
    return [(result.x_at_thrust_max,
             clamp_state(result.x_at_thrust_max, result.x_contact, mech)),
            (result.x_final, result.final), (result.x_final, result.hold)]


def structure(mech: Mechanism, result: ClampingResult) -> dict[str, float]:
    """Link utilisation (axial plus the triangular link's bending, over yield / 2),
    buckling utilisation of links 3 and 5, and the highest pin bearing pressure (Pa), over
    the clamp's loaded states."""
    dims, s, n, pins = mech.lower, mech.sections, mech.clamp.counts, mech.clamp.pins
    per_plate = 2.0 / n.n2  # a half's plates of the triangular link carry its load
    util, buckle, pressure = 0.0, 0.0, 0.0
    for x, state in _states(mech, result):
        pose = half_pose(x, dims)
        f3, f5 = float(state.crosshead_link_force), float(state.link1_force)
        f4 = max(abs(float(state.link2_bf_force)), abs(float(state.link2_cf_force)))
        # link 3's pull on the arm about C: its force times its lever r4a sin(mu_D)
        mu_d = float(_acute(np.asarray(pose.theta3 - pose.theta4 - pose.alpha4)))
        moment = n.n3 / 2 * abs(f3) * dims.r4a * math.sin(mu_d) * per_plate
        tri = s.triangle
        stresses = (abs(f5) / s.platen_link.area / s.platen_link.yield_strength,
                    abs(f3) / s.crosshead_link.area / s.crosshead_link.yield_strength,
                    (f4 / tri.area + moment / (tri.thickness * tri.depth ** 2 / 6))
                    / tri.yield_strength)
        util = max(util, YIELD_FACTOR * max(stresses))
        buckle = max(buckle, BUCKLING_FACTOR * max(
            max(f5, 0.0) / buckling_load(s.platen_link, dims.r5),
            max(f3, 0.0) / buckling_load(s.crosshead_link, dims.r3)))
        # the force on the triangle at B (from link 5) and at D (from link 3); C carries both
        b_pt = dims.r4b * np.array([math.cos(pose.theta4), math.sin(pose.theta4)])
        a_pt = np.array([float(pose.L), dims.e])
        d_pt = dims.r4a * np.array([math.cos(pose.theta4 + pose.alpha4),
                                    math.sin(pose.theta4 + pose.alpha4)])
        e_pt = np.array([x, dims.d])
        at_b = n.n1 / 2 * f5 * (b_pt - a_pt) / dims.r5
        at_d = n.n3 / 2 * f3 * (d_pt - e_pt) / dims.r3
        at_c = float(np.hypot(*(at_b + at_d)))
        pressure = max(pressure,
                       abs(f5) / (2 * pins.B * s.platen_link.thickness),   # A and B, link 5
                       abs(f3) / (2 * pins.D * s.crosshead_link.thickness),  # E and D, link 3
                       n.n1 / n.n2 * abs(f5) / (2 * pins.B * tri.thickness),  # B, triangle
                       n.n3 / n.n2 * abs(f3) / (2 * pins.D * tri.thickness),  # D, triangle
                       at_c * per_plate / (2 * pins.C * tri.thickness))       # C, triangle
    return {"link_utilisation": util, "buckling_utilisation": buckle, "pin_pressure": pressure}


def die_height(mech: Mechanism, thrust_limit: float | None, sensitivity_limit: float
               ) -> dict[str, float]:
    """The clamp at both ends of the tailstock's die-height range, the tailstock set for the
    clamp's final tie-bar force (:func:`toggle.elastics.at_mold_height`): the larger peak
    crosshead thrust (N), the larger sensitivity of the clamp force to mold height (dF/F
    per metre, 1 over the elastic interference: the thinnest mold's, the stiffest clamp),
    and their utilisation, the worse of thrust over ``thrust_limit`` (None: no motor) and
    sensitivity over ``sensitivity_limit``. ClampingError if an end cannot be clamped."""
    die = mech.clamp.die_height
    ends = [analyse_clamping(at_mold_height(mech, h)) for h in (die.min, die.max)]
    thrust = max(r.thrust_max for r in ends)
    sensitivity = max(1.0 / float(r.final.toggle_stretch) for r in ends)
    util = sensitivity / sensitivity_limit
    if thrust_limit is not None:
        util = max(util, thrust / thrust_limit)
    return {"die_height_thrust": thrust, "die_height_sensitivity": sensitivity,
            "die_height_range": util}


def lockup(mech: Mechanism, result: ClampingResult) -> dict[str, float]:
    """Lock-up: the angle of links 4b and 5 at the toggle (asin(e / (r4b + r5))), the
    break-away force (the crosshead pull that opens the clamped mold against static
    friction, N; > 0 a pull), the crosshead travel before the final position over which the
    clamp holds without motor torque (m), and the clamp force's sensitivity to mold height
    (dF/F per metre: 1 over the elastic interference)."""
    dims, clamp = mech.lower, mech.clamp
    mu_s = clamp.static_factor * clamp.mu

    def opening(x: float) -> float:  # crosshead force to start opening at x (> 0 a push)
        return float(clamp_state(x, result.x_contact, mech, mu_s, OPENING).thrust)

    xs = np.linspace(result.x_contact, result.x_final, 41)[1:]
    pushes = np.asarray(clamp_state(xs, result.x_contact, mech, mu_s, OPENING).thrust) >= 0
    travel = 0.0
    if not pushes[-1]:  # held at the final position: from where on?
        if pushes.any():
            i = int(np.flatnonzero(pushes)[-1])
            travel = result.x_final - brentq(opening, xs[i], xs[i + 1], xtol=1e-9)
        else:
            travel = result.x_final - result.x_contact
    return {"lockup_angle": math.asin(dims.e / (dims.r4b + dims.r5)),
            "breakaway_force": -opening(result.x_final), "self_locking_travel": travel,
            "clamp_force_sensitivity": 1.0 / float(result.final.toggle_stretch)}
