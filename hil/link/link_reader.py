"""The telemetry side of a :class:`hil.link.serial_link.SerialLink` session
(docs/rig-protocol-behaviour.md, sections 7, 10 and 11).

A reader thread decodes the frames, sends the heartbeats, checks each sample (boot id,
order, the MCU's clock, new faults), queues it for :meth:`LinkReader.next_sample`, hands
replies to the commands waiting for them, and watches the silence of the telemetry: a
silent MCU is asked with a HELLO whether it reset. The first failure is recorded, stops the
rig, and is raised to the consumer after every sample received before it.

:class:`LinkReader` is one part of SerialLink (a mixin, not used alone): it works on the
session's state that ``SerialLink.__init__`` sets.
"""

from __future__ import annotations

import contextlib
import dataclasses
import queue
import random
import select
import time

import serial

from hil.link import protocol as p
from hil.link.errors import (
    LinkLostError,
    LinkTimeoutError,
    RigError,
    RigFaultError,
    RigResetError,
    RigStalledError,
)
from hil.link.realtime import set_realtime
from hil.link.telemetry_watch import sample_distance


class LinkReader:
    """The reader thread and the telemetry queue; see the module's docstring."""

    def next_sample(self, timeout: float = 1.0) -> p.Telemetry:
        """The next telemetry sample; raises the link's failure once the samples before it
        are consumed, or LinkTimeoutError if none arrives within ``timeout``."""
        while True:
            try:
                item = self._queue.get(timeout=timeout)
            except queue.Empty:
                if self._failure is not None:
                    raise self._failure from None
                raise LinkTimeoutError(f"no telemetry for {timeout} s") from None
            if item is not None:
                return item
            if self._failure is not None:
                raise self._failure

    def drain(self) -> list[p.Telemetry]:
        """All samples queued now, without waiting or raising."""
        out = []
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return out
            if item is not None:
                out.append(item)

    @property
    def failure(self) -> RigError | None:
        """The failure that ended the session, if any."""
        return self._failure

    # --- reader thread --------------------------------------------------------------------

    def _read_loop(self) -> None:
        if self.realtime:
            set_realtime()
        next_heartbeat = time.monotonic()
        while not self._closing.is_set():
            now = time.monotonic()
            heartbeat_due = next_heartbeat if self.info and self.heartbeat_period else now + 1
            wait = max(0.0, min(min(heartbeat_due, self._watchdog_deadline()) - now, 0.05))
            try:
                data = self._read(wait)
            except (serial.SerialException, OSError) as exc:
                self._fail(LinkLostError(f"{self.url} disconnected: {exc}"))
                return
            before, now = now, time.monotonic()
            if self._silence.woke(wait, before, now):
                # the reader was not running (a loaded or paused machine): the silence
                # watchdog counts only time in which the host could have seen telemetry,
                # so its count restarts now (section 7)
                self.stats.host_late += 1
            for frame in self.decoder.feed(data):
                self._dispatch(frame, now)
            if self.info and self.heartbeat_period and now >= next_heartbeat:
                next_heartbeat = now + self.heartbeat_period
                self._send_quietly(p.Heartbeat(int(now * 1e3) & 0xFFFFFFFF))
            if now >= self._watchdog_deadline() and not self._pending_input():
                if self._reset_probe is None:
                    self._probe_for_reset(now)
                    continue
                self._fail(self._silence_error(now))

    def _silence_error(self, now: float) -> LinkTimeoutError:
        silence = now - self.stats.last_telemetry_rx
        counted = now - self._silence.since
        since_late = (f", {counted * 1e3:.1f} ms of it since the host was late"
                      if silence - counted > 1e-3 else "")
        return LinkTimeoutError(
            f"no telemetry for {silence * 1e3:.1f} ms{since_late} (watchdog "
            f"{self.telemetry_timeout * 1e3:.1f} ms): rig stalled or link broken")

    def _probe_for_reset(self, now: float) -> None:
        """The telemetry fell silent: an MCU that reset has no session and sends none
        (docs/rig-protocol.md, section 5; docs/rig-protocol-behaviour.md, section 10), so ask
        it with a HELLO, answered within an ACK timeout. A new boot id is
        :class:`RigResetError`, the same one (a stall: the HELLO may have taken the session
        over) or none the watchdog's :class:`LinkTimeoutError`, as before the probe."""
        seq, nonce = self._next_seq(), random.getrandbits(32)
        self._reset_probe = (seq, nonce)
        self._silence.since = now + self.ack_timeout - self._silence.timeout
        with contextlib.suppress(LinkLostError):
            self._write(p.encode_message(p.Hello(host_nonce=nonce), seq, p.FLAG_ACK_REQ))

    def _read(self, timeout: float) -> bytes:
        ser = self._ser
        if self._fd is not None:
            readable, _, _ = select.select([self._fd], [], [], timeout)
            return ser.read(ser.in_waiting or 1) if readable else b""
        waiting = ser.in_waiting
        if not waiting:
            time.sleep(min(timeout, 5e-4))
            waiting = ser.in_waiting
        return ser.read(waiting) if waiting else b""

    def _pending_input(self) -> bool:
        try:
            return bool(self._ser.in_waiting)
        except (serial.SerialException, OSError, AttributeError):
            return False

    def _watchdog_deadline(self) -> float:
        if self.info is None or self._failure is not None:
            return float("inf")
        return self._silence.deadline

    def _dispatch(self, frame: p.Frame, now: float) -> None:
        try:
            msg = p.parse_message(frame)
        except p.MessageError:
            self.stats.bad_messages += 1
            return
        if isinstance(msg, p.Telemetry):
            self._on_telemetry(dataclasses.replace(msg, rx_time=now), now)
        elif (isinstance(msg, p.HelloReply) and self._reset_probe is not None
              and (msg.acked_seq, msg.host_nonce) == self._reset_probe):
            if self.info is not None and msg.boot_id != self.info.boot_id:
                self._send_quietly(p.Bye())  # the probe's session: none is left open
                self._fail(RigResetError(
                    f"MCU reset detected mid-session: boot id changed from "
                    f"{self.info.boot_id:#010x} to {msg.boot_id:#010x} after sample "
                    f"{self._last_sample} (its telemetry stopped: no session after a "
                    f"reset); the rig's position reference is lost, re-home and open a new "
                    f"session"))
            else:
                self._fail(self._silence_error(now))
        elif isinstance(msg, (p.Ack, p.HelloReply, p.CalibrationReply)):
            pending = self._pending.get(msg.acked_seq)
            if pending is not None and pending.reply is None:
                pending.reply = msg
                pending.event.set()
        elif isinstance(msg, p.FaultReport):
            self.fault_reports.append(msg)
            new = msg.fault & ~self._known_faults
            if self.info is not None and new and self._fault_is_new(msg.sample):
                self._fail(RigFaultError(
                    f"rig fault {p.Fault(msg.fault).name} at sample {msg.sample}: value "
                    f"{msg.value}, limit {msg.limit} (MCU state {p.State(msg.state).name})",
                    p.Fault(msg.fault)))
        elif isinstance(msg, p.StateChange):
            self.state_changes.append(msg)

    def _on_telemetry(self, tel: p.Telemetry, now: float) -> None:
        if self.info is None:
            return  # before the handshake: stale or foreign samples
        if tel.boot_id != self.info.boot_id:
            self._fail(RigResetError(
                f"MCU reset detected mid-session: boot id changed from "
                f"{self.info.boot_id:#010x} to {tel.boot_id:#010x} after sample "
                f"{self._last_sample}; the rig's position reference is lost, re-home and "
                f"open a new session"))
            return
        stats, stalled = self.stats, None
        if self._last_sample is not None:
            distance = sample_distance(tel.sample, self._last_sample)
            if distance <= 0:
                stats.duplicates += 1  # a repeated (or reordered) frame: recorded once
                return
            stats.lost_samples += distance - 1
            elapsed = ((tel.t_us - self._last_t_us) & 0xFFFFFFFF) * 1e-6
            excess = elapsed - distance / self.info.telemetry_hz
            stats.max_clock_excess = max(stats.max_clock_excess, excess)
            if excess > self.clock_slack:
                stalled = RigStalledError(
                    f"rig stalled: the MCU's clock jumped {elapsed * 1e3:.1f} ms between "
                    f"samples {self._last_sample} and {tel.sample} (expected "
                    f"{distance * 1e3 / self.info.telemetry_hz:.0f} ms): its firmware missed "
                    f"periods")
            stats.record_gap(now - stats.last_telemetry_rx)
        self._last_sample, self._last_t_us = tel.sample, tel.t_us
        stats.samples += 1
        stats.last_telemetry_rx = now
        self._silence.restart(now)
        self.status = tel
        try:
            self._queue.put_nowait(tel)
        except queue.Full:
            stats.queue_dropped += 1
        new = tel.faults & ~self._known_faults
        if new and self._fault_is_new(tel.sample):
            faults = p.Fault(tel.faults)
            self._fail(RigFaultError(f"rig fault {faults.name} (state {p.State(tel.state).name}) "
                                     f"at sample {tel.sample}", faults))
        if stalled is not None:
            self._fail(stalled)

    def _fault_is_new(self, sample: int) -> bool:
        """A fault reported at ``sample`` is not one that clear_fault already handled."""
        return self._faults_from is None or sample_distance(sample, self._faults_from) >= 0

    def _fail(self, error: RigError) -> None:
        """Record the first failure, stop the rig unless the link is gone, wake consumers.

        The STOP is the first attempt of the stop sequence (if a START armed it), written at
        once; :meth:`stop_quietly` completes the sequence.
        """
        if self._failure is not None:
            return
        self._failure = error
        self.stats.failed_at = time.monotonic()
        if not isinstance(error, LinkLostError) and self.info is not None:
            self._begin_stop()
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait(None)

    def _send_quietly(self, msg: p.Message, *, ack: bool = False) -> None:
        """Send without waiting (the reader cannot wait for its own ACKs)."""
        with contextlib.suppress(LinkLostError):
            self._write(p.encode_message(msg, self._next_seq(), p.FLAG_ACK_REQ if ack else 0))
