"""The ``hil`` command: run experiments on the simulated or the real rig, emulate a rig, fit RSMs.

``hil run`` uses the FMU back-end unless ``--real`` (or ``backend = "real"`` in
a ``--config`` TOML file) selects the rig on ``--port``; nothing else changes.
Options are SI (m, m/s, N); the run directory gets samples.csv (units in the
header), meta.json, summary.json and the force plot, named on the last line. Outputs,
errors and exit codes follow ``toggle``'s convention (README, "Outputs and errors"): 0
done, 1 the run stopped early or could not start, 2 a usage error or unusable input,
130/143 SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, NoReturn

from controllers.progress import Progress
from hil import cli_rig, cli_rsm, experiment
from hil.backends import FmuPlant, Plant, RigPlant, RigSetup, RunStoppedError
from hil.experiment import (
    DEFAULT_END_TOL,
    CycleCounter,
    profile_cycles,
    reciprocating_trajectory,
)
from hil.interrupts import Interrupted, SignalGuard, exit_cleanly_on_signals
from hil.recording import RUN_FILES, RecordingError, RunMeta, RunRecorder
from hil.rsm import RsmError
from hil.run_settings import (
    BYTES_PER_SAMPLE,
    RUN_DEFAULTS,
    RunSettings,
    add_number_options,
    check_mold,
    resolve_settings,
)
from hil.samples import Trajectory, TrajectoryError
from toggle.args import (
    add_completion,
    add_force_options,
    add_version,
    join_negative_numbers,
    parse_command_line,
    path,
    quiet_broken_pipe,
    remember_parsers,
    use_help_formatter,
)
from toggle.elastics import clamp_stroke
from toggle.files import InputError, OutputError, allow_overwrite, one_line, print_results
from toggle.interrupts import raised_signal, signal_taken
from toggle.json_text import json_text
from toggle.params import DYNAMICS_PARAMETERS, ParameterError, load_preset
from toggle.rig_calibration import load_paper_tables

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
    """Seed 000's measured statistics (Tables 3-8, SI: mean and printed 3 sigma) of the
    condition this run repeats (a --speed run of the preset they were measured on at one of
    their speeds and link-8 errors), with the table's number; None for any other run."""
    if s.speed is None:
        return None
    tables = load_paper_tables()
    cell = tables.cell(s.preset, s.speed, s.delta_r8)
    if cell is None:
        return None
    i, j = cell
    return {"speed": float(tables.speeds[i]), "delta_r8": float(tables.errors[j]),
            **{key: {"table": (3 if key == "stroke" else 6) + i,
                     "mean": float(tables.mean[key][i, j]),
                     "three_sigma": float(tables.three_sigma[key][i, j])}
               for key in tables.mean}}


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
    # from here a signal only gets noted; the loop acts on it between samples, so the
    # recording and the link are never cut mid-operation
    guard.shield = True
    samples = plant.run(trajectory, guard.check)
    # a bar on a terminal, a line every few seconds in a log (closed below on every ending)
    bar = Progress(f"hil run ({plant.name})", unit="cycle", total=s.cycles, enabled=not s.quiet)
    try:
        for sample in samples:
            rec.append(sample)
            if counter.update(sample.x_cmd):
                bar.advance()
            guard.check()
    except (RunStoppedError, TrajectoryError) as exc:
        reason = str(exc)
    except Interrupted as exc:
        reason, interrupted = str(exc), exc
    finally:
        samples.close()
        for sample in plant.stop():
            rec.append(sample)
        rec.annotate(plant=plant.describe(), link=plant.link_report())
        if reason is not None:
            rec.abort(reason)
        bar.close()
    return reason, interrupted


def run(args: argparse.Namespace) -> int:
    s = resolve_settings(args)
    guard = SignalGuard()
    with guard:
        try:
            return _run(s, guard)
        except Interrupted as exc:  # before the recording started: nothing moved or recorded
            print(f"hil run: {exc}; nothing was recorded", file=sys.stderr)
            return exc.exit_code


def _run(s: RunSettings, guard: SignalGuard) -> int:
    setup = RigSetup(preset=s.preset, delta_r8=s.delta_r8, mu=s.mu, x_contact=s.x_contact,
                     force_limit=s.force_limit, as_built=s.as_built)
    trajectory, source = _trajectory(s, guard, setup)
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




def emulate(args: argparse.Namespace) -> int:
    from hil.mcu_model import RigHardware
    from hil.rig_emulator import FaultPlan, RigEmulator
    from hil.rig_physics import ClampPhysics

    setup = RigSetup(preset=args.preset, delta_r8=args.delta_r8, mu=args.mu)
    if args.x_contact == "planned":
        setup = replace(setup, x_contact=setup.planned_mold)
    elif args.x_contact is not None:
        check_mold(args.preset, args.x_contact)
        setup = replace(setup, x_contact=args.x_contact)
    faults = FaultPlan(drop_byte=args.drop_byte, flip_bit=args.flip_bit, junk=args.junk,
                       stall_at=args.stall_at, reset_at=args.reset_at, estop_at=args.estop_at,
                       disconnect_at=args.disconnect_at, seed=args.seed,
                       reconnect_after=None if args.disconnect_at is None else 0.5)
    physics = ClampPhysics(setup.preset, setup.delta_r8, setup.mu, setup.x_contact)
    hardware = RigHardware(x_origin=setup.stroke[0])
    if args.board == "nucleo":
        return _emulate_nucleo(args, setup, hardware)
    if args.qemu:
        return _emulate_qemu(args, setup, hardware)
    # an MCU's timer interrupt is hard real time: SCHED_FIFO when the OS permits it
    emulator = RigEmulator(physics, hardware, faults, realtime=True, firmware=args.firmware)
    print(emulator.open(), flush=True)
    emulator.on_port = lambda port: print(port, flush=True)  # after a re-plugged disconnect
    guard = SignalGuard()
    try:
        with guard:
            emulator.serve()
    except Interrupted:
        pass
    finally:
        emulator.close()
    return 0


def serve_until(stopped: Callable[[], bool]) -> None:
    """Serve an emulated rig (its own threads do the work) until ``stopped()``; a signal
    meanwhile raises :class:`~hil.interrupts.Interrupted` out of it."""
    while not stopped():
        time.sleep(0.2)


def _no_injection(args: argparse.Namespace, option: str) -> None:
    if not args.firmware:
        raise ParameterError(f"{option} runs the firmware: give --firmware too")
    injected = [n for n in ("drop_byte", "flip_bit", "junk", "stall_at", "reset_at",
                            "estop_at", "disconnect_at") if getattr(args, n)]
    if injected:
        raise ParameterError(f"{option} injects no faults: drop {', '.join(injected)}")


def _emulate_nucleo(args: argparse.Namespace, setup: RigSetup, hardware: Any) -> int:
    """The NUCLEO-F446RE image rehosted (hil/rehost/): print its pty, serve until a signal;
    on stderr the image's SHA-256 and, at the end, the emulated/wall time ratio."""
    if args.qemu:
        raise ParameterError("--board nucleo and --qemu are two ways to run the firmware: "
                         "give one")
    _no_injection(args, "--board nucleo")
    from hil.firmware_qemu import qemu_available
    from hil.rig_physics import ClampPhysics

    missing = qemu_available(need_qemu=False)
    if missing:
        raise OSError(f"--board nucleo needs the Debian packages {' '.join(missing)} "
                      f"(apt-get install {' '.join(missing)})")
    try:
        from hil.rehost.nucleo import NucleoBoard, NucleoRig, build_nucleo_image
    except ImportError as exc:
        raise OSError(f"--board nucleo needs the unicorn package: {exc}") from None
    elf = build_nucleo_image()
    physics = ClampPhysics(setup.preset, setup.delta_r8, setup.mu, setup.x_contact)
    board = NucleoBoard(elf, physics, hardware, seed=args.seed)
    guard = SignalGuard()
    rig = NucleoRig(board)
    try:
        print(rig.port, flush=True)
        print(f"hil emulate: {elf} sha256 {board.elf_sha256}", file=sys.stderr, flush=True)
        with guard:
            serve_until(lambda: rig.error is not None)
        stopped = f"the rehosted board stopped: {rig.error}"
    except Interrupted:
        stopped = None
    finally:
        rig.close()
        print(f"hil emulate: emulated/wall time {rig.time_ratio:.3f}; {rig.summary()}",
              file=sys.stderr)
    if stopped is not None:
        print(f"hil emulate: error: {stopped}", file=sys.stderr)
        return 1
    return 0


def _emulate_qemu(args: argparse.Namespace, setup: RigSetup, hardware: Any) -> int:
    """The firmware's Cortex-M build in QEMU: print its pty, serve until a signal."""
    _no_injection(args, "--qemu")
    from hil.firmware_qemu import QemuRig, build_qemu_image, qemu_available

    missing = qemu_available()
    if missing:
        raise OSError(f"--qemu needs the Debian packages {' '.join(missing)} "
                      f"(apt-get install {' '.join(missing)})")
    image = build_qemu_image(setup, hardware, args.seed)
    guard = SignalGuard()
    try:
        with guard, QemuRig(image) as rig:
            print(rig.port, flush=True)
            serve_until(lambda: not rig.running)
            print(f"hil emulate: error: QEMU ended: {' '.join(rig.output[-3:])}",
                  file=sys.stderr)
            return 1
    except Interrupted:
        pass
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hil", description="Run experiments on the simulated "
                                     "or the real rig, emulate a rig, fit response surfaces.",
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("run", help="run an experiment (simulated rig unless --real)",
                       description="Run an experiment; every option can also come from "
                                   "--config (command line wins). Defaults: "
                                   + ", ".join(f"{k} {v}" for k, v in RUN_DEFAULTS.items()
                                               if v is not None))
    p.add_argument("--config", type=path, default=None,
                   help="TOML file with any of these options (keys with underscores)")
    p.add_argument("--real", action="store_const", const="real", dest="backend", default=None,
                   help="use the real rig (or an emulator) on --port instead of the FMU")
    p.add_argument("--port", default=None, help="serial URL of the rig: /dev/ttyACM0, a pty, "
                                                "socket://host:port (needs --real)")
    p.add_argument("--no-as-built", action="store_const", const=False, dest="as_built",
                   default=None, help="simulate the model's clamp, without the prototype's "
                                      "as-built errors (for example to replay a plan on the "
                                      "clamp it was planned for)")
    p.add_argument("--preset", default=None,
                   help="clamp preset with [dynamics] masses: chang2021, lin2003_sm55 or a TOML "
                        "file (li_micro has no masses, dong2022 is a press; default chang2021)")
    add_number_options(p)
    p.add_argument("--profile", type=path, default=None,
                   help="planned profile CSV (toggle plan --out); replayed forward and back, "
                        "with the preset, mold and friction it was planned for")
    p.add_argument("--out", type=path, default=None, metavar="DIR",
                   help="results folder of the run, named on the last line (default "
                        "runs/<time>-<backend>)")
    p.add_argument("--fmu", type=path, default=None,
                   help="the simulated rig's FMU (default build/ToggleClamp.fmu, built when "
                        "missing or older than the model)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=run, checks_outputs=True)
    e = sub.add_parser("emulate", help="serve an emulated rig on a pseudo-terminal",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    cli_rig.add_emulator_options(e)
    e.set_defaults(handler=emulate)
    cli_rig.add_parser(sub)
    cli_rsm.add_parser(sub)
    add_completion(sub, "hil", build_parser)
    add_force_options(parser)
    use_help_formatter(parser)
    remember_parsers(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hil`` script; returns the exit status.

    The convention is ``toggle``'s (README, "Outputs and errors"): 2 a usage error or
    unreadable or invalid input (an option, a --config, --profile or run file; an output
    refused before the work), 1 a run that failed or stopped early, 130/143 SIGINT/SIGTERM;
    every error one ``hil COMMAND: error:`` line in words.
    """
    exit_cleanly_on_signals()  # from here a signal unwinds (hil/__init__.py: at once before)
    args = parse_command_line(build_parser(), join_negative_numbers(
        sys.argv[1:] if argv is None else list(argv)))
    command = " ".join(filter(None, (args.command, getattr(args, "action", None))))
    allow_overwrite(getattr(args, "force", False))
    try:
        return int(args.handler(args) or 0)
    except BrokenPipeError:
        return quiet_broken_pipe()
    except (ParameterError, InputError, OutputError, RsmError) as exc:
        return _error(command, exc, 2)
    except (TrajectoryError, RecordingError, RunStoppedError, cli_rig.RigCommandError,
            ValueError, OSError) as exc:
        return _error(command, exc, 1)
    finally:  # the policy is the command's: a library caller in this process keeps replacing
        allow_overwrite(True)


def _error(command: str, exc: Exception, code: int) -> int:
    """One ``hil COMMAND: error:`` line and ``code``; but the signal instead where one was
    raised and lost on the way (:func:`toggle.interrupts.raised_signal`)."""
    stop = raised_signal()
    if stop is not None:
        raise stop from None
    print(f"hil {command}: error: {one_line(exc)}", file=sys.stderr)
    return code


def entry() -> NoReturn:
    """The ``hil`` script: :func:`main`, then the process ends at once with its exit code.

    Everything the command opened is closed by then (the rig's session, the run's files,
    QEMU); what is left is the interpreter's teardown of numpy, scipy, CasADi and fmpy,
    measured at 110-200 ms here, which made a run that gave up on a deaf MCU exit 0.8 s
    after it (issue 35). The SystemExit of a signal (:func:`exit_cleanly_on_signals`) is
    taken here, so it is not delivered again; any other exception unwinds as usual."""
    try:
        code = main()
    except SystemExit as stop:
        signal_taken()
        code = stop.code if isinstance(stop.code, int) else int(stop.code is not None)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed or broken pipe
            stream.flush()
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
