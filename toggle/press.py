"""Toggle (elbow-bar) mechanical press of Dong & Sun 2022: one toggle chain.

The press is a second mechanism of the toolkit, written like the clamp: one
set of closed-form loop equations in numpy ufuncs, so the same function runs
on floats, on numpy arrays (vectorised Monte Carlo) and on CasADi SX symbols
(exact derivatives by AD).

Topology (reconstructed, see docs/press-reconstruction.md). Frame: origin O at
the upper fulcrum, x towards the crank side, z downwards. Labels are those of
the paper's loop equations (Eqs 9-10) and Table 3:

* crank l1 (the eccentric) turns about C = (Cx, Cz) and carries corner Q of
  the rigid triangle PQD;
* upper rod l3 joins O to corner P; the triangle has sides PQ = l2,
  PD = l4 (short side) and QD = l5;
* bottom rod l6 joins corner D to the slider pin E, which moves on the
  vertical line x = -e (the paper's e is measured away from the crank:
  e = -23 mm puts the slider line 23 mm towards it).

Loop I: l3 + l4 = C + l1 + l5 (both reach D); loop II: l3 + l4 + l6 = E.
The slider position s is the depth of E below O; the paper's "theoretical
BDC position" is the slider displacement from top dead centre (TDC) to bottom
dead centre (BDC), i.e. s(BDC) - s(TDC).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from toggle.kinematics import AssemblyError
from toggle.params import ParameterError, UnknownPresetError, preset_table
from toggle.synthesis import ErrorModel, SynthesisSettings, refine_extremum, settings_from_table

ca.GlobalOptions.setNumpyMode(True)

#: Field order of :class:`PressDims` (the paper's loop labels).
PRESS_DIMENSIONS = ("l1", "l2", "l3", "l4", "l5", "l6", "Cx", "Cz", "e")
#: Cost class of each error source (Table 1: links, Table 2: positions).
PRESS_KINDS = ("link",) * 6 + ("position",) * 3
#: Crank angles scanned to bracket the dead centres before refinement.
_SCAN_POINTS = 3601
#: Step (rad) of the finite-difference Newton refinement of the dead centres.
_REFINE_STEP = 1e-4


@dataclass(frozen=True)
class PressDims:
    """Dimensions of one toggle chain, metres (labels of the paper's loop equations)."""

    l1: float  # crank (eccentric) radius, C to Q
    l2: float  # triangle side PQ
    l3: float  # upper rod, O to P
    l4: float  # triangle side PD
    l5: float  # triangle side QD
    l6: float  # bottom rod, D to slider pin E
    Cx: float  # crank centre, horizontal (towards the crank side)
    Cz: float  # crank centre, depth below O
    e: float  # slider line at x = -e

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
                value
            ):
                raise ParameterError(f"{f.name} must be a finite number, got {value!r}")
        for name in PRESS_DIMENSIONS[:6]:
            if getattr(self, name) <= 0:
                value = getattr(self, name)
                raise ParameterError(f"link length {name} must be positive, got {value}")
        a, b, c = self.l2, self.l4, self.l5
        if not (abs(a - b) < c < a + b):
            raise ParameterError(
                f"triangle PQD cannot close: l2={a}, l4={b}, l5={c} m "
                "violate the triangle inequality"
            )

    def as_tuple(self) -> tuple[float, ...]:
        return tuple(getattr(self, n) for n in PRESS_DIMENSIONS)


@dataclass(frozen=True)
class Press:
    """A two-chain toggle press: chain dimensions, chain spacing and synthesis settings.

    chain_spacing: ye1 + ye2, the distance between the slider pins of the left
    and right chains, the lever arm of the slider tilt (m).
    """

    name: str
    dims: PressDims
    chain_spacing: float
    settings: SynthesisSettings
    description: str = ""


class PressPose(NamedTuple):
    """Joint positions (x, z) of one chain at a crank angle, m."""

    Q: tuple[Any, Any]
    P: tuple[Any, Any]
    D: tuple[Any, Any]
    E: tuple[Any, Any]


def _checked(arg: Any, what: str, theta: Any, check: bool) -> Any:
    """Square-root argument of a loop closure; negative means the loop cannot close."""
    if not check or isinstance(arg, (ca.SX, ca.MX, ca.casadi.ArrayInterface)):
        return arg
    arg = np.asarray(arg, dtype=float)
    bad = ~(arg >= -1e-12)
    if np.any(bad):
        i = int(np.flatnonzero(bad.ravel())[0])
        th = float(np.broadcast_to(np.asarray(theta, dtype=float), arg.shape).ravel()[i])
        raise AssemblyError(f"press chain cannot assemble at crank angle {th:.6g} rad: {what}")
    return np.maximum(arg, 0.0)


def _circle_intersection(x0: Any, z0: Any, r0: Any, x1: Any, z1: Any, r1: Any, side: float,
                         what: str, theta: Any, check: bool) -> tuple[Any, Any]:
    """Point at r0 from (x0, z0) and r1 from (x1, z1); side picks the assembly mode."""
    dx, dz = x1 - x0, z1 - z0
    dist = np.sqrt(dx * dx + dz * dz)
    along = (r0 * r0 - r1 * r1 + dist * dist) / (2 * dist)
    across = np.sqrt(_checked(r0 * r0 - along * along, what, theta, check))
    ux, uz = dx / dist, dz / dist
    return x0 + along * ux - side * across * uz, z0 + along * uz + side * across * ux


def press_pose(theta: Any, dims: PressDims | Any, *, check: bool = True) -> PressPose:
    """Joint positions of one chain at crank angle theta (rad, from +x towards +z).

    ``dims`` is a :class:`PressDims` or nine values in its field order (floats,
    arrays broadcasting with theta, or CasADi SX). The assembly modes are the
    ones of the running press (both intersections on the side +1 of
    :func:`_circle_intersection`): the upper rod hangs below O and the knee
    O-P-D-E nearly straightens at BDC; E lies below D.
    """
    l1, l2, l3, l4, l5, l6, Cx, Cz, e = dims.as_tuple() if isinstance(dims, PressDims) else dims
    qx, qz = Cx + l1 * np.cos(theta), Cz + l1 * np.sin(theta)
    px, pz = _circle_intersection(0.0, 0.0, l3, qx, qz, l2, 1.0,
                                  "upper rod l3 and triangle side l2 do not meet (loop I)",
                                  theta, check)
    dx, dz = _circle_intersection(px, pz, l4, qx, qz, l5, 1.0,
                                  "triangle sides l4 and l5 do not meet", theta, check)
    ex = -e + 0.0 * theta
    ez = dz + np.sqrt(_checked(l6 * l6 - (dx - ex) ** 2, "bottom rod l6 cannot reach the "
                               "slider line (loop II)", theta, check))
    return PressPose(Q=(qx, qz), P=(px, pz), D=(dx, dz), E=(ex, ez))


def slider_position(theta: Any, dims: PressDims | Any, *, check: bool = True) -> Any:
    """Depth s of the slider pin E below the upper fulcrum O, m."""
    return press_pose(theta, dims, check=check).E[1]


@functools.cache
def _motion_function() -> ca.Function:
    """CasADi function (theta, p) -> (s, ds/dtheta, d2s/dtheta2, ds/dp)."""
    theta = ca.SX.sym("theta")
    p = ca.SX.sym("p", len(PRESS_DIMENSIONS))
    s = ca.SX(slider_position(theta, [p[i] for i in range(len(PRESS_DIMENSIONS))]))
    ds = ca.jacobian(s, theta)
    return ca.Function("press_motion", [theta, p], [s, ds, ca.jacobian(ds, theta),
                                                    ca.jacobian(s, p)],
                       ["theta", "p"], ["s", "ds", "d2s", "ds_dp"])


def _newton_dead_centre(theta: float, dims: PressDims) -> float:
    """Refine a stationary point of s(theta) by Newton's method with exact AD derivatives."""
    f, p = _motion_function(), np.array(dims.as_tuple())
    for _ in range(50):
        out = f(theta, p)
        step = float(out[1]) / float(out[2])
        theta -= step
        if abs(step) < 1e-14:
            return theta
    raise AssemblyError("press dead centre did not converge (no smooth extremum of s)")


def dead_centres(dims: PressDims) -> tuple[float, float]:
    """Crank angles (theta_TDC, theta_BDC) of the minimum and maximum slider depth, rad.

    The crank turns fully; the extremes of s are bracketed on a scan and
    refined by Newton's method on ds/dtheta = 0.
    """
    thetas = np.linspace(0.0, 2 * math.pi, _SCAN_POINTS)
    s = slider_position(thetas, dims)
    tdc = _newton_dead_centre(float(thetas[np.argmin(s)]), dims)
    bdc = _newton_dead_centre(float(thetas[np.argmax(s)]), dims)
    return tdc % (2 * math.pi), bdc % (2 * math.pi)


def bdc_displacement(dims: PressDims) -> float:
    """Slider displacement at BDC measured from TDC (the paper's BDC position), m."""
    tdc, bdc = dead_centres(dims)
    return float(slider_position(bdc, dims) - slider_position(tdc, dims))


def bdc_sensitivities(dims: PressDims) -> dict[str, float]:
    """Exact d(BDC displacement)/dp for every dimension (AD).

    At a dead centre ds/dtheta = 0, so the shift of the dead-centre angle does
    not enter to first order (envelope theorem): the derivative is
    ds/dp at the BDC angle minus ds/dp at the TDC angle.
    """
    f, p = _motion_function(), np.array(dims.as_tuple())
    tdc, bdc = dead_centres(dims)
    grad = np.asarray(f(bdc, p)[3]).ravel() - np.asarray(f(tdc, p)[3]).ravel()
    return dict(zip(PRESS_DIMENSIONS, (float(g) for g in grad)))


def bdc_displacement_batch(params: np.ndarray, dims: PressDims) -> np.ndarray:
    """Exact BDC displacement of many perturbed chains (params: 9 x N, m), vectorised.

    Each dead centre starts at the nominal chain's angle and is refined by
    finite-difference Newton steps on the numpy path (the shift is tiny, so two
    steps reach machine precision).
    """
    rows = [params[i] for i in range(len(PRESS_DIMENSIONS))]
    tdc, bdc = dead_centres(dims)

    def s(theta: np.ndarray) -> np.ndarray:
        return slider_position(theta, rows)

    n = params.shape[1]
    return (refine_extremum(s, np.full(n, bdc), _REFINE_STEP)
            - refine_extremum(s, np.full(n, tdc), _REFINE_STEP))


def error_model(press: Press) -> ErrorModel:
    """The press as an error function for :mod:`toggle.synthesis`.

    Per chain the error sources are the nine dimensions plus ye, the chain's
    share of the slider-pin spacing (it enters only the tilt's lever arm).
    Both chains have the nominal dimensions of the preset.
    """
    dims = press.dims
    nominal = np.array(dims.as_tuple() + (press.chain_spacing / 2,))
    sens = bdc_sensitivities(dims)
    gradient = np.array([sens[k] for k in PRESS_DIMENSIONS] + [0.0])

    def output(chain: str, params: np.ndarray) -> np.ndarray:
        return bdc_displacement_batch(params[:-1], dims)

    def spacing(left: np.ndarray, right: np.ndarray) -> np.ndarray:
        return left[-1] + right[-1]

    return ErrorModel(
        name=press.name,
        sources=PRESS_DIMENSIONS + ("ye",),
        kinds=PRESS_KINDS + ("position",),
        nominal={"left": nominal, "right": nominal},
        gradient={"left": gradient, "right": gradient},
        output=output,
        spacing=spacing,
        reference_output=bdc_displacement(dims),
        output_label="BDC displacement from TDC",
        settings=press.settings,
    )


def press_from_dict(table: dict[str, Any], origin: str = "<dict>") -> Press:
    """Build a :class:`Press` from a parsed TOML table (SI units)."""
    body = table.get("press")
    if not isinstance(body, dict):
        raise ParameterError(f"{origin}: no [press] table")
    values = dict(body)
    spacing = values.pop("chain_spacing", None)
    unknown, missing = set(values) - set(PRESS_DIMENSIONS), set(PRESS_DIMENSIONS) - set(values)
    if unknown or missing:
        raise ParameterError(
            f"{origin}: [press]: unknown {sorted(unknown)}, missing {sorted(missing)}"
        )
    if not isinstance(spacing, (int, float)) or not spacing > 0:
        raise ParameterError(f"{origin}: [press] chain_spacing must be a positive number (m)")
    return Press(
        name=str(table.get("name", origin)),
        dims=PressDims(**{k: float(v) for k, v in values.items()}),
        chain_spacing=float(spacing),
        settings=settings_from_table(table.get("synthesis", {}), origin),
        description=str(table.get("description", "")),
    )


def _read_table(name: str) -> tuple[dict[str, Any], str] | None:
    """Parsed TOML of a preset name or file, with its origin; None if no such preset."""
    try:
        return preset_table(name)
    except UnknownPresetError:
        return None


def is_press_preset(name: str) -> bool:
    """Whether a preset name or TOML file describes a press (has a [press] table)."""
    found = _read_table(name)
    return found is not None and "press" in found[0]


def load_press(name: str) -> Press:
    """Load a shipped press preset by name, or a TOML file if ``name`` is a path."""
    found = _read_table(name)
    if found is None:
        raise ParameterError(f"unknown press preset {name!r}")
    return press_from_dict(*found)
