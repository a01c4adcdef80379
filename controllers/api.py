"""The public API of the planner: plan a clamp stroke (or the molding cycle) and export it.

`plan_stroke` wraps `controllers.planner.planner_for` and
`controllers.planner.ClampPlanner` (the CasADi optimal-control problem), and
`Plan` writes what ``toggle plan --out`` and ``toggle plan --export cam`` write.
Import both from `controllers`; the modules behind them are private by convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from controllers import plans as _plans
from controllers.cycle import MoldingCycle
from controllers.limits import DriveLimits, drive_limits
from controllers.planner import ClampPlanner, default_duration, planner_for
from controllers.plans import NO_PROTECTION, Protection
from controllers.profiles import ProfileSamples, predict, write_profile_csv
from controllers.stroke_reports import baseline_stroke
from toggle.files import atomic_path, check_writable
from toggle.params import Mechanism, ParameterError
from toggle.plant import PlantConfig, with_errors

#: The objectives `plan_stroke` takes.
OBJECTIVES = ("peak", "min_time", "energy")
#: The formats `Plan.export` writes: the profile CSV ``hil run --profile`` replays,
#: and the cam tables of ``toggle plan --export cam``.
EXPORT_FORMATS = ("profile", "csv", "plcopen", "twincat", "pvt")


@dataclass(frozen=True)
class Plan:
    """A planned closing stroke (and, for a cycle, the opening stroke and the dwells).

    Attributes:
        stroke: The closing stroke as the planner returned it (its profile, plant and
            solver data).
        limits: The drive limits it was planned within.
        lower_bound: No stroke of this plant can peak below this input force, N.
        cycle: The molding cycle (closing, hold, opening, ejection), or None.
        preset: The mechanism's name or preset path, written into exported files.
    """

    stroke: _plans.Plan
    limits: DriveLimits
    lower_bound: float
    cycle: MoldingCycle | None = None
    preset: str = ""

    @property
    def objective(self) -> str:
        """What the stroke minimises: ``"peak"``, ``"time"`` or ``"energy"``."""
        return self.stroke.objective

    @property
    def duration(self) -> float:
        """The closing stroke's duration, s."""
        return self.stroke.duration

    @property
    def t_contact(self) -> float:
        """Time of mold contact, s."""
        return self.stroke.t_contact

    @property
    def peak_force(self) -> float:
        """Peak input (crosshead) force over the stroke through the plant, N."""
        return self.stroke.peak_force

    @property
    def rms_force(self) -> float:
        """RMS input force over the stroke, N."""
        return self.stroke.rms_force

    @property
    def samples(self) -> ProfileSamples:
        """The stroke (or the whole cycle) every millisecond through the plant, SI."""
        return self.cycle.samples() if self.cycle else self.stroke.samples

    @property
    def cycle_time(self) -> float | None:
        """The molding cycle's time, s; None for a stroke alone."""
        return self.cycle.cycle_time if self.cycle else None

    def export(self, path: str | Path, format: str = "profile", *, overwrite: bool = False,
               points: int | None = None, interpolation: str | None = None,
               master: str = "time", units: str | None = None,
               drive_cycle: float | None = None) -> Path:
        """Write the plan to ``path``.

        Args:
            path: The file to write (atomically: a failed export leaves none).
            format: ``"profile"``: the 1 ms profile CSV that ``hil run --profile`` replays
                (the whole cycle for a cycle plan); ``"csv"``, ``"plcopen"``,
                ``"twincat"`` or ``"pvt"``: a cam table for a drive, checked as the drive
                interpolates it (``toggle plan --export cam``).
            overwrite: Replace an existing file.
            points: Cam table points; default the fewest that keep the plan.
            interpolation: ``"linear"`` or ``"cubic"`` (csv cam tables only).
            master: Cam master axis, ``"time"`` or ``"position"``.
            units: ``"si"``, ``"motor"`` or ``"counts"``.
            drive_cycle: The drive's interpolation cycle, s (default 125 us).

        Returns:
            The path written.

        Raises:
            ParameterError: An unknown format, or a cam table that cannot keep the plan.
            OutputError: A path that must not be written (a folder, an existing file
                without ``overwrite``).
        """
        from controllers import cam, cam_formats

        if format not in EXPORT_FORMATS:
            raise ParameterError(f"format must be one of {', '.join(EXPORT_FORMATS)}, "
                                 f"got {format!r}")
        path = Path(path)
        check_writable(path, "path", force=overwrite)
        cfg = self.stroke.config
        settings: dict[str, object] = {"preset": self.preset or cfg.mechanism.name,
                                       "x_contact": cfg.x_contact, "mu": cfg.friction,
                                       "objective": self.objective}
        if format == "profile":
            settings.update(duration=self.samples.time[-1] if self.cycle else self.duration,
                            cycle_time=self.cycle_time)
            with atomic_path(path) as tmp:
                write_profile_csv(tmp, self.samples, settings)
            return path
        cam_formats.export(path, self.stroke.profile, cfg, self.limits, self.peak_force,
                           format, {**settings, "peak_force": self.peak_force},
                           points=points, master=master, units=units,
                           interpolation=interpolation, cycle=drive_cycle or cam.DRIVE_CYCLE)
        return path


def plan_stroke(mechanism: str | Mechanism = "chang2021", objective: str = "peak", *,
                duration: float | None = None, force_limit: float | None = None,
                errors: dict[str, float] | None = None, robust: bool = False,
                cycle: bool = False, hold: float = 0.0, eject: float = 0.0,
                mu: float | None = None, x_contact: float | None = None,
                clamp_force: float | None = None, velocity: float | None = None,
                acceleration: float | None = None, jerk: float | None = None,
                torque: float | None = None,
                contact_speed: float = _plans.CONTACT_SPEED,
                intervals: int = _plans.INTERVALS) -> Plan:
    """Plan the crosshead's closing stroke through the plant model (CasADi + IPOPT).

    Args:
        mechanism: A preset's name or TOML path, or a `toggle.params.Mechanism`
            with ``[clamp]``, ``[drive]`` and ``[dynamics]`` data.
        objective: ``"peak"``: least peak input force in ``duration``; ``"min_time"``:
            the fastest stroke whose force stays within ``force_limit``; ``"energy"``:
            least electrical energy in ``duration``.
        duration: Stroke time, s; default twice the kinematic minimum.
        force_limit: Input-force limit of a ``"min_time"`` plan, N; default the drive's.
        errors: Dimensional errors by the FMU's names, m (e.g. ``{"r8": 0.25e-3}``).
        robust: Plan one stroke good for both the nominal clamp and the one with
            ``errors`` (each weighed against its own S-curve) instead of for the latter.
        cycle: Also plan the fastest opening stroke: the molding cycle.
        hold: With ``cycle``: the hold dwell, mold locked, s.
        eject: With ``cycle``: the ejection dwell at the open position, s.
        mu: Pin friction coefficient; default the preset's.
        x_contact: Mold-contact crosshead position, m (or ``clamp_force``, N).
        clamp_force: Clamp force held in the locked position, N; default the preset's.
        velocity: Crosshead speed limit, m/s; default the drive's.
        acceleration: Crosshead acceleration limit, m/s^2; default the drive's.
        jerk: Crosshead jerk limit, m/s^3; default the drive's.
        torque: Motor standstill torque, N m (scales the torque-speed curve).
        contact_speed: Platen speed limit at mold contact, m/s.
        intervals: Time intervals of the optimal-control problem.

    Returns:
        The plan: its stroke, limits, lower bound and (with ``cycle``) the molding cycle.

    Raises:
        ParameterError: Bad arguments (e.g. ``robust`` without ``errors``).
        PlanningError: No stroke meets the limits (the message says which binds).
    """
    if objective not in OBJECTIVES:
        raise ParameterError(f"objective must be one of {', '.join(OBJECTIVES)}, "
                             f"got {objective!r}")
    if robust and (not errors or objective == "min_time"):
        raise ParameterError("robust plans a fixed duration against dimensional errors: "
                             "give errors and an objective other than 'min_time'")
    if (hold or eject) and not cycle:
        raise ParameterError("hold and eject belong to the molding cycle: give cycle=True")
    cfg = _plans.plan_config(mechanism, mu=mu, x_contact=x_contact, clamp_force=clamp_force,
                             errors=None if robust else errors)
    limits = drive_limits(cfg.mechanism, velocity=velocity, acceleration=acceleration,
                          jerk=jerk, torque=torque)
    planner = planner_for(cfg, limits, contact_speed, intervals)
    if objective == "min_time":
        stroke = planner.minimum_time(force_limit)
    else:
        duration = duration or default_duration(planner)
        if robust:
            planner = robust_planner(cfg, limits, errors or {}, duration, contact_speed,
                                     intervals)[0]
        stroke = planner.best(duration, objective)
    opening = None
    if cycle:
        opener = planner_for(cfg, limits, contact_speed, intervals, opening=True)
        opening = MoldingCycle(stroke, opener.minimum_time(force_limit), hold, eject)
    name = mechanism if isinstance(mechanism, str) else mechanism.name
    return Plan(stroke, limits, planner.lower_bound(), opening, name)


def robust_planner(cfg: PlantConfig, limits: DriveLimits, errors: dict[str, float],
                   duration: float, contact_speed: float, intervals: int,
                   protection: Protection = NO_PROTECTION
                   ) -> tuple[ClampPlanner, PlantConfig, dict[str, ProfileSamples]]:
    """The robust planner (``toggle plan --robust``, ``plan_stroke(robust=True)``): the
    nominal clamp with the erroneous one as a variant, each weighed against its own S-curve
    of ``duration``; with the erroneous plant and the S-curve on both (``"nominal"``,
    ``"erroneous"``)."""
    nominal = planner_for(cfg, limits, contact_speed, intervals, protection=protection)
    nominal.check_duration(duration)  # before predicting a baseline of that length
    erroneous = cfg.with_(mechanism=with_errors(cfg.mechanism, errors)[0])
    stroke = baseline_stroke(cfg, limits, duration)
    curve = {"nominal": predict(stroke, cfg), "erroneous": predict(stroke, erroneous)}
    scale = curve["erroneous"].peak_force / curve["nominal"].peak_force
    if not math.isfinite(scale):
        raise ParameterError("the erroneous clamp's S-curve has no finite peak force")
    planner = planner_for(cfg, limits, contact_speed, intervals, (erroneous,), (scale,),
                          protection)
    return planner, erroneous, curve
