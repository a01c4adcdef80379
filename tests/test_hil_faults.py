"""Fault matrix of ``hil run --real`` against the emulated rig, driven as a user drives it.

For every fault: the exit code is non-zero, stderr names the cause, samples.csv holds
exactly the samples the emulator wrote intact from the run's START to its standstill
(counted by the emulator), and the rig is reusable: the next run on the same emulator
succeeds (after the operator's ``hil rig clear`` where the fault demands one: ESTOP).
"""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import signal
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from hil_host import (
    SHORT_RUN,
    X_OPEN,
    Host,
    hil,
    recorded_samples,
    sent_samples,
    spawn,
)

from controllers.profiles import ProfileSamples, s_curve, write_profile_csv
from hil.emulators.rig_emulator import FaultPlan
from hil.link import protocol as p

pytestmark = pytest.mark.real_time

AT = 0.6  # s after the first START (the homing move) when a scheduled fault strikes


def signal_after(signum: int, delay: float = 0.8) -> Callable[[Host], None]:
    def act(host: Host) -> None:
        host.wait_for("run directory")
        time.sleep(delay)
        host.proc.send_signal(signum)
    return act


def freeze(host: Host) -> None:
    """The host process stops for 0.4 s (a swap storm, a debugger): its heartbeats stop."""
    host.wait_for("run directory")
    time.sleep(0.6)
    host.proc.send_signal(signal.SIGSTOP)
    time.sleep(0.4)
    host.proc.send_signal(signal.SIGCONT)


@dataclass(frozen=True)
class Case:
    cause: str  # regex that stderr must match
    faults: FaultPlan = field(default_factory=FaultPlan)
    action: Callable[[Host], None] | None = None
    code: int = 1
    clear_first: bool = False  # the fault needs the operator (`hil rig clear`) before reuse
    completes: bool = False  # link noise: the motion completes; the run fails on its data
    in_flight: int = 0  # samples the host may never read (written just before a hang-up)
    # timeouts fixed by hand where the case is timed against them (the host measures them
    # from the link otherwise, longer on a loaded machine: docs/rig-protocol-behaviour.md,
    # section 7)
    args: tuple[str, ...] = ()


NOISE = dict(seed=7, noise_until=2.0)
NOISY = dict(completes=True)
CASES = {
    "bad CRC": Case(r"bad frames", FaultPlan(flip_bit=0.01, **NOISE), **NOISY),
    "dropped bytes": Case(r"bad frames", FaultPlan(drop_byte=0.01, **NOISE), **NOISY),
    "dropped frames": Case(r"lost samples", FaultPlan(drop_frame=0.01, **NOISE), **NOISY),
    "duplicated frames": Case(r"duplicate samples", FaultPlan(duplicate=0.01, **NOISE), **NOISY),
    "junk": Case(r"bad frames", FaultPlan(junk=0.02, **NOISE), **NOISY),
    "stall": Case(r"rig stalled.*clock jumped", FaultPlan(stall_at=AT, stall_for=0.05)),
    # the rig answers no STOP for 0.4 s: the host escalates to ESTOP, which only the
    # operator clears, and closes without reading on: samples the rig wrote after the
    # host's last read are never read
    "long stall": Case(r"no telemetry for", FaultPlan(stall_at=AT, stall_for=0.4),
                       clear_first=True, in_flight=3,
                       args=("--watchdog-ms", "100", "--ack-ms", "20")),
    "heartbeat loss": Case(r"HEARTBEAT_LOST", action=freeze, args=("--heartbeat-ms", "250")),
    "MCU reset": Case(r"MCU reset detected", FaultPlan(reset_at=AT)),
    # a hang-up discards what is in flight in the pty: the last few written samples
    "disconnect": Case(r"disconnected", FaultPlan(disconnect_at=AT, reconnect_after=0.3),
                       in_flight=5),
    "e-stop": Case(r"ESTOP", FaultPlan(estop_at=AT), clear_first=True),
    "force limit": Case(r"FORCE_LIMIT", FaultPlan(force_spike_at=AT, force_spike_n=450.0)),
    # a transient encoder fault: the MCU then drops REFERENCED and the next run re-homes
    "following error": Case(r"FOLLOWING_ERROR",
                            FaultPlan(stuck_encoder_at=AT, stuck_for=0.2)),
    "Ctrl-C in motion": Case(r"interrupted by SIGINT", action=signal_after(signal.SIGINT),
                             code=130),
    "SIGTERM": Case(r"interrupted by SIGTERM", action=signal_after(signal.SIGTERM), code=143),
}


#: Every case runs on the firmware (on the model where gcc is missing: the firmware's host
#: build needs it, Debian package gcc); the sensor faults run on the model too. The MCU's
#: own reactions are compared on both in tests/test_mcu_conformance.py; the rest (link
#: noise, a stall, a reset, a disconnect, signals) test the host and the emulator.
ON_BOTH = ("force limit", "following error")  # the heartbeat and ESTOP: conformance suite
HAVE_GCC = shutil.which("gcc") is not None
MATRIX = [(name, "firmware" if HAVE_GCC else "model") for name in CASES] + [
    (name, "model") for name in ON_BOTH if HAVE_GCC]


@pytest.mark.parametrize(("name", "mcu"), MATRIX)
def test_fault_stops_records_exactly_and_leaves_the_rig_reusable(name: str, mcu: str,
                                                                 tmp_path) -> None:
    """The fault matrix on the C firmware, and the MCU's own faults on the Python model
    too: the same expectations."""
    case = CASES[name]
    out = tmp_path / "run"
    with spawn(case.faults, firmware=mcu == "firmware") as emu:
        host = Host("run", "--real", "--port", emu.port, "--out", str(out), *SHORT_RUN,
                    *case.args)
        if case.action is not None:
            case.action(host)
        code, stdout, stderr = host.finish()
        assert code == case.code, stderr
        assert re.search(case.cause, stderr), stderr
        assert "Traceback" not in stderr
        assert "cycles complete" in stdout  # the summary of what was measured is printed
        time.sleep(0.4)  # a re-plugged port appears 0.3 s after the disconnect
        if case.clear_first:
            refused = out.parent / "refused"
            code, _, stderr = hil("run", "--real", "--port", emu.port, "--out", str(refused),
                                  *SHORT_RUN)
            assert code == 1 and "hil rig clear" in stderr and "ESTOP" in stderr
            assert not refused.exists()  # a refused run leaves no run directory
            assert hil("rig", "clear", "--port", emu.port)[0] == 0
        again = out.parent / "again"
        code, _, stderr = hil("run", "--real", "--port", emu.port, "--out", str(again),
                              *SHORT_RUN)
        assert code == 0, stderr
        assert json.loads((again / "summary.json").read_text())["cycles_complete"] == 1
    log = emu.log
    meta = json.loads((out / "meta.json").read_text())
    assert meta["aborted"] is not case.completes and (out / "summary.json").is_file()
    assert case.completes or re.search(case.cause, meta["abort_reason"])
    rows = recorded_samples(out)
    sent = sent_samples(log, rows[0], earliest_boot=True)  # "again" may follow a reset
    assert rows == sent[: len(rows)] and len(sent) - len(rows) <= case.in_flight
    assert recorded_samples(again) == sent_samples(log, recorded_samples(again)[0])
    # a complete run's last sample (IDLE, every point executed) is no "stopping" sample
    assert (again / "samples.csv").read_text().splitlines()[-1].split(",")[4] == "ok"


def test_ctrl_c_while_planning_moves_nothing(tmp_path) -> None:
    with spawn() as emu:
        host = Host("run", "--real", "--port", emu.port, "--out", str(tmp_path / "run"),
                    "--quiet")  # the default job: plans first
        host.wait_for("planning")
        host.proc.send_signal(signal.SIGINT)
        code, _, stderr = host.finish()
        assert code == 130 and "SIGINT" in stderr and "nothing was recorded" in stderr
        assert not (tmp_path / "run").exists()
    assert emu.log.run_starts == []  # the rig never moved


def test_a_swallowed_ctrl_c_during_planning_is_still_acted_on(monkeypatch, tmp_path,
                                                             swallowed_sigint) -> None:
    """IPOPT catches KeyboardInterrupt and returns as failed: the guard remembers it, also
    when the failed solve failed the plan (which was reported as 'duration 3.1 s is too
    short', exit 1)."""
    from controllers.plans import PlanningError
    from hil.cli.interrupts import Interrupted
    from hil.cli.main import main
    from hil.host import experiment

    real = experiment.planned_trajectory

    def planned(*args, **kw):
        swallowed_sigint(Interrupted)  # hil's guard raises Interrupted
        return real(*args, **kw)

    def failed(*_args, **_kw):
        swallowed_sigint(Interrupted)
        raise PlanningError("duration 3.1 s is too short: the shortest feasible stroke takes "
                            "1.547 s")

    for name, plan in (("planned", planned), ("failed", failed)):
        monkeypatch.setattr(experiment, "planned_trajectory", plan)
        assert main(["run", "--out", str(tmp_path / name), "--quiet"]) == 130, name
        assert not (tmp_path / name).exists()


def _profile_with_hold(path: Path) -> Path:
    """A 10 mm S-curve in 1 s, then 3 s at rest: most of the run is zero-step periods."""
    move = s_curve(X_OPEN, X_OPEN + 10e-3, 1.0, 40e-3, 0.5)
    t = np.arange(0.0, 4.0, 1e-3)
    x, v, a = move.sample(np.minimum(t, move.duration))
    v, a = np.where(t < move.duration, v, 0.0), np.where(t < move.duration, a, 0.0)
    zero = np.zeros_like(t)
    return write_profile_csv(path, ProfileSamples(t, x, v, a, zero, zero))


ONE_MCU = "firmware" if HAVE_GCC else "model"  # both: tests/test_mcu_conformance.py


@pytest.mark.parametrize("mcu", [ONE_MCU])
def test_ctrl_c_in_a_hold_leaves_the_rig_reusable(mcu: str, tmp_path: Path) -> None:
    """A STOP in a period without steps: the model never ended such a stop (STOPPING for
    good; every later command BAD_STATE until the emulator restarted). The MCU's side of
    it, on both MCUs: tests/test_mcu_conformance.py."""
    profile = _profile_with_hold(tmp_path / "hold.csv")
    out = tmp_path / "run"
    with spawn(firmware=mcu == "firmware") as emu:
        host = Host("run", "--real", "--port", emu.port, "--profile", str(profile),
                    "--cycles", "1", "--quiet", "--out", str(out))
        host.wait_for("run directory")
        time.sleep(2.5)  # in the hold: the move took 1 s
        host.proc.send_signal(signal.SIGINT)
        code, _, stderr = host.finish()
        assert code == 130 and "Traceback" not in stderr, stderr
        again = tmp_path / "again"
        code, _, stderr = hil("run", "--real", "--port", emu.port, "--out", str(again),
                              *SHORT_RUN)
        assert code == 0, stderr
    with (out / "samples.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    held = {float(row["x_cmd [m]"]) for row in rows[-200:]}
    assert len(held) == 1 and held.pop() == pytest.approx(X_OPEN + 10e-3, abs=1e-6)
    assert len(rows) < 3500  # interrupted in the hold, and stopped there
    assert recorded_samples(out) == sent_samples(emu.log, recorded_samples(out)[0])


@pytest.mark.parametrize("mcu", [ONE_MCU])
def test_a_fault_left_by_a_dead_host_needs_rig_clear(mcu: str, tmp_path: Path) -> None:
    """The clean-room rig's case (tests/test_rig_cleanroom.py) on the firmware: a host that
    opened a session and vanished leaves HEARTBEAT_LOST, which `hil run` refuses to clear."""
    with spawn(firmware=mcu == "firmware") as emu:
        fd = os.open(emu.port, os.O_RDWR | os.O_NOCTTY)
        try:
            tty.setraw(fd)
            os.write(fd, p.encode_frame(p.Hello(1, 1, 42).frame(100, p.FLAG_ACK_REQ)))
            time.sleep(0.45)  # no heartbeats: the MCU's 250 ms watchdog trips
        finally:
            os.close(fd)
        code, stdout, stderr = hil("rig", "status", "--port", emu.port)
        assert code == 1 and "latched faults: HEARTBEAT_LOST" in stdout + stderr  # exit 1: a fault
        code, _, stderr = hil("run", "--real", "--port", emu.port, "--out",
                              str(tmp_path / "refused"), *SHORT_RUN)
        assert code == 1 and "HEARTBEAT_LOST" in stderr and "hil rig clear" in stderr, stderr
        assert not (tmp_path / "refused").exists()
        assert hil("rig", "clear", "--port", emu.port)[0] == 0
        code, _, stderr = hil("run", "--real", "--port", emu.port, "--out",
                              str(tmp_path / "again"), *SHORT_RUN)
        assert code == 0, stderr
