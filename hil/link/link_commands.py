"""Commands of a :class:`hil.link.serial_link.SerialLink` session (docs/rig-protocol.md,
section 5, docs/rig-protocol-behaviour.md, section 6): each sent with acknowledgement and
retransmission, the emergency stop sent at once, and a trajectory streamed in chunks with
flow control.

:class:`LinkCommands` is one part of SerialLink (a mixin, not used alone): it works on the
session's state that ``SerialLink.__init__`` sets (the port, the pending replies, the
failure) and calls the stop sequence (:mod:`hil.link.link_stop`) and the reader's
``_fail`` (:mod:`hil.link.link_reader`).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Iterator, Sequence

import serial

from hil.link import protocol as p
from hil.link.errors import CommandError, LinkLostError, RigError, RigFaultError
from hil.link.telemetry_watch import HOST_LATE, sample_distance

ESTOP_REPEATS = 3  # an emergency stop is sent this many times back to back
#: At most this many command attempts are repeated, uncounted, for host lateness.
LATE_RETRIES = 20

#: Commands that make the rig move: once the session has failed (its stop sequence has
#: begun) an unacknowledged one is not sent again.
MOTION_COMMANDS = frozenset({p.MsgType.TRAJ_CHUNK, p.MsgType.START})


class Pending:
    """A command waiting for its ACK."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.reply: p.Ack | p.HelloReply | p.CalibrationReply | None = None


class LinkCommands:
    """The commands of a session: send, acknowledge, retransmit; see the module's docstring."""

    def command(self, msg: p.Message, *, check: bool = True, retries: int | None = None,
                waits: Sequence[float] | None = None,
                ) -> p.Ack | p.HelloReply | p.CalibrationReply:
        """Send ``msg``, wait for its ACK, retransmit on timeout; CommandError on NAK.

        Each attempt waits ``ack_timeout`` (or the next of ``waits``, whose length then
        gives the attempts). An acknowledged command's round trip, from its first attempt,
        adjusts a measured ACK timeout (:class:`hil.link.timing.AckTimer`)."""
        retries = (self.retries if waits is None else len(waits) - 1) if retries is None \
            else retries
        with self._cmd_lock:
            seq = self._next_seq()
            pending = self._pending[seq] = Pending()
            try:
                attempt = late = 0
                began = time.monotonic()
                while True:
                    flags = p.FLAG_ACK_REQ | (p.FLAG_RETRY if attempt or late else 0)
                    self._write(p.encode_message(msg, seq, flags))
                    sent = time.monotonic()
                    wait = self.ack_timeout if waits is None else waits[min(attempt,
                                                                            len(waits) - 1)]
                    if pending.event.wait(wait):
                        if self._ack_timer is not None and not late:
                            self._ack_timer.add(time.monotonic() - began)
                            self.ack_timeout = self._ack_timer.timeout
                        break
                    if isinstance(self._failure, LinkLostError):
                        raise self._failure
                    if self._failure is not None and msg.TYPE in MOTION_COMMANDS:
                        # the session failed meanwhile: the command has failed too (its
                        # stop sequence, as below), and no motion is resent into it
                        self._arm_stop(unless_begun_after=began)
                        raise self._failure
                    self.stats.retransmissions += 1
                    if (time.monotonic() - sent > wait + HOST_LATE
                            and late < LATE_RETRIES):
                        late += 1  # the host itself was not running: not the rig's fault
                        self.stats.late_attempts += 1
                        continue
                    attempt += 1
                    if attempt > retries:
                        # the command has failed (section 6): the session ends with the
                        # stop sequence (an unacknowledged START may have started the rig),
                        # unless one began meanwhile (the telemetry watchdog's)
                        self._arm_stop(unless_begun_after=began)
                        raise CommandError(f"{msg.TYPE.name} not acknowledged after "
                                           f"{retries + 1} attempts")
            finally:
                del self._pending[seq]
        reply = pending.reply
        if check and reply.result != p.Result.OK:
            error = CommandError(f"{msg.TYPE.name} refused: {p.Result(reply.result).name} "
                                 f"(MCU state {p.State(reply.state).name})")
            if self._failure is not None:
                raise self._failure from error
            raise error
        return reply

    def configure(self, config: p.Config) -> None:
        """Send limits (and a calibration, if its gain is not 0) in IDLE; the scaling follows."""
        self.command(config)
        self.config = config
        if config.load_gain_n == 0:
            return
        self.scaling = dataclasses.replace(self.scaling, load_offset=config.load_offset,
                                           load_gain_n=config.load_gain_n)

    def send_chunk(self, first_index: int, points: Sequence[tuple[int, int]],
                   *, final: bool = False, check: bool = True) -> p.Ack:
        """Send one chunk of (steps, expected encoder counts) points."""
        flags = p.TrajChunk.FINAL if final else 0
        return self.command(p.TrajChunk(first_index, flags, tuple(points)), check=check)

    def start(self) -> p.Ack:
        """Start the buffered trajectory; the ACK's ``sample`` is the first sample of the run.

        Arms the stop sequence first: a START whose ACK is lost may still have started.
        """
        self._arm_stop()
        self._unresponsive = False  # a new run: wait for this rig again
        return self.command(p.Start())

    def stop(self) -> None:
        """Controlled stop (decelerate, discard the buffer)."""
        self.command(p.Stop())

    def clear_fault(self) -> None:
        """Leave FAULT/ESTOP; forget a RigFaultError failure."""
        ack = self.command(p.ClearFault())
        self._faults_from, self._known_faults = ack.sample, 0
        if isinstance(self._failure, RigFaultError):
            self._failure = None

    def set_position(self, steps: int, enc: int) -> None:
        """Redefine the present step and encoder counts (after homing)."""
        self.command(p.SetPosition(steps, enc))

    def estop(self, *, wait: bool = True) -> bool:
        """Emergency stop, sent at once even while another command waits; True if acked
        (within 3 ACK timeouts; ``wait`` False returns False at once, for a dead rig).

        The repeats reuse the seq and carry RETRY, so the MCU answers each but halts once.
        """
        seq = self._next_seq()
        pending = self._pending[seq] = Pending()
        try:
            for attempt in range(ESTOP_REPEATS):
                flags = p.FLAG_ACK_REQ | (p.FLAG_RETRY if attempt else 0)
                self._write(p.encode_message(p.EStop(), seq, flags))
            return wait and pending.event.wait(self.ack_timeout * 3)
        except LinkLostError:
            return False
        finally:
            self._pending.pop(seq, None)


    def run_trajectory(self, points: Sequence[tuple[int, int]]) -> Iterator[p.Telemetry]:
        """Stream ``points`` (steps, expected encoder counts; p.NO_CHECK skips the check),
        start them and yield every sample of the run until the MCU reports it complete.

        Flow control: points sent minus points executed (from telemetry) never exceeds
        the MCU's buffer. Any exception, including the consumer abandoning the
        generator, stops the rig before it propagates.
        """
        if not points:
            raise ValueError("a trajectory needs at least one point")
        capacity, size = self.info.buffer_capacity, self.info.max_chunk_points
        sent = 0
        self.drain()  # idle samples from before this run

        def top_up(executed: int) -> int:
            nonlocal sent
            while sent < len(points) and sent - executed + size <= capacity:
                chunk = points[sent : sent + size]
                ack = self.send_chunk(sent, chunk, final=sent + len(chunk) == len(points),
                                      check=False)
                if ack.result == p.Result.NO_SPACE:
                    break  # our estimate was optimistic; retry after the next sample
                if ack.result != p.Result.OK:
                    if self._failure is not None:
                        raise self._failure
                    raise CommandError(f"chunk at point {sent} refused: "
                                       f"{p.Result(ack.result).name}")
                sent += len(chunk)
            return sent

        try:
            top_up(0)
            first = self._run_first = self.start().sample
            while True:
                tel = self.next_sample(timeout=max(1.0, 10 * self.telemetry_timeout))
                if sample_distance(tel.sample, first) < 0:
                    continue  # the idle rig's, from before START
                yield tel
                if tel.state == p.State.IDLE and tel.exec_index >= len(points):
                    self._run_first = None  # complete: nothing left for finish_run
                    return
                if tel.state != p.State.RUNNING:
                    raise RigError(f"run ended early in state {p.State(tel.state).name} "
                                   f"after {tel.exec_index} of {len(points)} points")
                top_up(tel.exec_index)
        except BaseException:
            self.stop_quietly()
            raise

    def _next_seq(self) -> int:
        with self._write_lock:
            self._seq = (self._seq + 1) & 0xFFFF
            return self._seq

    def _write(self, data: bytes) -> None:
        ser = self._ser
        if ser is None:
            raise LinkLostError("port is closed")
        try:
            with self._write_lock:
                ser.write(data)
        except (serial.SerialException, OSError) as exc:
            # a port that refuses a write is gone (EIO: the cable pulled, the pty hung up),
            # said as the reader says it, whichever of the two meets the hang-up first
            lost = LinkLostError(f"{self.url} disconnected: {exc}")
            self._fail(lost)
            raise lost from exc

