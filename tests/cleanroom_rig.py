"""Clean-room MCU of the clamp test rig, written from docs/rig-protocol.md and
docs/rig-protocol-behaviour.md (v1.1) alone.

None of the project's protocol, host or emulator code was read or imported to write
this: COBS, CRC-16/CCITT-FALSE, the message layouts, the state machine, the safety
checks, the trajectory buffer, duplicate/STALE handling, the heartbeat watchdog,
telemetry at 1 kHz and the home switch are all implemented here from the document.
The only project code used is the mechanics (`hil.emulators.rig_physics.ClampPhysics`), the
open position of the stroke (`hil.host.backends.RigSetup().stroke[0]`) and SCHED_FIFO
scheduling for the serving process (`hil.link.realtime.set_realtime`).

Readings taken where the document leaves a choice (see the clean-room report):

* the sample of period i shows point i reached (steps = point i, exec_index = i + 1) and
  compares enc with point i's enc_expected; the period that executes the last point
  (FINAL) already reports IDLE, so a complete run of N points is N samples;
* CONFIG with load_gain_n = 0 keeps the stored offset too (its load_offset is ignored);
* a HELLO resets the stored seq whatever its result; ESTOP re-bases it only if newer;
  BAD_LENGTH and UNKNOWN_TYPE answers do not touch the stored seq and reply;
* "present position" in TRAJ_CHUNK rule 7 applies to point 0 of the trajectory only;
* MOVING = steps changed in this period; DRIVER_ENABLED is off only in ESTOP;
* a controlled stop loses decel_steps_s2 * T^2 steps/period of speed each period, and
  the first period at zero speed is the standstill sample;
* conditions "still present" for CLEAR_FAULT: force, travel and ADC rail on the last
  reading; CLEAR_FAULT clears every bit, and is BAD_STATE in RUNNING and STOPPING;
* HEARTBEAT_LOST keeps the session open (until BYE; a new HELLO takes it over); a pty has no
  USB detach, so LINK_LOST is never sent;
* stored calibration: load_offset 1500 counts, load_gain_n 1e-4 N/count (section 12) until
  a STORE_CALIBRATION (1.3, section 5 "The stored calibration"), whose records live in a
  dict standing for the non-volatile memory (it survives the Mcu's reset()).

The clean room is four modules: tests/cleanroom_wire.py (the document's constants, message
layouts, COBS and CRC), tests/cleanroom_commands.py (receiving frames and the host's
commands), tests/cleanroom_mcu.py (`Mcu`, the firmware logic without I/O: bytes in, frames
out, one `tick` per period) and this one: `serve` runs an `Mcu` on a pseudo-terminal with a
1 ms tick loop, and `CleanroomRig` starts `serve` in a separate (spawned) process and talks
to it over a pipe.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import select
import time
import tty
from collections import deque
from multiprocessing.connection import Connection
from typing import Any

from cleanroom_commands import Run
from cleanroom_mcu import Mcu
from cleanroom_wire import PERIOD_S, STATE_NAMES


def serve(conn: Connection, x_open: float, noise_n: float = 0.2, future: bool = False) -> None:
    """Child-process main: run an Mcu on a pty with a 1 ms tick loop until told to quit."""
    from hil.emulators.rig_physics import ClampPhysics
    from hil.link.realtime import set_realtime

    # an MCU is real time: SCHED_FIFO where allowed (a nice level alone left it starved
    # past the host's HELLO retries on a loaded machine), else a higher priority
    if not set_realtime():
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, -10)
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    physics = ClampPhysics("chang2021", 0.0)
    # the plant is built now, at rest at the open position, not in the first period (a
    # real MCU's first period is as short as the others): on a loaded machine the build
    # took 170 ms of that period, and the host's first HELLO went unanswered (6 x 20 ms)
    physics(x_open, 0.0)
    mcu = Mcu(physics, x_open, noise_n=noise_n, future=future)
    pending: deque[bytes] = deque()
    conn.send(os.ttyname(slave))
    t0 = time.monotonic()
    mcu.last_rx = t0
    k = 0
    next_poll = t0
    try:
        while True:
            deadline = t0 + k * PERIOD_S
            wait = max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([master], [], [], wait)
            if ready:
                try:
                    data = os.read(master, 4096)
                except OSError:
                    data = b""
                if data:
                    mcu.receive(data, time.monotonic())
            now = time.monotonic()
            late_us = int((now - (t0 + k * PERIOD_S)) * 1e6)
            if late_us > mcu.stats.get("max_late_us", 0):
                mcu.stats["max_late_us"] = late_us
            while t0 + k * PERIOD_S <= now:
                mcu.tick(t0 + k * PERIOD_S)
                k += 1
            pending.extend(mcu.out)
            mcu.out.clear()
            lost = _flush(master, pending, 5000 if mcu.session else 64)
            if lost:
                mcu.stats["tx_dropped"] = mcu.stats.get("tx_dropped", 0) + lost
                if mcu.session:
                    mcu.stats["tx_dropped_in_session"] = (
                        mcu.stats.get("tx_dropped_in_session", 0) + lost)
            if now >= next_poll:
                next_poll = now + 0.005
                if conn.poll():
                    req = conn.recv()
                    if req == "quit":
                        break
                    conn.send(_answer(mcu, req))
    finally:
        os.close(master)
        os.close(slave)


def _flush(fd: int, pending: deque[bytes], keep: int) -> int:
    """Write queued frames; keep at most `keep` unwritten (the oldest go); return the drops."""
    while pending:
        try:
            n = os.write(fd, pending[0])
        except OSError:
            break
        if n < len(pending[0]):
            pending[0] = pending[0][n:]
            break
        pending.popleft()
    dropped = 0
    while len(pending) > max(keep, 1):
        del pending[1]  # the head may be partly written: never cut a frame
        dropped += 1
    return dropped


def _answer(mcu: Mcu, req: str) -> Any:
    if req == "runs":
        return list(mcu.runs)
    if req == "stats":
        return {"sample": mcu.sample, "state": STATE_NAMES[mcu.state], "faults": mcu.faults,
                "session": mcu.session, "steps": mcu.steps, "enc": mcu.enc,
                "referenced": mcu.referenced, **mcu.stats}
    if req == "log":
        return list(mcu.log)
    return None


class CleanroomRig:
    """Handle to a clean-room MCU served on a pty in a spawned process."""

    def __init__(self, noise_n: float = 0.2, future: bool = False) -> None:
        from hil.host.backends import RigSetup

        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=serve, args=(child, RigSetup().stroke[0], noise_n, future),
                                 daemon=True, name="cleanroom-rig")
        self._proc.start()
        child.close()
        if not self._conn.poll(60):
            self._proc.kill()
            raise RuntimeError("clean-room rig did not start")
        self.port: str = self._conn.recv()

    def _ask(self, req: str) -> Any:
        self._conn.send(req)
        if not self._conn.poll(5):
            raise RuntimeError(f"clean-room rig did not answer {req!r}")
        return self._conn.recv()

    def runs(self) -> list[Run]:
        """Every run (START to the first sample at standstill) so far."""
        return self._ask("runs")

    def stats(self) -> dict[str, Any]:
        """Present state and counters of the MCU."""
        return self._ask("stats")

    def log(self) -> list[tuple[Any, ...]]:
        """The last frames received and replies sent, oldest first."""
        return self._ask("log")

    def close(self) -> None:
        """Stop the rig process."""
        if self._proc.is_alive():
            with contextlib.suppress(OSError):
                self._conn.send("quit")
            self._proc.join(5)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(5)
        self._conn.close()

    def __enter__(self) -> CleanroomRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
