"""Test helpers: the ``hil`` command as a separate process, and the emulator's own count.

The host runs as a user runs it (``python -m hil.cli run ...`` in its own process, so
signals and exit codes are real); the emulator runs in a process of its own and reports
what it wrote to the pty, so a test compares the CSV against what was sent, not against
what the host believes it received.
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from hil.emulators.mcu_model import RigHardware
from hil.emulators.rig_emulator import EmulatorLog, EmulatorProcess, FaultPlan, spawn_emulator
from hil.emulators.rig_physics import ClampPhysics
from hil.host.backends import RigSetup
from hil.link import protocol as p

X_OPEN = RigSetup().stroke[0]
#: A short experiment: one cycle at 40 mm/s (about 2.5 s of motion).
SHORT_RUN = ("--speed", "40e-3", "--cycles", "1", "--quiet")


def wait_for(condition: Callable[[], bool], timeout: float = 2.0) -> bool:
    """Poll ``condition`` every 5 ms until it holds (True) or ``timeout`` s pass (False)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def spawn(faults: FaultPlan | None = None, delta_r8: float = 0.0,
          firmware: bool = False) -> EmulatorProcess:
    """The emulated rig of chang2021 in its own SCHED_FIFO process; ``firmware``: its MCU
    is the C firmware's host build instead of the Python model."""
    return spawn_emulator(ClampPhysics("chang2021", delta_r8), RigHardware(x_origin=X_OPEN),
                          faults, realtime=True, firmware=firmware)


class Host:
    """``hil ARGS`` in a child process; its stderr is collected line by line as it comes."""

    def __init__(self, *args: str) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([sys.executable, "-m", "hil.cli", *args], env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self.stdout: list[str] = []
        self._readers = [threading.Thread(target=self._read, args=(stream, sink), daemon=True)
                         for stream, sink in ((self.proc.stderr, self.lines),
                                              (self.proc.stdout, self.stdout))]
        for reader in self._readers:
            reader.start()

    @staticmethod
    def _read(stream: object, sink: list[str]) -> None:
        for line in stream:
            sink.append(line.rstrip("\n"))

    def wait_for(self, text: str, timeout: float = 60.0) -> None:
        """Block until a stderr line contains ``text``."""
        deadline = time.monotonic() + timeout
        while not any(text in line for line in self.lines):
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise AssertionError(f"no {text!r} on stderr: {self.lines}")
            time.sleep(0.005)

    def finish(self, timeout: float = 120.0) -> tuple[int, str, str]:
        """(exit code, stdout, stderr) once the process ended."""
        self.proc.wait(timeout=timeout)
        for reader in self._readers:
            reader.join(timeout=5.0)
        return self.proc.returncode, "\n".join(self.stdout), "\n".join(self.lines)


def hil(*args: str, timeout: float = 120.0) -> tuple[int, str, str]:
    """Run ``hil ARGS`` to completion: (exit code, stdout, stderr)."""
    return Host(*args).finish(timeout)


def recorded_samples(run_dir: Path) -> list[int]:
    """The MCU sample indices in a run's samples.csv, in file order."""
    with (run_dir / "samples.csv").open(newline="") as fh:
        return [int(row["sample"]) for row in csv.DictReader(fh)]


def sent_samples(log: EmulatorLog, first: int, earliest_boot: bool = False) -> list[int]:
    """What the emulator sent intact for the run whose first recorded sample is ``first``: from
    the run's START to the first sample at standstill (docs/rig-protocol-behaviour.md, section 11).

    The run is the latest START at or before ``first`` in a boot that sent ``first`` intact:
    the START's own sample may have been corrupted on the wire (the dropped-bytes fault), so the
    first recorded sample can follow it. A reset restarts the sample count, so two boots can
    both have sent ``first``: the latest boot is taken, or with ``earliest_boot`` the earliest
    (the run before a reset, where the run after it sent the same sample number)."""
    # the boots (random ids) that sent ``first`` intact, in the order they sent it
    sent_first = list(dict.fromkeys(b for b, sample, _, intact in log.written
                                    if sample == first and intact))
    boot = sent_first[0] if earliest_boot else sent_first[-1]
    start = max(s for b, s in log.run_starts if b == boot and s <= first)
    out = []
    for b, sample, state, intact in log.written:
        if b != boot or sample < start or not intact:
            continue
        out.append(sample)
        if state not in (p.State.RUNNING, p.State.STOPPING):
            break
    return out
