"""Ctrl-C and SIGTERM at any moment of a ``toggle`` command: exit 130/143 and one line.

The console script imports numpy, scipy and CasADi before and while the command runs; a
Ctrl-C in that first second printed a KeyboardInterrupt traceback, and a SIGTERM killed
the process without a word. toggle/__init__.py installs the start-up handlers first
(toggle.interrupts.install_exit_handlers), main() replaces them with handlers that unwind
(toggle.interrupts.unwind_on_signals). The planning processes: tests/test_background.py;
the Dask cluster: tests/test_design_cluster.py.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from toggle.interrupts import RaiseOutsideImports, Terminated, started_as
from toggle_cli import signal_cause

pytestmark = pytest.mark.real_time

TOGGLE = Path(sys.executable).with_name("toggle")
SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: s after the start: the interpreter, the CLI's imports (numpy, from 0.1 s), the planner's
#: (casadi) and its compiled problem, the solve (about 1 s on)
DELAYS = (0.15, 0.4, 0.8, 1.5, 2.5)
#: a plan whose solve outlasts the last delay: 400 intervals took 5.8 s warm, idle, where
#: the default plan's 2.4 s ended before 2.5 s in CI
PLAN = ("plan", "--json", "--intervals", "400")
SAID = {signal.SIGINT: ("interrupted by SIGINT", "toggle plan: interrupted"),
        signal.SIGTERM: ("interrupted by SIGTERM", "toggle plan: terminated")}


def _catches_sigterm(pid: int) -> bool:
    """Whether process ``pid`` has a handler for SIGTERM (/proc/PID/status, SigCgt): the
    command's start-up handlers are installed."""
    status = Path(f"/proc/{pid}/status").read_text()
    caught = int(next(line for line in status.splitlines()
                      if line.startswith("SigCgt:")).split()[1], 16)
    return bool(caught >> (signal.SIGTERM - 1) & 1)


@pytest.mark.parametrize("delay", DELAYS)
@pytest.mark.parametrize("signum", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_a_signal_at_any_moment_of_toggle_plan_exits_with_its_code_and_one_line(
        signum: int, delay: float) -> None:
    proc = subprocess.Popen([str(TOGGLE), *PLAN], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            # as from a terminal: a background job's ignored SIGINT is not
                            # inherited
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        out, err = proc.communicate(timeout=delay)
    except subprocess.TimeoutExpired:
        # not before the command's first line has run: a signal before it meets only the
        # interpreter's own start-up (which took over 0.15 s at load 9)
        deadline = time.monotonic() + 30
        while not _catches_sigterm(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.002)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=60)
    else:
        pytest.fail(f"toggle plan ended before {delay} s: {err}")
    assert proc.returncode == 128 + signum and out == "", err
    assert "Traceback" not in err, err
    # besides ours, only CasADi's own line when the signal stopped an IPOPT solve
    lines = [line for line in err.strip().splitlines()
             if 'WARNING("KeyboardInterruptException")' not in line]
    assert len(lines) == 1 and lines[0].endswith(SAID[signum]), err


def test_a_signal_raised_where_c_code_called_python_is_still_the_signal() -> None:
    """A handler's exception raised in Python that C code called (CasADi's DM.__array__
    calling DM.elements) comes back as SystemError with it as the cause: SIGTERM 1.5 s
    into ``toggle plan`` then exited 1 with that traceback."""
    try:
        try:
            raise Terminated("signal 15")
        except Terminated as stop:
            raise SystemError("<function DM.__array__> returned a result with an exception "
                              "set") from stop
    except SystemError as exc:
        assert isinstance(signal_cause(exc), Terminated)
    assert signal_cause(SystemError("a bug of C code")) is None
    assert isinstance(signal_cause(KeyboardInterrupt()), KeyboardInterrupt)


def test_only_the_toggle_command_installs_the_start_up_handlers() -> None:
    python = "/usr/bin/python3"
    assert started_as("toggle", "toggle_cli", ["/venv/bin/toggle", "plan"],
                      [python, "/venv/bin/toggle", "plan"])
    assert not started_as("toggle", "toggle_cli", ["/venv/bin/hil", "run"],
                          [python, "/venv/bin/hil", "run"])
    assert not started_as("toggle", "toggle_cli", ["/venv/bin/pytest"],
                          [python, "/venv/bin/pytest"])
    assert not started_as("toggle", "toggle_cli", ["-c"], [python, "-c", "import toggle"])
    # a planning process spawned from toggle: its sys.argv is the parent's
    assert not started_as("toggle", "toggle_cli", ["/venv/bin/toggle", "plan"],
                          [python, "-c", "from multiprocessing.spawn import spawn_main",
                           "--multiprocessing-fork"])
    # this process (pytest) keeps Python's own handlers: importing toggle changed nothing
    assert signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, None)
    # (SIG_IGN where pytest runs as a shell's background job, which ignores SIGINT)
    assert signal.getsignal(signal.SIGINT) in (signal.default_int_handler, signal.SIG_IGN)


#: ``toggle plan`` in a process that sends itself ``SIG`` the first time CasADi's Python
#: type check ``CHECK`` (called from its C code, which clears what it raises) runs after the
#: command's handlers are installed: the moment a Ctrl-C was lost 0.8 s into a plan.
_SIGNAL_IN_A_TYPE_CHECK = """
import os, signal, sys
sys.argv = [{toggle!r}, "plan", "--json"]
import toggle_cli
from toggle.interrupts import RaiseOutsideImports

def tracer(frame, event, arg):
    if (frame.f_code.co_name == {check!r} and frame.f_code.co_filename.endswith("casadi.py")
            and isinstance(signal.getsignal({sig}), RaiseOutsideImports)):
        sys.settrace(None)
        sys.stderr.write("sent\\n")
        os.kill(os.getpid(), {sig})

sys.settrace(tracer)
sys.exit(toggle_cli.main())
"""


@pytest.mark.parametrize("check", ["size1", "DM_from_csc", "DM_from_array"])
@pytest.mark.parametrize("signum", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_a_signal_whose_exception_casadi_clears_still_ends_toggle_plan(
        check: str, signum: int) -> None:
    """CasADi's SWIG type checks clear any exception their Python raised; the handler's
    KeyboardInterrupt raised there was lost and the plan finished with exit 0 (a CI run),
    or CasADi went on to "Wrong number or type of arguments" and toggle exited 1 with that
    error. The handler keeps the signal and raises it again until main() takes it; an
    error that follows a signal not taken is the signal."""
    code = _SIGNAL_IN_A_TYPE_CHECK.format(toggle=str(TOGGLE), check=check, sig=int(signum))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = proc.stderr.strip().splitlines()
    assert lines[0] == "sent", proc.stderr  # the signal met the type check
    assert proc.returncode == 128 + signum and proc.stdout == "", proc.stderr
    assert len(lines) == 2 and lines[1].endswith(SAID[signum]), proc.stderr


def test_a_raised_signal_is_raised_again_until_taken_but_not_during_its_cleanup() -> None:
    """The handler's contract on its own: an exception swallowed (``except: pass``, as
    CasADi's checks do) comes back within a few KEEP intervals; while it unwinds through a
    ``finally`` it is not raised again; once taken, nothing more is delivered."""
    handler = RaiseOutsideImports()
    previous = signal.signal(signal.SIGINT, handler)
    raised: list[KeyboardInterrupt] = []
    try:
        try:
            for i in range(1000):
                try:
                    if i == 0:
                        os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(0.001)
                except KeyboardInterrupt as exc:
                    raised.append(exc)
                    if len(raised) == 1:
                        continue  # swallowed
                    raise
            pytest.fail("a swallowed signal was not raised again within 1 s")
        except KeyboardInterrupt:
            try:
                try:
                    raise
                finally:
                    time.sleep(5 * handler.KEEP)  # cleanup: deliveries again, no raise
            except KeyboardInterrupt:  # main()'s last handler
                handler.taken()
        assert len(raised) == 2
        time.sleep(3 * handler.KEEP)  # a delivery sent before taken() is ignored
        assert handler.pending is None and handler.raised is None
    finally:
        handler.taken()
        signal.signal(signal.SIGINT, previous)


def test_a_signal_held_back_is_not_raised_by_another_thread_inside_the_block() -> None:
    """signals_held blocks the signal in this thread, but a thread that does not block it
    (a progress bar's, a timer's) receives a process-directed one, and Python runs the
    handler in the main thread anyway: a Ctrl-C raised inside Process.start() and the
    planning child died on "EOFError: Ran out of input" with a traceback. Inside the block
    nothing is raised; on leaving, the signal is."""
    from toggle.interrupts import signals_held

    other = threading.Thread(target=time.sleep, args=(1.0,), daemon=True)
    other.start()
    inside: list[str] = []
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt), signals_held(signal.SIGINT):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(50):
                time.sleep(0.002)  # Python would run a handler here
            inside.append("not raised")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert inside == ["not raised"]
