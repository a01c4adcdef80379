"""The prototype's statistics (seed 000, Tables 3-8) from the plant, as the rig measured them.

Chang, Lee & Hsu 2021 drove the clamp from the open position x_open to the toggle and
back at a constant speed v, 100 times, and reported per condition (v, delta_r8):

* F_F(max), F_F(rms): maximum and RMS of the load-cell force over the forward stroke;
* F_B(min), F_B(rms): minimum and RMS over the backward stroke;
* F_TP: the force as the encoder passes the toggle, in motion: the first forward reading
  within the encoder's resolution (:data:`TOGGLE_BAND`) of the platen's end position;
* the stroke S read by the platen's encoder (Tables 3-5).

Here the strokes are quasi-static at the constant speed v (the rig's ramps are 0.5 % of
the stroke), the force comes from :func:`toggle.plant.plant_outputs` in the hysteretic
slip state carried along the strokes (:func:`toggle.asymmetry.slip_state_along`), so
these numbers and the simulated rig come from the same equations. The stroke measurement
adds what the plant's platen does not know (:class:`RigReading`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from toggle.asymmetry import AsymmetryParams, slip_state_along
from toggle.kinematics import stroke_limits
from toggle.params import Mechanism
from toggle.plant import PlantConfig, configure, plant_outputs
from toggle.roots import brentq

#: The encoder's resolution, m: F_TP is read where the platen first comes this close to
#: its end position (the rig's 1 um optical encoder, hil.emulators.rig_hardware).
TOGGLE_BAND = 1e-6
#: How long before the encoder reached the toggle the prototype's rig sampled F_TP, s
#: (fittable, ``toggle tables --fit toggle_latency``): 0, since with the prototype's
#: as-built error a latency no longer improves the fit of Tables 6-7 (0.07 +- 0.21 s),
#: docs/unequal-halves.md section 9.4. The HIL run summaries read F_TP the same way.
F_TP_LATENCY = 0.0
#: Points per stroke of the quasi-static evaluation (RMS converged to 0.1 %).
POINTS = 801
FORCE_STATISTICS = ("force_forward_max", "force_forward_rms", "force_backward_min",
                    "force_backward_rms", "force_toggle")


class RigError(ValueError):
    """A condition the rig statistics cannot be computed for."""


@dataclass(frozen=True)
class RigReading:
    """How the rig reads F_TP and the stroke, beyond the plant (SI).

    toggle_latency: F_TP is the force sampled this long (s) before the encoder reading
    reached the toggle (within its 1 um resolution of the platen's end position): the
    rig's force sample and position report are not simultaneous (a USB DAQ and a motion
    card polled by one LabVIEW loop), so at speed v the force is read v * latency early.

    datum: offset of the reading between the open and the toggle end (m): the platen not
    yet seated against the links at the open position, a play taken up as the motion turns
    (the measured stroke error at delta_r8 = 0, 0.40-0.45 mm, is far above any
    compliance of a 20 N stroke; :meth:`read`). lever: the encoder's place across the
    platen, as a fraction of the distance between the halves' joints measured from the
    platen's centre (positive towards the upper half): a tilted platen reads
    lever * (L_U - L_L) more there.
    compliance: the load-cell force F stretches the frame that carries the scale, which
    reads compliance * F more; the stroke gains compliance * (F_TP - F at the start).
    """

    datum: float = 0.0
    lever: float = 0.0
    compliance: float = 0.0  # m/N: the frame carrying the scale, read as platen travel
    toggle_latency: float = F_TP_LATENCY

    def __post_init__(self) -> None:
        for name in ("datum", "lever", "compliance", "toggle_latency"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise RigError(f"rig reading {name} must be finite, got {value!r}")
        if not 0.0 <= self.toggle_latency <= 1.0:
            raise RigError(f"toggle_latency must lie in [0, 1] s, got {self.toggle_latency!r}")

    def read(self, platen: float, mismatch: float, force: float, play: float) -> float:
        """The encoder's reading (m) of the platen at ``platen`` (m), the halves' mismatch
        L_U - L_L (m) and the load-cell force (N), in the play's state p in [-1, 1]: the
        play of ``datum`` is open after a backward move (p = -1) and taken up after a
        forward one (p = 1), so a cycle reads datum more than the platen travels. p turns
        with the crosshead's motion like the friction's slip state (Dahl's law over the
        slip distance, :func:`toggle.asymmetry.advance_slip_state`)."""
        return (platen + self.lever * mismatch + self.compliance * force
                - self.datum * (1.0 - play) / 2.0)


#: The prototype's reading, fitted with the force model on Tables 3-4 and 6-7
#: (``toggle tables --fit ...``, docs/unequal-halves.md section 9; the shipped fit:
#: docs/unequal-halves-results.md section 9.5).
CHANG2021_READING = RigReading(datum=0.4032e-3, lever=0.648, compliance=0.869e-6)


#: The prototype's own dimensional errors (seed 000's names, m) besides the set link-8
#: error: the height of the upper half's link-7 pivot (r1U), whose mismatch vanishes at
#: both ends of the stroke, fitted on Tables 6-7 with the platen's friction below
#: (``toggle tables --fit as_built_r1U ...``: 0.96 +- 0.78 mm; docs/unequal-halves.md
#: section 9.4). Data of the rig, not of the model: a preset's mechanism stays as its file
#: writes it (equal halves add nothing), and only the simulated rig (:func:`rig_errors`)
#: adds these.
CHANG2021_AS_BUILT: dict[str, float] = {"r1U": 0.961e-3}
#: As-built errors of the rigs whose tables the project has, by preset name.
AS_BUILT = {"chang2021": CHANG2021_AS_BUILT}
#: The prototype's [dynamics] beyond its preset: the friction of its moving platen's four
#: oil-free bronze bushings on the tie-bars (seed 000, section 4), fitted on Tables 6-7
#: (``toggle tables --fit platen_friction platen_rate ...``): 4.26 N near rest, rising with
#: the log of the platen's speed (platen_rate 1.81: 23 N at 10 mm/s, 35 N at 50 mm/s).
#: Referred to the input by dL/dx it drags the stroke's start (x 2.1) and fades to nothing
#: at the toggle, so it gives the delta_r8 = 0 rows their force without an F_TP
#: (docs/unequal-halves-results.md section 9.5). Data of the rig like the as-built errors: the
#: preset, the planner's and the FMU's defaults stay without it; the simulated rig
#: (:func:`rig_dynamics`) adds it.
CHANG2021_DYNAMICS: dict[str, float] = {"platen_friction": 4.26, "platen_rate": 1.81}
#: [dynamics] fields of the rigs whose tables the project has, by preset name.
RIG_DYNAMICS = {"chang2021": CHANG2021_DYNAMICS}


def rig_dynamics(preset: str, dynamics: dict[str, float] | None = None) -> dict[str, float]:
    """[dynamics] fields (:class:`toggle.params.Dynamics`, SI) the rig of ``preset`` has
    beyond its preset (``dynamics``, default the shipped ones of that rig, none for a preset
    without a rig). What the simulated rig applies with :func:`rig_errors`."""
    return dict(RIG_DYNAMICS.get(preset, {}) if dynamics is None else dynamics)


def rig_errors(preset: str, delta_r8: float, as_built: dict[str, float] | None = None
               ) -> dict[str, float]:
    """Dimensional errors (seed 000's names, m) of the rig of ``preset`` with link 8 set
    ``delta_r8`` off: its as-built errors (``as_built``, default the shipped ones of that
    rig, none for a preset without a rig) plus delta_r8. What the simulated rig applies:
    :func:`rig_config`, ``hil run``'s FMU, ``hil emulate``."""
    errors = dict(AS_BUILT.get(preset, {}) if as_built is None else as_built)
    errors["r8"] = errors.get("r8", 0.0) + delta_r8
    return errors


class RigStatistics(NamedTuple):
    """One condition's statistics, SI (m, N)."""

    force_forward_max: float
    force_forward_rms: float
    force_backward_min: float
    force_backward_rms: float
    force_toggle: float
    stroke: float

    def as_dict(self) -> dict[str, float]:
        return self._asdict()


def rig_config(nominal: Mechanism, delta_r8: float, params: AsymmetryParams,
               dynamics: dict[str, float] | None = None,
               as_built: dict[str, float] | None = None) -> PlantConfig:
    """The plant of the rig of ``nominal`` with link 8 off by delta_r8 (m), no mold:
    :func:`rig_errors` and :func:`rig_dynamics` (default the shipped ones) applied."""
    return configure(nominal, errors=rig_errors(nominal.name, delta_r8, as_built),
                     masses=rig_dynamics(nominal.name, dynamics)).with_(asymmetry=params)


def _platen(x: float, cfg: PlantConfig) -> float:
    """The plant's platen position at x (no mold), m."""
    return float(plant_outputs(x, 0.0, 0.0, cfg).platen_position)


def rig_statistics(cfg: PlantConfig, speed: float, reading: RigReading = RigReading(),
                   x_ends: tuple[float, float] | None = None) -> RigStatistics:
    """Tables 3-8 statistics of the steady reciprocation at ``speed`` (m/s) of this plant.

    ``x_ends``: the commanded open and toggle positions (default: the lower half's, which
    the paper keeps for every delta_r8).
    """
    if not (math.isfinite(speed) and speed > 0):
        raise RigError(f"speed must be a positive number of m/s, got {speed!r}")
    x_open, x_tp = stroke_limits(cfg.mechanism.lower) if x_ends is None else x_ends
    xs = np.linspace(x_open, x_tp, POINTS)
    slip = cfg.asymmetry.slip_distance
    z_back_end = -1.0
    for _ in range(2):  # the periodic state: each stroke starts where the last one ended
        z_fwd = slip_state_along(xs, z_back_end, slip)
        z_back = slip_state_along(xs[::-1], z_fwd[-1], slip)[::-1]
        z_back_end = float(z_back[0])
    fwd = np.asarray(plant_outputs(xs, speed, 0.0, cfg, slip_state=z_fwd).input_force)
    back = np.asarray(plant_outputs(xs, -speed, 0.0, cfg, slip_state=z_back).input_force)
    end = float(_platen(x_tp, cfg))
    x_band = brentq(lambda x: float(_platen(x, cfg)) - (end - TOGGLE_BAND), x_open, x_tp,
                    xtol=1e-12)
    x_read = max(x_band - speed * reading.toggle_latency, x_open)
    z_read = float(slip_state_along(np.array([x_open, x_read]), z_back_end, slip)[-1])
    f_tp = float(plant_outputs(x_read, speed, 0.0, cfg, slip_state=z_read).input_force)
    mismatch = [float(plant_outputs(x, 0.0, 0.0, cfg).asymmetry) for x in (x_open, x_tp)]
    stroke = (reading.read(end, mismatch[1], f_tp, float(z_fwd[-1]))
              - reading.read(float(_platen(x_open, cfg)), mismatch[0], float(fwd[0]),
                             z_back_end))
    return RigStatistics(float(fwd.max()), float(np.sqrt(np.mean(fwd * fwd))),
                         float(back.min()), float(np.sqrt(np.mean(back * back))), f_tp, stroke)
