"""The stop that ends a session (docs/rig-protocol-behaviour.md, section 6), and what follows it.

The stop sequence goes out once per START: STOP, STOP_ATTEMPTS attempts with one seq, then
ESTOP if no STOP was acknowledged; later calls return its outcome without sending more.
After it the host waits for the standstill (the stop ramp plus STANDSTILL_MARGIN), clears
the faults the session latched, says BYE, and hands back the rest of a run that ended early.

:class:`LinkStop` is one part of :class:`hil.link.serial_link.SerialLink` (a mixin, not used
alone): it works on the session's state that ``SerialLink.__init__`` sets and sends through
:class:`hil.link.link_commands.LinkCommands`.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time

from hil.link import protocol as p
from hil.link.errors import LinkLostError, RigResetError
from hil.link.link_commands import LATE_RETRIES, Pending
from hil.link.telemetry_watch import HOST_LATE, sample_distance

#: Attempts of the STOP that ends a session before the host escalates to ESTOP (section 6).
STOP_ATTEMPTS = 3
#: Longest wait for the rig to reach a standstill after a stop, beyond the stop ramp, s.
STANDSTILL_MARGIN = 1.0
#: States in which the table may still move.
MOVING_STATES = (p.State.RUNNING, p.State.STOPPING)


class StopSequence:
    """The stop that ends a session (section 6): STOP, STOP_ATTEMPTS attempts with one
    seq, then ESTOP if no STOP was acknowledged. Sent once; a new START arms another."""

    def __init__(self, seq: int) -> None:
        self.seq = seq
        self.pending = Pending()
        self.sent_at: float | None = None  # the first attempt (None: not written yet)
        self.lock = threading.Lock()  # one thread completes the sequence
        self.acked: bool | None = None  # the outcome once complete: STOP acknowledged


class LinkStop:
    """The stop sequence and the end of a session; see the module's docstring."""

    def stop_quietly(self) -> bool:
        """The stop sequence, once per START; never raises (for cleanup paths).

        STOP (STOP_ATTEMPTS attempts with one seq, ``ack_timeout`` each; attempts during
        which the host ran late are repeated uncounted), then ESTOP if no STOP was
        acknowledged. It goes out once: later calls, from the run, the back-end and
        :meth:`close`, return its outcome without sending anything until a new START.
        True when the rig acknowledged the STOP (it answers commands); also True when
        nothing was started in this session.
        """
        if isinstance(self._failure, LinkLostError) or self._ser is None:
            return False
        stop = self._begin_stop()
        if stop is None:
            return True  # nothing started in this session: nothing to stop
        with stop.lock:
            if stop.acked is None:
                stop.acked = self._complete_stop(stop)
        return stop.acked

    def _arm_stop(self, unless_begun_after: float | None = None) -> None:
        """The next stop sends the stop sequence (unless one began after the given time)."""
        with self._stop_lock:
            last = self._stop_seq
            if (unless_begun_after is None or last is None
                    or last.sent_at < unless_begun_after):
                self._stop_armed = True

    def _begin_stop(self) -> StopSequence | None:
        """The stop sequence: begun now (its first STOP written, without waiting) if armed,
        else the last one; None if none was ever armed. Any thread (the reader's _fail)."""
        with self._stop_lock:
            if not self._stop_armed:
                return self._stop_seq
            self._stop_armed = False
            stop = self._stop_seq = StopSequence(self._next_seq())
            self._pending[stop.seq] = stop.pending
            stop.sent_at = self.stats.stop_sent_at = time.monotonic()
        with contextlib.suppress(LinkLostError):
            self._write(p.encode_message(p.Stop(), stop.seq, p.FLAG_ACK_REQ))
        return stop

    def _complete_stop(self, stop: StopSequence) -> bool:
        """Wait for the STOP's ACK, retransmit, escalate to ESTOP; True if STOP was acked."""
        attempts, late, sent = 1, 0, stop.sent_at
        try:
            while True:
                asked_at = time.monotonic()
                asked = max(0.0, sent + self.ack_timeout - asked_at)
                if stop.pending.event.wait(asked):
                    return True
                if isinstance(self._failure, LinkLostError):
                    return False
                if time.monotonic() - asked_at > asked + HOST_LATE and late < LATE_RETRIES:
                    late += 1  # the host was not running: this attempt is repeated, uncounted
                    self.stats.late_attempts += 1
                elif attempts >= STOP_ATTEMPTS:
                    break
                else:
                    attempts += 1
                try:
                    self._write(p.encode_message(p.Stop(), stop.seq,
                                                 p.FLAG_ACK_REQ | p.FLAG_RETRY))
                except LinkLostError:
                    return False
                sent = time.monotonic()
                self.stats.retransmissions += 1
        finally:
            self._pending.pop(stop.seq, None)
        # no STOP answered: ESTOP, and no more waiting for this rig (section 6: its
        # heartbeat watchdog stops it on its side); samples still arriving are still read
        self._unresponsive = True
        self.estop(wait=False)
        return False

    def wait_standstill(self, timeout: float | None = None) -> p.Telemetry | None:
        """Wait until a sample shows the rig outside RUNNING/STOPPING; that sample or None.

        Samples of a run in progress stay queued for :meth:`finish_run`.
        """
        deadline = time.monotonic() + (self._stop_time() if timeout is None else timeout)
        while time.monotonic() < deadline:
            status = self.status
            if status is not None and status.state not in MOVING_STATES and (
                    self._run_first is None
                    or sample_distance(status.sample, self._run_first) >= 0):
                return status
            if self._gone():
                return None
            time.sleep(0.002)
        return None

    def _gone(self) -> bool:
        """Nothing more to wait for in this session: the port failed, the MCU reset, or the
        rig acknowledged no STOP of the stop sequence."""
        return self._unresponsive or isinstance(self._failure, (LinkLostError, RigResetError))

    def _stop_time(self) -> float:
        """Longest stop ramp at the configured deceleration plus STANDSTILL_MARGIN, s of the
        wall clock (longer when the MCU's clock runs slow)."""
        cfg = self.config
        v = cfg.max_step_delta * (self.info.telemetry_hz if self.info else 1000)
        return (v / cfg.decel_steps_s2 + STANDSTILL_MARGIN) / self._clock_rate

    def _end_session(self) -> None:
        """After a stop: wait for the standstill, clear this session's faults, BYE."""
        status = self.wait_standstill()
        if status is None:
            return  # still moving or silent: the MCU's heartbeat watchdog ends it
        faults = p.Fault(status.faults)
        if (faults and self.clear_faults_on_close and not self.faults_at_open
                and not faults & p.Fault.ESTOP):
            # the halt itself can hold (or re-latch) the condition for a few periods: clear
            # until a sample taken after the clear shows no fault
            deadline = time.monotonic() + STANDSTILL_MARGIN
            while time.monotonic() < deadline and not self._cleared():
                time.sleep(0.02)
        self.command(p.Bye(), check=False)

    def _cleared(self) -> bool:
        """CLEAR_FAULT, then True once a later sample shows no latched fault."""
        ack = self.command(p.ClearFault(), check=False)
        if ack.result != p.Result.OK:
            return False
        deadline = time.monotonic() + 0.05 / self._clock_rate
        while time.monotonic() < deadline:
            status = self.status
            if status is not None and sample_distance(status.sample, ack.sample) > 0:
                return not status.faults
            time.sleep(0.002)
        return False

    def finish_run(self) -> list[p.Telemetry]:
        """The rest of a run that ended early: every sample of it queued or still arriving,
        up to and including the first one at standstill (the fault sample included).

        Call after :meth:`run_trajectory` raised; never raises. Empty after a complete run.
        """
        first, self._run_first = self._run_first, None
        if first is None:
            return []
        out: list[p.Telemetry] = []
        deadline = time.monotonic() + self._stop_time()
        while True:
            try:  # a rig that is gone sends no more: take what is queued, do not wait
                item = (self._queue.get_nowait() if self._gone()
                        else self._queue.get(timeout=0.02))
            except queue.Empty:
                if self._gone() or time.monotonic() > deadline or self._ser is None:
                    return out
                continue
            if item is None or sample_distance(item.sample, first) < 0:
                continue
            out.append(item)
            if item.state not in MOVING_STATES:
                return out

