"""Host side of the rig protocol over pyserial (docs/rig-protocol.md).

:class:`SerialLink` opens any pyserial URL (a device path, a pseudo-terminal,
``socket://host:port``, ``loop://``), runs a reader thread that decodes frames, sends
heartbeats and watches the telemetry, and offers commands with acknowledgement and
retransmission, the version handshake, streamed trajectories with flow control, a
telemetry queue, stop and emergency stop. Any failure (watchdog timeout, MCU stall,
disconnect, MCU reset, rig fault) is raised from the next :meth:`SerialLink.next_sample`
call, after every sample received before it; :meth:`SerialLink.finish_run` then returns
the rest of the run up to the standstill, and :meth:`SerialLink.close` ends the session
cleanly (docs/rig-protocol-behaviour.md, sections 7, 10 and 11).

This module holds the session's state, its opening (the handshake and the measurement of
the link) and its closing; the class's other parts are the reader thread and the
telemetry queue (:mod:`hil.link.link_reader`), the commands (:mod:`hil.link.link_commands`)
and the stop sequence (:mod:`hil.link.link_stop`). Its errors are in
:mod:`hil.link.errors`, the telemetry's bookkeeping in :mod:`hil.link.telemetry_watch`,
the units in :mod:`hil.link.scaling`.
"""

from __future__ import annotations

import contextlib
import queue
import random
import threading
import time
from collections.abc import Callable

import serial

from hil.link import protocol as p
from hil.link.errors import (
    CommandError,
    HandshakeError,
    LinkLostError,
    RigError,
    RigFaultError,
    RigResetError,
)
from hil.link.link_commands import LinkCommands, Pending
from hil.link.link_reader import LinkReader
from hil.link.link_stop import LinkStop, StopSequence
from hil.link.realtime import freeze_collections, raise_thread_priority
from hil.link.scaling import Scaling
from hil.link.telemetry_watch import LinkStats, SilenceWatchdog
from hil.link.timing import ACK_TIMEOUT_MAX, ACK_TIMEOUT_MIN, WATCHDOG_MAX, AckTimer, LinkTiming

#: The point period the host plans with, us: an MCU that runs another is refused at the
#: handshake (it would run the plan slower or faster than planned).
HOST_POINT_PERIOD_US = 1000
#: Host watchdog on telemetry arrival, s: a soft bound above the host's scheduling jitter
#: (measured on a loaded 2-core PC shared with other work, 20 soak runs: p99 3-6 ms, p99.9
#: 7-11 ms, longest gap 28-68 ms). The hard real-time stops are the MCU's
#: (docs/rig-protocol-behaviour.md, section 7).
DEFAULT_TELEMETRY_TIMEOUT = 0.1
#: Largest allowed excess of the MCU's own clock between two received samples over their
#: sample distance, s: a larger jump means the MCU missed periods (a stalled firmware).
DEFAULT_CLOCK_SLACK = 2e-3
#: Waits for the HELLO that opens a session, s: an emulated MCU on a loaded machine answers
#: in up to hundreds of ms (the timeouts are measured only once it answers), 1.6 s in all.
HANDSHAKE_WAITS = (ACK_TIMEOUT_MIN, 0.04, 0.08, 0.16, 0.32, ACK_TIMEOUT_MAX, ACK_TIMEOUT_MAX)
#: HELLO round trips measured at the start of a session (LinkTiming), each HELLO padded to
#: the payload of a full chunk (receivers ignore the extra bytes, section 2): an emulated
#: UART that takes one byte at a time (QEMU's) answers a long frame the later.
PROBE_ROUND_TRIPS = 5
PROBE_PAYLOAD = 6 + 8 * p.MAX_CHUNK_POINTS
#: Longest wait for a probe's answer, s.
PROBE_WAIT = ACK_TIMEOUT_MAX
#: Telemetry measured at the start of a session: at least this long (wall clock, s) and
#: this many samples, at most PROBE_LONGEST s.
PROBE_WINDOW, PROBE_SAMPLES, PROBE_LONGEST = 0.25, 20, 2.0


class SerialLink(LinkReader, LinkCommands, LinkStop):
    """A session with the rig's MCU; use as a context manager so the port always closes."""

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 921_600,
        ack_timeout: float | None = None,
        retries: int = 5,
        heartbeat_period: float | None = 0.02,
        telemetry_timeout: float | None = None,
        heartbeat_timeout_ms: int | None = None,
        clock_slack: float = DEFAULT_CLOCK_SLACK,
        queue_size: int = 100_000,
        realtime: bool = False,
        clear_faults_on_close: bool = True,
        point_period_us: int = HOST_POINT_PERIOD_US,
    ) -> None:
        """``ack_timeout`` (s), ``telemetry_timeout`` (s, the silence of the telemetry at the
        host) and ``heartbeat_timeout_ms`` (the MCU's watchdog, in the CONFIGs of
        :meth:`config_for`) are measured from the link when the session opens
        (:class:`hil.link.timing.LinkTiming`) unless given; ``clock_slack`` bounds the
        MCU-clock jump between received samples beyond their sample distance;
        ``heartbeat_period`` None sends no
        heartbeats (only to test the MCU's watchdog); ``realtime`` asks for SCHED_FIFO
        scheduling of the reader thread (best effort); ``clear_faults_on_close`` clears,
        at the end of the session, faults that latched during it (never ESTOP, never a
        fault found latched at open); ``point_period_us`` is the period the host plans
        with: an MCU that runs another is refused at the handshake."""
        self.url, self.baudrate = url, baudrate
        self.retries = retries
        self._ack_fixed = ack_timeout is not None
        self.ack_timeout = ack_timeout if ack_timeout is not None else ACK_TIMEOUT_MIN
        self._ack_timer: AckTimer | None = None  # follows the round trips once measured
        self._heartbeat_timeout_ms = heartbeat_timeout_ms
        self.timing: LinkTiming | None = None  # measured at open
        self.heartbeat_period = heartbeat_period
        self.realtime = realtime
        self._restore_priority: Callable[[], None] = lambda: None  # the session thread's nice
        self._unfreeze: Callable[[], None] = lambda: None  # the heap kept out of collections
        self.clock_slack = clock_slack
        self.clear_faults_on_close = clear_faults_on_close
        self.point_period_us = point_period_us
        self._telemetry_timeout = telemetry_timeout
        self._silence = SilenceWatchdog(self.telemetry_timeout)
        self._clock_rate = 1.0  # the MCU's clock against the host's, once measured
        self.stats = LinkStats()
        self.decoder = p.FrameDecoder()
        self.info: p.HelloReply | None = None
        self.scaling: Scaling | None = None
        self.fault_reports: list[p.FaultReport] = []
        self.state_changes: list[p.StateChange] = []
        self._queue: queue.Queue[p.Telemetry | None] = queue.Queue(queue_size)
        self._ser: serial.SerialBase | None = None
        self._fd: int | None = None
        self._reader: threading.Thread | None = None
        self._closing = threading.Event()
        self._write_lock = threading.Lock()
        self._cmd_lock = threading.Lock()
        self._seq = random.getrandbits(16)
        self._reset_probe: tuple[int, int] | None = None  # (seq, nonce) of the silence's HELLO
        self._pending: dict[int, Pending] = {}
        self._failure: RigError | None = None
        self._last_sample: int | None = None
        self._last_t_us: int | None = None
        self._faults_from: int | None = None  # fault bits before this sample are handled
        self.status: p.Telemetry | None = None  # the latest sample (any state)
        self.faults_at_open = p.Fault.NONE  # latched before this session
        self._known_faults = 0  # fault bits already reported (latched at open)
        self.config = p.Config()  # the MCU's limits: its defaults until configure()
        self._run_first: int | None = None  # first sample of the run in progress
        # the session end's stop sequence goes out once: armed by START (and by a command
        # that was never acknowledged), spent when sent, acknowledged or not
        self._stop_lock = threading.Lock()
        self._stop_armed = False
        self._stop_seq: StopSequence | None = None  # the last stop sequence
        self._unresponsive = False  # the stop sequence went unacknowledged: no more waiting

    # --- opening and closing --------------------------------------------------------------

    def open(self, config: p.Config | None = None) -> p.HelloReply:
        """Open the port, start the reader, handshake; send ``config`` if given."""
        try:
            self._ser = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkLostError(f"cannot open {self.url}: {exc}") from exc
        try:
            self._fd = self._ser.fileno()
        except (AttributeError, serial.SerialException, OSError):
            self._fd = None
        self._ser.reset_input_buffer()
        with contextlib.suppress(serial.SerialException, OSError):
            self._ser.write(b"\x00")  # resynchronise the MCU's receiver (section 2)
        if self._telemetry_timeout is None:
            self._silence.timeout = WATCHDOG_MAX  # until the link is measured
        if self.realtime:
            self._restore_priority = raise_thread_priority()
            self._unfreeze = freeze_collections()
        self._reader = threading.Thread(target=self._read_loop, name="rig-reader", daemon=True)
        self._reader.start()
        try:
            self._handshake()
            self.status = self._wait_status()
            self.faults_at_open = p.Fault(self.status.faults)
            self._known_faults = int(self.faults_at_open)
            self._measure_link()
            if config is not None:
                self.configure(config)
        except BaseException:
            self.close()
            raise
        return self.info

    def _wait_status(self, timeout: float = 1.0) -> p.Telemetry:
        """The first sample after the handshake: the rig's state, faults and position."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                item = self._queue.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise HandshakeError(f"no telemetry from {self.url} within {timeout} s "
                                     f"of the handshake") from None
            if item is not None:
                return item
            if self._failure is not None:
                raise self._failure

    def _handshake(self) -> None:
        nonce = random.getrandbits(32)
        deadline = time.monotonic() + 2.0
        while True:
            try:
                reply = self.command(p.Hello(p.PROTO_MAJOR, p.PROTO_MINOR, nonce), check=False,
                                     waits=None if self._ack_fixed else HANDSHAKE_WAITS)
            except CommandError as exc:
                raise HandshakeError(f"no answer to HELLO on {self.url}: {exc}") from exc
            if reply.result == p.Result.BAD_STATE and time.monotonic() < deadline:
                self.command(p.Stop(), check=False)  # a previous session left it moving
                time.sleep(0.05)
                continue
            break
        if not isinstance(reply, p.HelloReply) or reply.result != p.Result.OK:
            raise HandshakeError(
                f"rig refused the session: {p.Result(reply.result).name} (MCU protocol "
                f"{getattr(reply, 'proto_major', '?')}, host {p.PROTO_MAJOR})")
        if reply.host_nonce != nonce:
            raise HandshakeError("HELLO_REPLY echoes another session's nonce")
        refused = self._refusal(reply)
        if refused:
            with contextlib.suppress(RigError):  # end the MCU's session: no watchdog left armed
                self.command(p.Bye(), check=False, retries=1)
            raise HandshakeError(f"the host refuses the MCU on {self.url}: {refused}")
        self.scaling = Scaling(reply.step_nm / 1e9, reply.enc_nm / 1e9, reply.load_offset,
                               reply.load_gain_n, 1.0 / reply.telemetry_hz)
        self._last_sample = self._last_t_us = None
        self.stats.last_telemetry_rx = time.monotonic()
        self._silence.restart(self.stats.last_telemetry_rx)
        # what arrived before the session (a frame cut in two by opening the port mid-stream)
        # is not a link error of this session
        self.decoder.stats = p.DecoderStats()
        self.info = reply  # last: it arms the reader's watchdog and heartbeats

    def _refusal(self, reply: p.HelloReply) -> str:
        """Why the host cannot run this MCU's timing or buffer ('' when it can)."""
        period, hz = reply.point_period_us, reply.telemetry_hz
        if period != self.point_period_us:
            return (f"its point period is {period} us (point_period_us), the host plans with "
                    f"{self.point_period_us} us: the trajectory would run "
                    f"{period / self.point_period_us:g} times as long as planned")
        if hz * period != 1_000_000:
            return (f"its telemetry rate {hz} Hz (telemetry_hz) is not one sample per point "
                    f"period of {period} us (telemetry_hz x point_period_us = {hz * period}, "
                    f"not 1000000)")
        if not 1 <= reply.max_chunk_points <= p.MAX_CHUNK_POINTS:
            return (f"its max_chunk_points {reply.max_chunk_points} is outside 1.."
                    f"{p.MAX_CHUNK_POINTS}")
        if reply.buffer_capacity < reply.max_chunk_points:
            return (f"its buffer of {reply.buffer_capacity} points (buffer_capacity) holds "
                    f"less than one chunk of {reply.max_chunk_points} points")
        return ""

    @property
    def telemetry_timeout(self) -> float:
        """Host watchdog: longest allowed silence of the telemetry stream, s (as given, else
        as measured at open, else DEFAULT_TELEMETRY_TIMEOUT)."""
        if self._telemetry_timeout is not None:
            return self._telemetry_timeout
        if self.timing is not None:
            return self.timing.telemetry_timeout
        return DEFAULT_TELEMETRY_TIMEOUT

    @property
    def heartbeat_timeout_ms(self) -> int:
        """The MCU's heartbeat watchdog this session asks for, ms of the MCU's clock (as
        given, else as measured at open, else the protocol's 250 ms)."""
        if self._heartbeat_timeout_ms is not None:
            return self._heartbeat_timeout_ms
        if self.timing is not None:
            return self.timing.heartbeat_timeout_ms
        return p.Config().heartbeat_timeout_ms  # (the class attribute is a slot)

    def config_for(self, **limits: float) -> p.Config:
        """A CONFIG of ``limits`` (p.Config's fields) with this session's heartbeat timeout:
        every CONFIG of a session, homing's included, keeps the MCU's watchdog as measured
        (or given)."""
        return p.Config(**{"heartbeat_timeout_ms": self.heartbeat_timeout_ms, **limits})

    def _measure_link(self) -> None:
        """Measure the link (:class:`LinkTiming`) and take the timeouts not given from it:
        the telemetry that arrives until PROBE_WINDOW s and PROBE_SAMPLES samples are in,
        and meanwhile PROBE_ROUND_TRIPS more HELLOs spread over the window, each sent once
        (one without an answer within PROBE_WAIT counts as PROBE_WAIT; the HELLOs also keep
        the MCU's heartbeat watchdog fed, heartbeats or not), each as long as a full chunk
        (PROBE_PAYLOAD)."""
        trips: list[float] = []
        samples: list[p.Telemetry] = [self.status]
        began = time.monotonic()
        spacing = PROBE_WINDOW / PROBE_ROUND_TRIPS
        while True:
            now = time.monotonic()
            if len(trips) < PROBE_ROUND_TRIPS and now >= began + len(trips) * spacing:
                trip = self._round_trip(p.Hello(p.PROTO_MAJOR, p.PROTO_MINOR,
                                                random.getrandbits(32)), PROBE_WAIT)
                trips.append(PROBE_WAIT if trip is None else trip)  # at least that slow
                continue
            samples += self.drain()
            window = samples[-1].rx_time - samples[0].rx_time
            if ((window >= PROBE_WINDOW and len(samples) >= PROBE_SAMPLES
                 and len(trips) == PROBE_ROUND_TRIPS) or now - began > PROBE_LONGEST):
                break
            if self._failure is not None and not isinstance(self._failure, RigFaultError):
                raise self._failure  # (a fault latched at open is the caller's to judge)
            time.sleep(0.005)
        self.status = self.status if not samples else samples[-1]
        mcu = sum(((b.t_us - a.t_us) & 0xFFFFFFFF) * 1e-6 for a, b in zip(samples, samples[1:]))
        gaps = [b.rx_time - a.rx_time for a, b in zip(samples, samples[1:])]
        self.timing = timing = LinkTiming(tuple(trips), mcu / window if window > 0 else 1.0,
                                          max(gaps, default=0.0), window, len(samples))
        self._clock_rate = timing.rate
        if not self._ack_fixed:
            self.ack_timeout = timing.ack_timeout
            self._ack_timer = AckTimer(self.ack_timeout)
        self._silence.timeout = self.telemetry_timeout

    def _round_trip(self, msg: p.Message, wait: float) -> float | None:
        """Send ``msg`` once (a new seq), its payload padded to PROBE_PAYLOAD bytes, and
        wait up to ``wait`` s for its answer: the round trip, s, or None without one."""
        payload = msg.pack()
        payload += b"\x55" * max(0, PROBE_PAYLOAD - len(payload))
        with self._cmd_lock:
            seq = self._next_seq()
            pending = self._pending[seq] = Pending()
            try:
                self._write(p.encode_frame(p.Frame(msg.TYPE, p.FLAG_ACK_REQ, seq, payload)))
                sent = time.monotonic()
                answered = pending.event.wait(wait)
                trip = time.monotonic() - sent
            finally:
                del self._pending[seq]
        if not answered:
            return None
        reply = pending.reply
        if isinstance(reply, p.HelloReply) and reply.boot_id != self.info.boot_id:
            raise RigResetError(f"MCU reset during the handshake: boot id "
                                f"{self.info.boot_id:#010x}, then {reply.boot_id:#010x}")
        if reply.result != p.Result.OK:
            raise HandshakeError(f"rig refused a HELLO of the session's measurement: "
                                 f"{p.Result(reply.result).name}")
        return trip

    def close(self) -> None:
        """End the session cleanly and close the port; never raises, idempotent.

        STOP, wait for a standstill (the stop ramp plus STANDSTILL_MARGIN), clear the
        faults that latched during this session (when ``clear_faults_on_close``; never
        ESTOP), BYE, close. The stop sequence goes out once per START (section 6): a rig
        that does not answer gets STOP_ATTEMPTS STOPs and ESTOP_REPEATS ESTOPs once, then
        no more waiting, so leaving a dead rig takes about 3 ACK timeouts (60 ms).
        """
        if self._ser is None:
            return
        if self.info is not None and not isinstance(self._failure, LinkLostError):
            with contextlib.suppress(RigError):
                if self.stop_quietly():
                    self._end_session()
        self._closing.set()
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(timeout=1.0)
        with contextlib.suppress(serial.SerialException, OSError):
            self._ser.close()
        self._ser = None
        self.info = None
        self._restore_priority()
        self._restore_priority = lambda: None
        self._unfreeze()
        self._unfreeze = lambda: None

    def __enter__(self) -> SerialLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
