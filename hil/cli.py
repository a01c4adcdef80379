"""The ``hil`` command: run experiments on the simulated or the real rig, emulate a rig, fit RSMs.

``hil run`` uses the FMU back-end unless ``--real`` (or ``backend = "real"`` in
a ``--config`` TOML file) selects the rig on ``--port``; nothing else changes.
Options are SI (m, m/s, N); the run directory gets samples.csv (units in the
header), meta.json, summary.json and the force plot.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hil import cli_rsm
from hil.backends import FmuPlant, Plant, RigPlant, RigSetup, RunStoppedError
from hil.experiment import CycleCounter, profile_cycles, reciprocating_trajectory
from hil.recording import RecordingError, RunMeta, RunRecorder
from hil.samples import Trajectory, TrajectoryError
from toggle.params import ParameterError, load_preset, tomllib

#: Keys a --config file may set (the long options' names, with underscores).
CONFIG_KEYS = {"backend", "port", "preset", "profile", "cycles", "speed", "delta_r8", "mu",
               "x_contact", "force_limit", "out", "watchdog_ms"}


def _config_defaults(path: Path | None) -> dict[str, Any]:
    if path is None:
        return {}
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ParameterError(f"cannot read config {path}: {exc}") from exc
    unknown = set(table) - CONFIG_KEYS
    if unknown:
        raise ParameterError(f"config {path}: unknown keys {sorted(unknown)}")
    if table.get("backend", "fmu") not in ("fmu", "real"):
        raise ParameterError(f"config {path}: backend must be 'fmu' or 'real'")
    return table


def _trajectory(args: argparse.Namespace, setup: RigSetup) -> tuple[Trajectory, str]:
    nominal = load_preset(setup.preset)
    if args.profile:
        forward = Trajectory.from_csv(args.profile, period=setup.period)
        return profile_cycles(forward, args.cycles), str(args.profile)
    if args.speed is not None:
        return reciprocating_trajectory(nominal, args.speed, args.cycles, setup.period), None
    from controllers.planner import plan_default_profile

    forward = plan_default_profile(setup.preset, period=setup.period)
    return profile_cycles(forward, args.cycles), "planned (minimum peak input force)"


def _backend(args: argparse.Namespace) -> Plant:
    if args.backend == "real":
        if not args.port:
            raise ParameterError("--real needs --port (a device, a pty, socket:// or loop://)")
        timeout = args.watchdog_ms * 1e-3 if args.watchdog_ms else None
        return RigPlant(args.port, telemetry_timeout=timeout)
    return FmuPlant()


def run(args: argparse.Namespace) -> int:
    if args.profile is None and args.speed is None and args.x_contact is None:
        # the default job clamps a mold: the plan's contact position (the preset's final
        # tie-bar force) is the simulated mold height too
        from controllers.planner import plan_config

        args.x_contact = plan_config(args.preset).x_contact
    setup = RigSetup(preset=args.preset, delta_r8=args.delta_r8, mu=args.mu,
                     x_contact=args.x_contact, force_limit=args.force_limit)
    plant = _backend(args)
    trajectory, profile = _trajectory(args, setup)
    plant.configure(setup)
    nominal = load_preset(setup.preset)
    meta = RunMeta.for_experiment(nominal, backend=plant.name, cycles=args.cycles,
                                  delta_r8=setup.delta_r8, period=setup.period,
                                  speed=args.speed, profile=profile)
    from tqdm import tqdm

    x_open, x_tp = setup.stroke
    counter = CycleCounter(x_open, x_tp)
    status = 0
    with RunRecorder(meta, args.out) as rec:
        print(f"run directory: {rec.dir}", file=sys.stderr)
        bar = tqdm(total=args.cycles, unit="cycle", desc=f"hil run ({plant.name})",
                   disable=args.quiet)
        try:
            with plant:
                for sample in plant.run(trajectory):
                    rec.append(sample)
                    if counter.update(sample.x_cmd):
                        bar.update(1)
        except (RunStoppedError, TrajectoryError) as exc:
            rec.abort(str(exc))
            print(f"hil run: stopped: {exc}", file=sys.stderr)
            status = 1
        finally:
            bar.close()
    summary = rec.summary
    if args.json:
        print(json.dumps({"run_dir": str(rec.dir), "samples": rec.count, **summary}, indent=2))
    else:
        print(f"{rec.count} samples in {rec.dir} (samples.csv, summary.json, meta.json, plots)")
        for key in ("stroke", "stroke_error", "force_forward_rms", "force_toggle"):
            stat = summary.get(key)
            if isinstance(stat, dict) and stat.get("mean") is not None:
                print(f"  {key:18s} mean {stat['mean']:.6g}  three_sigma {stat['three_sigma']:.3g}")
    return status


def emulate(args: argparse.Namespace) -> int:
    from hil.mcu_model import RigHardware
    from hil.rig_emulator import FaultPlan, RigEmulator
    from hil.rig_physics import ClampPhysics

    setup = RigSetup(preset=args.preset, delta_r8=args.delta_r8, mu=args.mu,
                     x_contact=args.x_contact)
    faults = FaultPlan(drop_byte=args.drop_byte, flip_bit=args.flip_bit, junk=args.junk,
                       stall_at=args.stall_at, seed=args.seed)
    physics = ClampPhysics(setup.preset, setup.delta_r8, setup.mu, setup.x_contact)
    emulator = RigEmulator(physics, RigHardware(x_origin=setup.stroke[0]), faults)
    print(emulator.open(), flush=True)

    def terminate(*_: object) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, terminate)
    try:
        emulator.serve()
    except (KeyboardInterrupt, SystemExit):
        pass
    finally:
        emulator.close()
    return 0


def _add_physics_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="chang2021", help="mechanism preset (default chang2021)")
    p.add_argument("--delta-r8", type=float, default=0.0, dest="delta_r8",
                   help="length error of link 8 of the simulated clamp, m (e.g. 0.5e-3)")
    p.add_argument("--mu", type=float, default=None, help="pin friction (default: the preset's)")
    p.add_argument("--x-contact", type=float, default=None, dest="x_contact",
                   help="crosshead position at mold contact, m (default: no mold)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hil", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("run", help="run an experiment (simulated rig unless --real)")
    p.add_argument("--config", type=Path, default=None, help="TOML file with these options")
    p.add_argument("--real", action="store_const", const="real", dest="backend",
                   help="use the real rig (or an emulator) on --port instead of the FMU")
    p.add_argument("--port", default=None, help="serial URL of the rig: /dev/ttyACM0, a pty, "
                                                "socket://host:port, loop://")
    _add_physics_options(p)
    p.add_argument("--profile", type=Path, default=None,
                   help="planned profile CSV (toggle plan --out); replayed forward and back")
    p.add_argument("--cycles", type=int, default=3, help="forward-backward cycles (default 3)")
    p.add_argument("--speed", type=float, default=None,
                   help="constant input speed of the reciprocating experiment, m/s (e.g. 5e-3)")
    p.add_argument("--force-limit", type=float, default=400.0, dest="force_limit",
                   help="stop when |input force| exceeds this, N (default 400)")
    p.add_argument("--watchdog-ms", type=float, default=None, dest="watchdog_ms",
                   help="host telemetry watchdog, ms (default three telemetry periods)")
    p.add_argument("--out", type=Path, default=None, help="run directory (default runs/<time>)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=run, backend=None)
    e = sub.add_parser("emulate", help="serve an emulated rig on a pseudo-terminal")
    _add_physics_options(e)
    e.add_argument("--drop-byte", type=float, default=0.0, help="fault: P(drop a byte) per frame")
    e.add_argument("--flip-bit", type=float, default=0.0, help="fault: P(flip a bit) per frame")
    e.add_argument("--junk", type=float, default=0.0, help="fault: P(junk before a frame)")
    e.add_argument("--stall-at", type=float, default=None, help="fault: stall at t s after START")
    e.add_argument("--seed", type=int, default=1, help="seed of the injected faults")
    e.set_defaults(handler=emulate)
    cli_rsm.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hil`` script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            config = _config_defaults(args.config)
            explicit = {k for k, v in vars(args).items() if v not in (None, False)}
            for key, value in config.items():
                if key not in explicit or parser.get_default(key) == getattr(args, key):
                    setattr(args, key, Path(value) if key in ("out", "profile") else value)
            args.backend = args.backend or "fmu"
            if args.cycles < 1:
                raise ParameterError(f"--cycles must be >= 1, got {args.cycles}")
        return int(args.handler(args) or 0)
    except (ParameterError, TrajectoryError, RecordingError, RunStoppedError, ValueError) as exc:
        print(f"hil {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
