"""The ``toggle`` command line: one sub-command per module in this package.

The top floor of the project: it imports the model (toggle), the planner (controllers),
the FMU builders (fmu_src) and the clamp synthesis (design); nothing imports it. Each
command module defines ``add_parser(subparsers)``; a module may also define
``add_plot_parser(plot_subparsers)`` to add a ``toggle plot <kind>`` figure. Values are SI
inside; the tables convert to mm and degrees.

Every command line builds every command's parser, so the command modules import nothing
heavy at their top (numpy, SciPy, CasADi, the planner: a third of a second): each command
loads what it runs when it runs, and arguments whose declarations need such a module are
added only when the command line names their command
(:func:`toggle_cli.common.add_arguments_later`).

The command's process gets its SIGINT/SIGTERM handlers on this file's first lines, before
numpy and the rest load (a Ctrl-C in its first second printed a KeyboardInterrupt
traceback); :func:`main` then installs handlers that unwind.
"""

from __future__ import annotations

from toggle.interrupts import install_exit_handlers, started_as

if started_as("toggle", "toggle_cli"):
    install_exit_handlers("toggle")

import argparse  # noqa: E402
import importlib  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
from collections.abc import Collection, Sequence  # noqa: E402

from toggle.args import (  # noqa: E402
    add_completion,
    add_force_options,
    add_version,
    join_negative_numbers,
    parse_command_line,
    quiet_broken_pipe,
    remember_parsers,
    use_help_formatter,
    version,
)
from toggle.files import allow_overwrite, one_line, print_results, take_written  # noqa: E402
from toggle.interrupts import (  # noqa: E402
    Terminated,
    raised_signal,
    signal_taken,
    unwind_on_signals,
)

#: Commands (their words) whose modules check their output files with
#: :func:`toggle.files.check_writable` before the work (``toggle plan``: --out, --cycle-out,
#: --duty-plot) without marking it: they take ``--force`` too.
CHECKS_OUTPUTS = (("plan",),)

#: Command modules, in the order ``toggle --help`` lists them.
COMMANDS = ("kinematics", "tolerance", "clamp", "synthesize", "study", "asymmetry", "calibrate",
            "tables", "build_fmu", "plan", "design", "plot", "cache")


def build_parser(words: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The ``toggle`` command line's parser; with ``words`` (the command line's), the
    arguments kept back (:func:`toggle_cli.common.add_arguments_later`) only of the
    sub-commands it names, which are all the parser can parse of it."""
    from toggle_cli.common import add_waiting_arguments

    parser = argparse.ArgumentParser(
        prog="toggle", description="Double-toggle mold/die clamp: model, analysis and tools."
    )
    add_version(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"toggle_cli.{name}").add_parser(sub)
    add_waiting_arguments(parser, words)
    add_completion(sub, "toggle", build_parser)
    for chain in CHECKS_OUTPUTS:
        command = parser
        for word in chain:
            command = _subcommands(command)[word]
        command.set_defaults(checks_outputs=True)
    add_force_options(parser)
    use_help_formatter(parser)
    remember_parsers(parser)
    return parser


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            return dict(action.choices)
    return {}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``toggle`` script; returns the exit status.

    Exit codes: 0 done, 2 a usage error or unreadable or invalid input (a bad option,
    preset, value or file; an output refused before the work), 1 a run that failed (a
    solver that fails, a write that fails midway), 130 Ctrl-C, 143 SIGTERM.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv == ["--version"]:  # without loading the commands (numpy, CasADi: seconds)
        print(f"toggle {version()}")
        return 0
    argv = join_negative_numbers(argv)
    args = parse_command_line(build_parser(words=argv), argv)

    # from here a signal unwinds into the handlers below (while the commands' modules load
    # and the arguments are parsed, toggle/__init__.py's end the process at once)
    unwind_on_signals()
    command = " ".join(filter(None, (args.command, getattr(args, "kind", None))))
    try:
        try:
            check_outputs(args)
            take_written()  # what this command writes from here is named on its last line
            code = int(args.handler(args) or 0)
            print_results(take_written(), to_stderr=getattr(args, "json", False))
            return code
        except Exception as exc:  # a signal's exception wrapped or lost by C code: the signal
            stop = signal_cause(exc) or raised_signal()
            if stop is None:
                raise
            raise stop from None
        finally:  # no progress line after the error printed below: it is the last line
            if (shown := sys.modules.get("controllers.progress")) is not None:
                shown.stop_all()
    except BrokenPipeError:
        return quiet_broken_pipe()
    except Terminated:  # SIGTERM: a planning process that ran is stopped
        signal_taken()
        print(f"toggle {command}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        signal_taken()
        print(f"toggle {command}: interrupted", file=sys.stderr)
        return 130
    except ValueError as exc:  # ParameterError, AssemblyError, InputError, OutputError too
        print(f"toggle {command}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError) as exc:
        print(f"toggle {command}: error: {one_line(exc)}", file=sys.stderr)
        return 1
    finally:  # the policy is the command's: a library caller in this process keeps replacing

        allow_overwrite(True)


def check_outputs(args: argparse.Namespace) -> None:
    """Before the work: the process's overwrite policy from ``--force``, the settings a
    command takes from its input file (its ``prepare``), and the files the command declared
    (:func:`toggle_cli.common.declare_outputs`, named after those settings) checked
    writable."""
    from toggle.files import OutputError, check_writable, check_writable_dir
    from toggle_cli.common import outputs

    allow_overwrite(getattr(args, "force", False))
    prepare = getattr(args, "prepare", None)  # settings read from an input file (plot plan)
    if prepare is not None:
        prepare(args)
    targets = outputs(args)
    if targets:
        if args.out.suffix.lower() in (".png", ".gif", ".csv") and not args.out.is_dir():
            raise OutputError(f"--out {args.out}: names a file; --out is the folder the "
                              f"results go into ({', '.join(t.name for t in targets)})")
        check_writable_dir(args.out, "--out")
    for target in targets:
        check_writable(target, "--out")


def signal_cause(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (or :class:`Terminated`) ``exc`` is, or was raised from: a
    signal handler's exception raised in Python code that C code called (CasADi's
    ``DM.__array__``) comes back as SystemError("... returned a result with an exception
    set") with the signal's exception as its cause."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, KeyboardInterrupt):
            return seen
        seen = seen.__cause__ or seen.__context__
    return None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
