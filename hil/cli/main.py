"""The ``hil`` command: run experiments on the simulated or the real rig, emulate a rig, fit RSMs.

``hil run`` uses the FMU back-end unless ``--real`` (or ``backend = "real"`` in
a ``--config`` TOML file) selects the rig on ``--port``; nothing else changes.
Options are SI (m, m/s, N); the run directory gets samples.csv (units in the
header), meta.json, summary.json and the force plot, named on the last line. Outputs,
errors and exit codes follow ``toggle``'s convention (docs/cli.md, "Outputs and errors"): 0
done, 1 the run stopped early or could not start, 2 a usage error or unusable input,
130/143 SIGINT/SIGTERM.

This module builds the parser and dispatches; it imports nothing heavy (numpy, SciPy,
CasADi, fmpy): each command's module (run.py, emulate.py, rig.py, rsm.py) loads what it runs
when it runs, so ``hil --version`` and ``hil COMMAND --help`` answer as fast as ``toggle``'s.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

from hil.cli import rig as cli_rig
from hil.cli import rsm as cli_rsm
from hil.cli.interrupts import exit_cleanly_on_signals
from hil.host.run_settings import RUN_DEFAULTS, add_number_options
from hil.panel import command as panel_command
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
from toggle.files import InputError, OutputError, allow_overwrite, one_line
from toggle.interrupts import raised_signal, signal_taken
from toggle.params import ParameterError


def run(args: argparse.Namespace) -> int:
    """``hil run`` (hil/cli/run.py)."""
    from hil.cli.run import run

    return run(args)


def emulate(args: argparse.Namespace) -> int:
    """``hil emulate`` (hil/cli/emulate.py)."""
    from hil.cli.emulate import emulate

    return emulate(args)


def _stopped_errors() -> tuple[type[Exception], ...]:
    """The errors of a run or a rig action that failed or stopped early (exit 1), beyond
    ValueError and OSError; their modules are loaded on this error path only."""
    from hil.host.backends import RunStoppedError

    return RunStoppedError, cli_rig.RigCommandError


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
                        "file (li_micro has no masses, dong2022 is a press; default: the "
                        "preset of --fmu, or of the FMU toggle build-fmu wrote last, else "
                        "chang2021)")
    add_number_options(p)
    p.add_argument("--profile", type=path, default=None,
                   help="planned profile CSV (toggle plan --out); replayed forward and back, "
                        "with the preset, mold and friction it was planned for")
    p.add_argument("--out", type=path, default=None, metavar="DIR",
                   help="results folder of the run, named on the last line (default "
                        "runs/<time>-<backend>)")
    p.add_argument("--fmu", type=path, default=None,
                   help="the simulated rig's FMU; its preset is the run's unless one is given "
                        "(default: the build folder's, build/ToggleClamp.fmu as toggle "
                        "build-fmu wrote it last, or build/PRESET/, built when "
                        "missing or older than the model)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(handler=run, checks_outputs=True)
    e = sub.add_parser("emulate", help="serve an emulated rig on a pseudo-terminal",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    cli_rig.add_emulator_options(e)
    e.set_defaults(handler=emulate)
    cli_rig.add_parser(sub)
    panel_command.add_parser(sub)
    cli_rsm.add_parser(sub)
    add_completion(sub, "hil", build_parser)
    add_force_options(parser)
    use_help_formatter(parser)
    remember_parsers(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hil`` script; returns the exit status.

    The convention is ``toggle``'s (docs/cli.md, "Outputs and errors"): 2 a usage error or
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
    except (ParameterError, InputError, OutputError) as exc:  # an RsmError is an InputError
        return _error(command, exc, 2)
    except (ValueError, OSError) as exc:  # a TrajectoryError, a RecordingError among them
        return _error(command, exc, 1)
    except RuntimeError as exc:
        if not isinstance(exc, _stopped_errors()):
            raise
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
