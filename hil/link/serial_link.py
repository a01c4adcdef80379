"""Host side of the rig protocol over pyserial (docs/rig-protocol.md).

:class:`SerialLink` opens any pyserial URL (a device path, a pseudo-terminal,
``socket://host:port``, ``loop://``), runs a reader thread that decodes frames, sends
heartbeats and watches the telemetry, and offers commands with acknowledgement and
retransmission, the version handshake, streamed trajectories with flow control, a
telemetry queue, stop and emergency stop. Any failure (watchdog timeout, MCU stall,
disconnect, MCU reset, rig fault) is raised from the next :meth:`SerialLink.next_sample`
call, after every sample received before it; :meth:`SerialLink.finish_run` then returns
the rest of the run up to the standstill, and :meth:`SerialLink.close` ends the session
cleanly (docs/rig-protocol.md, sections 7, 10 and 11).
"""

from __future__ import annotations

import contextlib
import dataclasses
import queue
import random
import select
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import serial

from hil.link import protocol as p
from hil.link.realtime import freeze_collections, raise_thread_priority, set_realtime
from hil.link.timing import ACK_TIMEOUT_MAX, ACK_TIMEOUT_MIN, WATCHDOG_MAX, AckTimer, LinkTiming

ESTOP_REPEATS = 3  # an emergency stop is sent this many times back to back
#: Attempts of the STOP that ends a session before the host escalates to ESTOP (section 6).
STOP_ATTEMPTS = 3
#: The point period the host plans with, us: an MCU that runs another is refused at the
#: handshake (it would run the plan slower or faster than planned).
HOST_POINT_PERIOD_US = 1000
#: Host watchdog on telemetry arrival, s: a soft bound above the host's scheduling jitter
#: (measured on a loaded 2-core PC shared with other work, 20 soak runs: p99 3-6 ms, p99.9
#: 7-11 ms, longest gap 28-68 ms). The hard real-time stops are the MCU's
#: (docs/rig-protocol.md, section 7).
DEFAULT_TELEMETRY_TIMEOUT = 0.1
#: Largest allowed excess of the MCU's own clock between two received samples over their
#: sample distance, s: a larger jump means the MCU missed periods (a stalled firmware).
DEFAULT_CLOCK_SLACK = 2e-3
#: A host thread that wakes this much later than it asked was itself not running (a loaded
#: or paused machine, s): that time is not counted against the rig.
HOST_LATE = 0.025
#: At most this many command attempts are repeated, uncounted, for host lateness.
LATE_RETRIES = 20
#: Longest wait for the rig to reach a standstill after a stop, beyond the stop ramp, s.
STANDSTILL_MARGIN = 1.0
#: States in which the table may still move.
MOVING_STATES = (p.State.RUNNING, p.State.STOPPING)
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


def sample_distance(sample: int, ref: int) -> int:
    """Signed distance from telemetry index ``ref`` to ``sample`` in RFC 1982 serial-number
    arithmetic on 32 bits: positive when ``sample`` is after ``ref``, also across the wrap
    of the u32 counter (2**32 - 1 -> 0, after 49.7 days of MCU uptime at 1 kHz).

    Exactly 2**31 apart is undefined in RFC 1982; it counts as before (negative).
    """
    d = (sample - ref) & 0xFFFFFFFF
    return d - 0x100000000 if d >= 0x80000000 else d


class SilenceWatchdog:
    """The host's telemetry-silence watchdog (docs/rig-protocol.md, section 7).

    It expires ``timeout`` s after its count started: at the last telemetry arrival
    (:meth:`restart`), or when the reader woke more than ``late`` s later than it asked
    (:meth:`woke`). Then the host itself was not running (a loaded or paused machine), so
    the silence it saw is not the rig's: the count restarts at that moment. ``clock`` is
    injectable for tests.
    """

    def __init__(self, timeout: float, clock: Callable[[], float] = time.monotonic,
                 late: float = HOST_LATE) -> None:
        self.timeout, self.clock, self.late = timeout, clock, late
        self.since = clock()  # start of the present count
        self.restarts = 0  # counts restarted by a late wake-up

    def restart(self, now: float | None = None) -> None:
        """Telemetry arrived (or a session opened): the count starts again."""
        self.since = self.clock() if now is None else now

    def woke(self, asked: float, before: float, now: float | None = None) -> bool:
        """The reader asked at ``before`` to wait ``asked`` s and woke at ``now``; True (and
        the count restarted at ``now``) if that was more than ``late`` s later than asked."""
        now = self.clock() if now is None else now
        if now - before <= asked + self.late:
            return False
        self.restarts += 1
        self.since = max(self.since, now)
        return True

    @property
    def deadline(self) -> float:
        """When the watchdog expires unless telemetry arrives, in ``clock`` time."""
        return self.since + self.timeout

    def expired(self, now: float | None = None) -> bool:
        return (self.clock() if now is None else now) >= self.deadline


class RigError(Exception):
    """Base of every error of the rig link."""


class HandshakeError(RigError):
    """No session could be opened (no answer, wrong protocol version, rig busy)."""


class CommandError(RigError):
    """A command was refused (NAK) or never acknowledged."""


class LinkTimeoutError(RigError):
    """The host-side watchdog saw no telemetry for longer than its timeout."""


class RigStalledError(RigError):
    """The MCU's own timestamps show that it missed periods (its firmware stalled)."""


class LinkLostError(RigError):
    """The port failed or was disconnected."""


class RigResetError(RigError):
    """The MCU rebooted during the session; its position reference is lost."""


class RigFaultError(RigError):
    """The MCU latched a fault (it has already stopped or halted)."""

    def __init__(self, message: str, faults: p.Fault) -> None:
        super().__init__(message)
        self.faults = faults


@dataclass(frozen=True)
class Scaling:
    """Raw units of the rig -> SI, from HELLO_REPLY and the load-cell calibration in use."""

    step_m: float
    enc_m: float
    load_offset: int
    load_gain_n: float
    period: float

    def x(self, steps: int, origin: float = 0.0) -> float:
        """Input-link position (m) of a step count; ``origin`` is the position at step 0."""
        return origin + steps * self.step_m

    def steps(self, x: float, origin: float = 0.0) -> int:
        """Nearest step count of input-link position ``x`` (m)."""
        return round((x - origin) / self.step_m)

    def platen(self, enc: int, origin: float = 0.0) -> float:
        """Platen position (m) of an encoder count; ``origin`` is the position at count 0."""
        return origin + enc * self.enc_m

    def counts(self, platen: float, origin: float = 0.0) -> int:
        """Nearest encoder count of platen position ``platen`` (m)."""
        return round((platen - origin) / self.enc_m)

    def force(self, load_raw: int) -> float:
        """Input force (N) of a raw load-cell reading."""
        return (load_raw - self.load_offset) * self.load_gain_n


@dataclass
class LinkStats:
    """Counters and timestamps of a link (times are time.monotonic())."""

    samples: int = 0
    lost_samples: int = 0  # gaps in the telemetry sample index
    duplicates: int = 0  # telemetry frames received twice (dropped)
    queue_dropped: int = 0  # samples dropped because nobody consumed them
    retransmissions: int = 0
    late_attempts: int = 0  # command attempts repeated, uncounted, because the host ran late
    bad_messages: int = 0  # valid frames with an unknown type or wrong length
    last_telemetry_rx: float = 0.0
    max_arrival_gap: float = 0.0  # longest host-side silence between samples, s
    max_clock_excess: float = 0.0  # largest MCU-clock excess between received samples, s
    arrival_gaps_ms: list[int] = dataclasses.field(default_factory=lambda: [0] * 101)
    host_late: int = 0  # times the reader woke more than HOST_LATE after it asked
    failed_at: float | None = None
    stop_sent_at: float | None = None

    def record_gap(self, gap: float) -> None:
        """Count one inter-arrival gap in 1 ms bins (the last bin holds >= 100 ms)."""
        self.max_arrival_gap = max(self.max_arrival_gap, gap)
        self.arrival_gaps_ms[min(int(gap * 1e3), 100)] += 1

    def gap_percentile(self, q: float) -> float:
        """Upper edge (s) of the 1 ms bin holding the q-quantile of the arrival gaps."""
        total = sum(self.arrival_gaps_ms)
        if not total:
            return 0.0
        acc = 0
        for ms, n in enumerate(self.arrival_gaps_ms):
            acc += n
            if acc >= q * total:
                return (ms + 1) * 1e-3
        return self.max_arrival_gap


#: Commands that make the rig move: once the session has failed (its stop sequence has
#: begun) an unacknowledged one is not sent again.
MOTION_COMMANDS = frozenset({p.MsgType.TRAJ_CHUNK, p.MsgType.START})


class _Pending:
    """A command waiting for its ACK."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.reply: p.Ack | p.HelloReply | p.CalibrationReply | None = None


class _StopSequence:
    """The stop that ends a session (section 6): STOP, STOP_ATTEMPTS attempts with one
    seq, then ESTOP if no STOP was acknowledged. Sent once; a new START arms another."""

    def __init__(self, seq: int) -> None:
        self.seq = seq
        self.pending = _Pending()
        self.sent_at: float | None = None  # the first attempt (None: not written yet)
        self.lock = threading.Lock()  # one thread completes the sequence
        self.acked: bool | None = None  # the outcome once complete: STOP acknowledged


class SerialLink:
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
        self._pending: dict[int, _Pending] = {}
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
        self._stop_seq: _StopSequence | None = None  # the last stop sequence
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
            pending = self._pending[seq] = _Pending()
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

    # --- commands -------------------------------------------------------------------------

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
            pending = self._pending[seq] = _Pending()
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
        pending = self._pending[seq] = _Pending()
        try:
            for attempt in range(ESTOP_REPEATS):
                flags = p.FLAG_ACK_REQ | (p.FLAG_RETRY if attempt else 0)
                self._write(p.encode_message(p.EStop(), seq, flags))
            return wait and pending.event.wait(self.ack_timeout * 3)
        except LinkLostError:
            return False
        finally:
            self._pending.pop(seq, None)

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

    def _begin_stop(self) -> _StopSequence | None:
        """The stop sequence: begun now (its first STOP written, without waiting) if armed,
        else the last one; None if none was ever armed. Any thread (the reader's _fail)."""
        with self._stop_lock:
            if not self._stop_armed:
                return self._stop_seq
            self._stop_armed = False
            stop = self._stop_seq = _StopSequence(self._next_seq())
            self._pending[stop.seq] = stop.pending
            stop.sent_at = self.stats.stop_sent_at = time.monotonic()
        with contextlib.suppress(LinkLostError):
            self._write(p.encode_message(p.Stop(), stop.seq, p.FLAG_ACK_REQ))
        return stop

    def _complete_stop(self, stop: _StopSequence) -> bool:
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
            # the halt itself can hold the condition for a few periods (the force of
            # stopping dead): retry while it settles
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

    # --- telemetry ------------------------------------------------------------------------

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
        (docs/rig-protocol.md, sections 5 and 10), so ask it with a HELLO, answered within
        an ACK timeout. A new boot id is :class:`RigResetError`, the same one (a stall:
        the HELLO may have taken the session over) or none the watchdog's
        :class:`LinkTimeoutError`, as before the probe."""
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
