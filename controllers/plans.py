"""What a stroke plan is and what it is planned for: the plant with its mold
(:func:`plan_config`), the mold-protection zone (:class:`Protection`), the planned stroke
(:class:`Plan`) and the error of a request no stroke meets (:class:`PlanningError`).

The planner (:mod:`controllers.planner`) makes the plans, the problem it solves is
:mod:`controllers.stroke_problem`, the reports on a plan :mod:`controllers.stroke_reports`;
the molding cycle (:mod:`controllers.cycle`) strings plans together.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from controllers.profiles import Profile, ProfileSamples, predict
from toggle.elastics import ClampingError, clamp_stroke, contact_for_clamp_force
from toggle.params import Mechanism, ParameterError
from toggle.plant import PlantConfig, configure, plant_outputs
from toggle.roots import brentq

CONTACT_SPEED = 5e-3  # m/s, default limit on the platen's speed at mold contact
#: Default mold-protection distance: this fraction of the platen's travel from the open
#: position to mold contact (4.5 mm of chang2021's 45 mm; see :func:`protection_entry`).
PROTECT_FRACTION = 0.1
INTERVALS = 200  # intervals of a planned stroke (N)
#: While clamping the crosshead moves at least this many times the plant's friction-smoothing
#: speed (tanh(v / v_eps)), except while it settles in the last tenth of the clamping phase:
#: below it the smooth friction model fades out, and a plan creeping there would exploit that.
CREEP_FACTOR = 10.0


class PlanningError(ValueError):
    """A request no profile can meet; the message names the binding limit."""


@dataclass(frozen=True)
class Protection:
    """The mold-protection zone as machine controls define it: over the last ``distance``
    m of platen travel before mold contact (default :data:`PROTECT_FRACTION` of the
    platen's travel to contact) the platen moves at most ``speed`` m/s and the input force
    stays within ``force`` N (a part left in the mold stops the clamp); None: no cap."""

    distance: float | None = None
    speed: float | None = None
    force: float | None = None

    def __post_init__(self) -> None:
        for name in ("distance", "speed", "force"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ParameterError(f"protection {name} must be > 0, got {value!r}")


#: No mold protection beyond the default zone's distance: no speed or force cap.
NO_PROTECTION = Protection()


def protection_entry(cfg: PlantConfig, distance: float | None) -> tuple[float, float]:
    """The crosshead position where the mold-protection zone begins, ``distance`` m of
    platen travel before mold contact (default :data:`PROTECT_FRACTION` of the platen's
    travel from the open position to contact), and that distance, m."""
    free = cfg.with_(x_contact=None)
    x_open = clamp_stroke(cfg.mechanism)[0]

    def platen(x: float) -> float:
        return float(plant_outputs(x, 0.0, 0.0, free).platen_position)

    travel = platen(cfg.x_contact) - platen(x_open)
    distance = PROTECT_FRACTION * travel if distance is None else distance
    if not 0 < distance < travel:
        raise ParameterError(f"protection distance {distance!r} m must be > 0 and shorter than "
                             f"the platen's travel to mold contact ({travel:.6g} m)")
    target = platen(cfg.x_contact) - distance
    return brentq(lambda x: platen(x) - target, x_open, cfg.x_contact, xtol=1e-14), distance


@dataclass(frozen=True)
class Plan:
    """A planned stroke: the profile, its prediction through the plant and solver data."""

    profile: Profile
    config: PlantConfig = field(repr=False)
    objective: str
    t_contact: float
    solve_time: float
    iterations: int
    warm: bool
    solution: dict[str, np.ndarray] = field(repr=False)  # scaled primal and dual solution

    @property
    def duration(self) -> float:
        return self.profile.duration

    @functools.cached_property
    def samples(self) -> ProfileSamples:
        """The profile every millisecond through the plant, computed when first asked for."""
        return predict(self.profile, self.config)

    @property
    def peak_force(self) -> float:
        return self.samples.peak_force

    @property
    def rms_force(self) -> float:
        return self.samples.rms_force


def plan_config(
    mechanism: str | Mechanism,
    *,
    mu: float | None = None,
    x_contact: float | None = None,
    clamp_force: float | None = None,
    masses: dict[str, float] | None = None,
    errors: dict[str, float] | None = None,
) -> PlantConfig:
    """The plant to plan for (:func:`toggle.plant.configure`, the one plant configuration
    the FMU also uses), with the mold-contact position set.

    Give the mold-contact crosshead position ``x_contact`` or the clamp force
    ``clamp_force`` (N) to hold at rest in the locked position, not both; without
    either the preset's final tie-bar force is that clamp force
    (:func:`toggle.elastics.contact_for_clamp_force`). ``errors`` adds dimensional errors
    by seed 000's names, as the FMU's ``delta_*`` parameters do; ``masses`` overrides or,
    for a preset without [dynamics], supplies crosshead, links, platen (kg) and
    guide_damping (N s/m).
    """
    cfg = configure(mechanism, masses=masses, errors=errors)
    mech = cfg.mechanism
    mu = cfg.friction if mu is None else mu
    x_open, x_final = clamp_stroke(mech)
    if x_contact is not None and clamp_force is not None:
        raise ParameterError("give either the mold-contact position or the clamp force")
    if x_contact is None:
        force = mech.clamp.final_tiebar_force if clamp_force is None else clamp_force
        x_contact = contact_for_clamp_force(mech, mu, force)
    elif not (x_open < x_contact < x_final):
        raise ClampingError(f"mold-contact position {x_contact!r} m is outside the stroke "
                            f"({x_open:.6g}, {x_final:.6g}) m")
    return cfg.with_(mu=mu, x_contact=x_contact)

