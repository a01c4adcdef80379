"""``hil run``: an experiment on the simulated rig (the FMU) or the real one (``--real``).

The run directory gets samples.csv (units in the header), meta.json, summary.json and the
force plot, named on the last line; a run that stops early keeps what it recorded.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from typing import Any

from controllers.progress import Progress
from hil.cli.interrupts import Interrupted, SignalGuard
from hil.host import experiment
from hil.host.backends import (
    FmuPlant,
    Plant,
    RigPlant,
    RigSetup,
    default_fmu_path,
)
from hil.host.experiment import (
    DEFAULT_END_TOL,
    CycleCounter,
    profile_cycles,
    reciprocating_trajectory,
)
from hil.host.recording import (
    RUN_FILES,
    RunMeta,
    RunRecorder,
    prototype_statistics,
    record_run,
)
from hil.host.run_settings import (
    BYTES_PER_SAMPLE,
    RunSettings,
    limit_for_plan,
    resolve_settings,
)
from hil.host.samples import Trajectory, TrajectoryError
from toggle.elastics import clamp_stroke
from toggle.files import print_results
from toggle.json_text import json_text
from toggle.params import DYNAMICS_PARAMETERS, ParameterError, load_preset

#: Printed rows of a run summary: (key, label, scale to the printed unit, unit).
SUMMARY_ROWS = (
    ("stroke", "stroke S", 1e3, "mm"),
    ("stroke_error", "stroke error dS", 1e3, "mm"),
    ("force_forward_max", "F_F(max)", 1.0, "N"),
    ("force_forward_rms", "F_F(rms)", 1.0, "N"),
    ("force_backward_min", "F_B(min)", 1.0, "N"),
    ("force_backward_rms", "F_B(rms)", 1.0, "N"),
    ("force_toggle", "F_TP", 1.0, "N"),
)
#: Runs longer than this print their estimated duration and file size first, s.
ANNOUNCE_AFTER = 60.0
#: The unit of each [dynamics] field as printed (" N", " kg", ...; nothing for a ratio).
UNITS = {field: "" if unit == "1" else f" {unit}"
         for field, unit, _ in DYNAMICS_PARAMETERS.values()}


def _trajectory(s: RunSettings, guard: SignalGuard, setup: RigSetup
                ) -> tuple[Trajectory, str]:
    period = setup.period
    if s.profile is not None:
        forward = Trajectory.from_csv(s.profile, period=period)
        return _guarded(profile_cycles(forward, s.cycles), s), f"profile {s.profile}"
    if s.speed is not None:
        nominal = load_preset(s.preset)
        x_open, x_tp = clamp_stroke(nominal)
        _guard_duration(2 * s.cycles * (x_tp - x_open) / s.speed, s)  # before building it
        return reciprocating_trajectory(nominal, s.speed, s.cycles, period), (
            f"reciprocating at {s.speed * 1e3:g} mm/s")
    errors = {name: delta for name, delta in setup.errors.items() if delta}
    built = ", ".join([*(f"delta_{name} {delta * 1e3:g} mm" for name, delta in errors.items()),
                       *(f"{name} {value:g}{UNITS[name]}"
                         for name, value in setup.dynamics.items())])
    print(f"hil run: planning the default profile for {s.preset}"
          f"{f' as the rig is built ({built})' if built else ''}", file=sys.stderr)
    try:
        forward = experiment.planned_trajectory(s.preset, period, mu=s.mu,
                                                x_contact=s.x_contact, errors=errors,
                                                masses=setup.dynamics)
    finally:  # IPOPT swallows Ctrl-C: act on it before anything moves, and before the
        guard.check()  # failed solve it made is reported as a planning error
    return _guarded(profile_cycles(forward, s.cycles), s), (
        f"planned (minimum peak input force){f' for {built}' if built else ''}")


def _plan_peak(s: RunSettings, setup: RigSetup, forward: Trajectory) -> float:
    """The peak input force (N) of the default job's plan on the clamp it was planned for
    (the model, :func:`toggle.plant.plant_outputs`, on the plan's sampled positions)."""
    import numpy as np

    from controllers.plans import plan_config
    from toggle.plant import plant_outputs

    errors = {name: delta for name, delta in setup.errors.items() if delta}
    cfg = plan_config(s.preset, mu=s.mu, x_contact=s.x_contact, errors=errors,
                      masses=setup.dynamics)
    velocity = np.gradient(forward.x_cmd, forward.period)
    forces = plant_outputs(forward.x_cmd, velocity, np.gradient(velocity, forward.period),
                           cfg).input_force
    return float(np.max(np.abs(forces)))


def _guarded(trajectory: Trajectory, s: RunSettings) -> Trajectory:
    _guard_duration(trajectory.duration, s)
    return trajectory


def _backend(s: RunSettings) -> Plant:
    if s.backend == "real":
        timeout = s.watchdog_ms * 1e-3 if s.watchdog_ms is not None else None
        return RigPlant(s.port, telemetry_timeout=timeout,
                        ack_timeout=None if s.ack_ms is None else s.ack_ms * 1e-3,
                        heartbeat_ms=s.heartbeat_ms,
                        notify=lambda msg: print(f"hil run: {msg}", file=sys.stderr))
    return FmuPlant(s.fmu, notify=lambda msg: print(f"hil run: {msg}", file=sys.stderr))


def _guard_duration(duration: float, s: RunSettings) -> None:
    """Refuse runs longer than --max-duration (s); announce long ones with their file size."""
    samples = round(duration / RigSetup.period) + 1
    size_mb = samples * BYTES_PER_SAMPLE / 1e6
    text = f"{_duration_text(duration)} of motion, about {size_mb:.3g} MB of samples"
    if duration > s.max_duration:
        raise ParameterError(f"the run would take {text}, longer than --max-duration "
                             f"{s.max_duration:g} s; raise --max-duration to run it")
    if duration > ANNOUNCE_AFTER:
        print(f"hil run: {samples} samples, {text}", file=sys.stderr)


def _duration_text(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.4g} h"  # --speed 1e-300 printed a 300-digit number


def paper_statistics(s: RunSettings) -> dict[str, Any] | None:
    """Seed 000's measured statistics of the condition this run repeats
    (:func:`hil.host.recording.prototype_statistics`); None for any other run."""
    return prototype_statistics(s.preset, s.speed, s.delta_r8)


def _print_summary(summary: dict, count: int, cycles: int, backend: str,
                   paper: dict[str, Any] | None = None) -> None:
    done = summary["cycles_complete"]
    print(f"{count} samples, {done} of {cycles} cycles complete")
    for key, label, scale, unit in SUMMARY_ROWS:
        stat = summary.get(key)
        if not isinstance(stat, dict):
            continue
        spread = (f"3 sigma {stat['three_sigma'] * scale:.4f} {unit}"
                  if stat["three_sigma"] is not None else "one cycle: no spread")
        line = f"  {label:16s} {stat['mean'] * scale:10.4f} {unit:2s}  ({spread})"
        if paper is not None and key in paper:
            m = paper[key]
            off = stat["mean"] - m["mean"]
            line += (f"  Table {m['table']}: {m['mean'] * scale:.3f} +- "
                     f"{m['three_sigma'] * scale:.3f} {unit}, " + (
                         f"{off * scale:+.3f} {unit}" if key == "stroke"
                         else f"{100 * off / abs(m['mean']):+.1f} %"))
        print(line)
    if paper is not None and backend == "fmu":
        print("  (the simulated rig's stroke is the platen's travel; the prototype's encoder "
              "read 0.38-0.56 mm more, docs/unequal-halves.md section 9.3)")
    if backend == "fmu" and done > 1:
        print("  (the simulated rig is deterministic: its spread is only the first cycle's "
              "start with the friction at rest; the real rig's is not)")
    link = summary.get("link") or {}
    if link:
        print(f"  link: {link_errors(link) or 'no errors'}, {link['retransmissions']} "
              f"retransmissions; telemetry arrival p99 {link['arrival_gap_p99_s'] * 1e3:.0f} ms, "
              f"max {link['arrival_gap_max_s'] * 1e3:.1f} ms")


def link_errors(link: dict) -> str:
    """'3 bad frames, 37 lost samples (not in samples.csv)', or '' for a clean link."""
    parts = [f"{link[key]} {text}" for key, text in (
        ("bad_frames", "bad frames"), ("lost_samples", "lost samples (not in samples.csv)"),
        ("duplicate_samples", "duplicate samples (recorded once)")) if link.get(key)]
    return ", ".join(parts)


def _record(plant: Plant, trajectory: Trajectory, rec: RunRecorder, guard: SignalGuard,
            s: RunSettings, counter: CycleCounter) -> tuple[str | None, Interrupted | None]:
    """Run the trajectory into the recorder; stop and keep the rest on every ending.

    Returns why the run ended early (None when complete) and the signal, if one ended it.
    """
    reason, interrupted = None, None
    print(f"run directory: {rec.dir}", file=sys.stderr)
    # a bar on a terminal, a line every few seconds in a log (closed below on every ending)
    bar = Progress(f"hil run ({plant.name})", unit="cycle", total=s.cycles, enabled=not s.quiet)
    # from here a signal only gets noted; the loop acts on it between samples, so the
    # recording and the link are never cut mid-operation
    guard.shield = True
    try:
        reason = record_run(plant, trajectory, rec, guard.check,
                            lambda sample: counter.update(sample.x_cmd) and bar.advance())
    except Interrupted as exc:
        reason, interrupted = str(exc), exc
    finally:
        bar.close()
    return reason, interrupted


def run(args: argparse.Namespace) -> int:
    s = resolve_settings(args)
    if s.backend == "fmu":  # which FMU, and so which clamp, the simulated rig is
        fmu = s.fmu if s.fmu is not None else default_fmu_path(s.preset)
        print(f"hil run: the simulated rig is the FMU {fmu} (preset {s.preset})",
              file=sys.stderr)
    guard = SignalGuard()
    with guard:
        try:
            return execute(s, guard)
        except Interrupted as exc:  # before the recording started: nothing moved or recorded
            print(f"hil run: {exc}; nothing was recorded", file=sys.stderr)
            return exc.exit_code


def execute(s: RunSettings, guard: SignalGuard) -> int:
    """Run the experiment ``s`` describes under ``guard``: record it, print its summary (or
    its JSON with ``s.json``) and name its files; the exit code (hil.api.run_on_rig too)."""
    setup = RigSetup(preset=s.preset, delta_r8=s.delta_r8, mu=s.mu, x_contact=s.x_contact,
                     force_limit=s.force_limit, as_built=s.as_built)
    trajectory, source = _trajectory(s, guard, setup)
    if s.profile is None and s.speed is None:  # the default job: its plan's peak, known now
        one_stroke = Trajectory.from_positions(
            trajectory.x_cmd[:int(trajectory.x_cmd.argmax()) + 1], trajectory.period)
        limit = limit_for_plan(s, _plan_peak(s, setup, one_stroke), "the default job")
        s, setup = replace(s, force_limit=limit), replace(setup, force_limit=limit)
    plant = _backend(s)
    plant.configure(setup)
    try:
        plant.check(trajectory)
    except TrajectoryError as exc:
        if s.profile is None:
            raise
        raise ParameterError(f"--profile {s.profile}: {exc} (its positions in m, times in "
                             "s)") from None
    nominal = load_preset(s.preset)
    meta = RunMeta.for_experiment(nominal, backend=plant.name, cycles=s.cycles,
                                  delta_r8=s.delta_r8, period=setup.period, speed=s.speed,
                                  profile=source, settings=s.record())
    counter = CycleCounter(*setup.stroke)
    plant.activate()  # before the run directory: a refused start leaves none
    try:
        with RunRecorder(meta, s.out, overwrite=s.force) as rec:
            try:
                reason, interrupted = _record(plant, trajectory, rec, guard, s, counter)
            finally:
                plant.deactivate()  # end the session before the summary and the plots
    finally:
        plant.deactivate()
    summary = rec.summary
    if reason is not None:
        print(f"hil run: stopped: {reason}", file=sys.stderr)
    if s.json:
        print(json_text({"run_dir": str(rec.dir), "samples": rec.count, **summary,
                         "paper": paper_statistics(s)}))
    else:
        _print_summary(summary, rec.count, s.cycles, plant.name, paper_statistics(s))
    if reason is None and summary["cycles_complete"] < s.cycles:
        print(f"hil run: {summary['cycles_complete']} of {s.cycles} cycles went from the open "
              f"position {meta.x_open * 1e3:.4g} mm to the toggle {meta.x_toggle * 1e3:.4g} mm "
              f"and back (within {DEFAULT_END_TOL * 1e6:g} um); the trajectory spans "
              f"{trajectory.x_cmd.min() * 1e3:.4g} to {trajectory.x_cmd.max() * 1e3:.4g} mm, "
              f"and the statistics cover only whole cycles", file=sys.stderr)
    if interrupted is None and guard.received is not None:  # while summarising: after the run
        interrupted = Interrupted(guard.received)
        print(f"hil run: {interrupted} after the run completed; its record is whole",
              file=sys.stderr)
    if reason is None and link_errors(summary.get("link") or {}):
        print(f"hil run: the run completed with link errors: {link_errors(summary['link'])}",
              file=sys.stderr)
        reason = "link errors"
    print_results([rec.dir / name for name in RUN_FILES if (rec.dir / name).is_file()],
                  to_stderr=s.json)
    if interrupted is not None:
        return interrupted.exit_code
    return 1 if reason is not None else 0



