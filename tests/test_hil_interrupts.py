"""Ctrl-C and SIGTERM at any moment of ``hil``'s start-up: exit 130/143 and one line.

The console script imports hil.cli.main, and with it numpy, scipy and the rest, before main()
runs; a Ctrl-C in that first second printed a KeyboardInterrupt traceback, and a SIGTERM
killed the process without its exit code. hil/cli/__init__.py now installs the handlers
first (hil.cli.interrupts.install_exit_handlers); ``hil run`` then replaces them with its
SignalGuard (tests/test_hil_faults.py covers Ctrl-C while planning and in motion). No
handler raises inside an import: numpy's C code turned that exception into an ImportError
traceback, and some imports swallowed it (the run went on, exit 0).
"""

from __future__ import annotations

import importlib
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hil.cli import interrupts
from hil.cli.interrupts import Interrupted, SignalGuard, in_import, started_as_hil

pytestmark = pytest.mark.real_time

COMMANDS = {
    "python -m hil.cli": [sys.executable, "-m", "hil.cli"],
    "console script": [str(Path(sys.executable).with_name("hil"))],
}
SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: s after the process started: the interpreter, hil.cli's imports (0.5 s), planning's
#: imports (casadi, from 0.7 s). A signal during the planning itself: tests/test_hil_faults.py
DELAYS = (0.05, 0.2, 0.5, 1.0)
EARLIEST_HIL_CODE = 0.1  # s: hil's handlers are installed by then (25-45 ms measured)


def handles(pid: int, signum: int) -> bool:
    """The process has a handler for ``signum`` (Linux: SigCgt in /proc/PID/status)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            caught = next(int(line.split()[1], 16) for line in fh if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(caught & (1 << (signum - 1)))


def interrupt(command: list[str], signum: int, delay: float, out: Path
              ) -> tuple[int, str, bool]:
    """Start ``hil run`` (the default job), send ``signum`` after ``delay`` s; (exit code,
    stderr, whether hil's own code had installed its handlers when the signal was sent)."""
    proc = subprocess.Popen([*command, "run", "--quiet", "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            # as from a terminal: a background job's ignored SIGINT is not
                            # inherited
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(delay)
    ours = handles(proc.pid, signal.SIGTERM)  # Python itself never catches SIGTERM
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=120)
    return proc.returncode, stderr, ours


@pytest.mark.parametrize("delay", DELAYS)
@pytest.mark.parametrize("signum", SIGNALS, ids=lambda s: signal.Signals(s).name)
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_signal_during_start_up_exits_with_its_code_and_one_line(
        command: str, signum: int, delay: float, tmp_path: Path) -> None:
    if not Path(COMMANDS[command][0]).exists():
        pytest.skip(f"no {COMMANDS[command][0]}")
    for attempt in range(5):
        out = tmp_path / f"run{attempt}"
        code, stderr, ours = interrupt(COMMANDS[command], signum, delay, out)
        if ours or delay >= EARLIEST_HIL_CODE:
            break
        # 50 ms: the interpreter can still be starting on a loaded machine (its site
        # imports take 15-30 ms here), before any code of hil's ran: try again
    else:
        pytest.skip(f"the interpreter had not reached hil's code {delay} s after its start")
    assert code == 128 + signum, stderr
    assert "Traceback" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if "interrupted by" in line]
    assert lines == [lines[-1]] and signal.Signals(signum).name in lines[0], stderr
    assert not out.exists()  # nothing was recorded


def test_only_the_hil_command_installs_the_exit_handlers() -> None:
    python = "/usr/bin/python3"
    assert started_as_hil(["/venv/bin/hil", "run"], [python, "/venv/bin/hil", "run"])
    assert started_as_hil(["-m"], [python, "-m", "hil.cli", "run"])
    assert started_as_hil(["-m"], [python, "-u", "-X", "dev", "-W", "error", "-m", "hil.cli"])
    assert started_as_hil(["-m"], [python, "-u", "-mhil.cli"])
    assert not started_as_hil(["-m"], [python, "-m", "pytest", "tests"])
    assert not started_as_hil(["/venv/bin/pytest"], [python, "/venv/bin/pytest"])
    assert not started_as_hil(["-c"], [python, "-c", "import hil"])
    assert not started_as_hil(["script.py"], [python, "script.py", "-m", "hil.cli"])
    # this process (pytest) keeps Python's own handlers: importing hil changed nothing
    assert signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, None)


SWALLOWING_MODULE = """
    import os, signal, time
    from hil.cli.interrupts import in_import
    INSIDE = in_import(__import__("sys")._getframe())
    try:  # what numpy's C import of datetime does to an exception raised in it
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
        SWALLOWED = False
    except BaseException:
        SWALLOWED = True
"""


def import_swallowing(tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(SWALLOWING_MODULE))
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.import_module(name)


def test_a_signal_inside_an_import_is_raised_after_it(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    assert not in_import(sys._getframe())
    with SignalGuard() as guard, pytest.raises(Interrupted):
        import_swallowing(tmp_path, "swallows_in_run", monkeypatch)
        time.sleep(1.0)  # delivered again within REDELIVER once the import is over
    module = sys.modules["swallows_in_run"]
    assert module.INSIDE and not module.SWALLOWED and guard.received == signal.SIGINT


def test_the_exit_handler_exits_after_an_import_not_inside_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    previous = signal.signal(signal.SIGINT, interrupts._exit_cleanly())
    try:
        with pytest.raises(SystemExit) as info:
            import_swallowing(tmp_path, "swallows_at_start", monkeypatch)
            time.sleep(1.0)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert info.value.code == 130 and not sys.modules["swallows_at_start"].SWALLOWED
