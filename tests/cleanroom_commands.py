"""The clean-room MCU's commands (docs/rig-protocol.md sections 4-5; tests/cleanroom_rig.py
says how it was written): receiving frames, the duplicate/STALE bookkeeping, and each host
command's handler. :class:`Commands` is a base of :class:`cleanroom_mcu.Mcu` and acts on its
state and helpers; the period (steps, sensors, checks, telemetry) is the Mcu's own."""

from __future__ import annotations

import math
from dataclasses import dataclass

from cleanroom_wire import (
    ACK,
    ACK_REQ,
    ADC_MAX,
    ADC_MIN,
    BAD_LENGTH,
    BAD_STATE,
    BAD_VALUE,
    BOOT,
    BUFFER_CAPACITY,
    CAL_TAIL,
    CALIBRATION,
    CHUNK_HEAD,
    CONFIG_FMT,
    EMPTY,
    ENC_NM,
    ESTOP,
    ESTOP_CMD,
    F_ESTOP,
    FAULT,
    FAULT_ACTIVE,
    FW_VERSION,
    HEARTBEAT,
    HELLO,
    HELLO_FMT,
    HELLO_REPLY,
    HELLO_TAIL,
    IDLE,
    LAYOUT_LEN,
    MAX_CHUNK_POINTS,
    MAX_ENCODED,
    MAX_STEP_DELTA,
    NO_SESSION,
    NO_SPACE,
    OK,
    OUT_OF_LIMITS,
    PERIOD_US,
    POINT,
    PROTO_MAJOR,
    PROTO_MINOR,
    R_COMMAND,
    READ_CAL,
    RUNNING,
    SEQUENCE_GAP,
    SESSION_ONLY,
    SETPOS_FMT,
    STALE,
    STATE_NAMES,
    STEP_NM,
    STOPPING,
    STORE_CAL,
    STORE_CAL_FMT,
    TELEMETRY_HZ,
    TRAJ_CHUNK,
    UNKNOWN_TYPE,
    VERSION_MISMATCH,
    cobs_decode,
    parse_body,
)


@dataclass
class Config:
    """Session limits and settings (CONFIG, section 5), defaults as at boot."""

    force_limit_n: float = 400.0
    steps_min: int = -50_000
    steps_max: int = 400_000
    enc_min: int = -20_000
    enc_max: int = 200_000
    following_error_counts: int = 1000
    decel_steps_s2: float = 5e6
    max_step_delta: int = 250
    heartbeat_timeout_ms: int = 250
    stuck_samples: int = 200


@dataclass
class Run:
    """One START of the MCU and how it ended (kept for the tests)."""

    start_sample: int
    points: int = 0  # points received (at START, then at the end)
    end_sample: int | None = None
    end_state: int | None = None
    exec_index: int = 0
    faults: int = 0

    @property
    def samples(self) -> int:
        """Telemetry samples sent from START's sample to the first one at standstill."""
        assert self.end_sample is not None
        return self.end_sample - self.start_sample + 1


class Commands:
    """The host commands of an :class:`cleanroom_mcu.Mcu`: bytes in, replies out."""

    # -- receive -----------------------------------------------------------------------

    def receive(self, data: bytes, now: float) -> None:
        """Feed received bytes; complete frames are acted on at once."""
        for byte in data:
            if byte != 0:
                if self.rx_skip:
                    continue
                self.rx.append(byte)
                if len(self.rx) > MAX_ENCODED:
                    self._count("overflow")
                    self.rx.clear()
                    self.rx_skip = True
                continue
            if self.rx_skip:
                self.rx_skip = False
                continue
            if not self.rx:
                self._count("empty_frames")
                continue
            body = cobs_decode(bytes(self.rx))
            self.rx.clear()
            msg = parse_body(body) if body is not None else None
            if msg is None:
                self._count("dropped")
                continue
            self.last_rx = now
            self._command(*msg)

    def _command(self, msg_type: int, flags: int, seq: int, payload: bytes) -> None:
        self._count(f"rx_{msg_type:#04x}")
        self.log.append((self.sample, "rx", msg_type, flags, seq, payload[:64].hex(),
                         self.steps, self.enc))
        if msg_type == HEARTBEAT:
            return
        reply_type = {HELLO: HELLO_REPLY, STORE_CAL: CALIBRATION,
                      READ_CAL: CALIBRATION}.get(msg_type, ACK)
        if msg_type not in LAYOUT_LEN:
            self._reply(flags, ACK, self._ack(seq, UNKNOWN_TYPE), seq)
            return
        if len(payload) < LAYOUT_LEN[msg_type] or (
                msg_type == TRAJ_CHUNK and len(payload) < 6 + 8 * payload[5]):
            self._reply(flags, ACK, self._ack(seq, BAD_LENGTH), seq)
            return
        if msg_type == HELLO:
            reply = self._hello(seq, payload)
            self.last_seq, self.last_reply = seq, (HELLO_REPLY, reply)
            self._reply(flags, HELLO_REPLY, reply, seq)
            return
        if msg_type == ESTOP_CMD:
            result = self._estop()
            reply = self._ack(seq, result)
            if self.last_seq is None or 0 < (seq - self.last_seq) % 65536 <= 32768:
                self.last_seq, self.last_reply = seq, (ACK, reply)
            self._reply(flags, ACK, reply, seq)
            return
        if self.last_seq is not None:
            diff = (self.last_seq - seq) % 65536
            if diff == 0 and self.last_reply is not None:
                self._count("duplicate")
                self._reply(flags, *self.last_reply, seq)
                return
            if 0 < diff < 32768:
                self._count("stale")
                self._reply(flags, ACK, self._ack(seq, STALE), seq)
                return
        if msg_type in SESSION_ONLY and not self.session:
            result, reply_type = NO_SESSION, ACK
        else:
            result = getattr(self, f"_cmd_{msg_type:#04x}")(payload)
        reply = self._ack(seq, result)
        if reply_type == CALIBRATION:
            reply += CAL_TAIL.pack(self.nvm["seq"], self.nvm["offset"], self.nvm["gain"])
        self.last_seq, self.last_reply = seq, (reply_type, reply)
        self._reply(flags, reply_type, reply, seq)

    def _reply(self, flags: int, reply_type: int, payload: bytes, seq: int) -> None:
        result = payload[2]
        if result != OK:
            self._count(f"result_{result}")
        self.log.append((self.sample, "reply", reply_type, seq, result, STATE_NAMES[self.state]))
        if flags & ACK_REQ:
            self._send(reply_type, payload)

    # -- commands ----------------------------------------------------------------------

    def _hello(self, seq: int, payload: bytes) -> bytes:
        major, _minor, nonce = HELLO_FMT.unpack_from(payload)
        if major != PROTO_MAJOR:
            result = VERSION_MISMATCH
        elif self.state in (RUNNING, STOPPING):
            result = BAD_STATE
        else:
            result = OK
            self.session = True
            self.load_offset, self.load_gain = self.nvm["offset"], self.nvm["gain"]
            if self.state == BOOT:
                self._set_state(IDLE, R_COMMAND)
        minor = PROTO_MINOR + 1 if self.future else PROTO_MINOR
        tail = HELLO_TAIL.pack(PROTO_MAJOR, minor, FW_VERSION, self.boot_id, nonce,
                               TELEMETRY_HZ, PERIOD_US, MAX_CHUNK_POINTS, BUFFER_CAPACITY,
                               STEP_NM, ENC_NM, self.load_offset, self.load_gain,
                               ADC_MIN, ADC_MAX, MAX_STEP_DELTA)
        return self._ack(seq, result) + tail

    def _estop(self) -> int:
        self._latch(F_ESTOP, 0, 0)
        if self.state != ESTOP:
            self._halt(ESTOP)
        return OK

    def _cmd_0x03(self, payload: bytes) -> int:  # CONFIG
        if self.state != IDLE:
            return BAD_STATE
        (force, smin, smax, emin, emax, ferr, offset, gain, decel, maxd, hb,
         stuck) = CONFIG_FMT.unpack_from(payload)
        if not (all(math.isfinite(v) for v in (force, gain, decel)) and smin < smax
                and emin < emax and force > 0 and ferr > 0 and decel > 0
                and 0 < maxd <= MAX_STEP_DELTA
                and hb > 0 and stuck > 0 and gain >= 0):
            return BAD_VALUE
        self.cfg = Config(force, smin, smax, emin, emax, ferr, decel, maxd, hb, stuck)
        if gain > 0:
            self.load_offset, self.load_gain = offset, gain
        return OK

    def _cmd_0x04(self, payload: bytes) -> int:  # TRAJ_CHUNK
        first, flags, n = CHUNK_HEAD.unpack_from(payload)
        if not 1 <= n <= MAX_CHUNK_POINTS:
            return BAD_VALUE
        pts = [POINT.unpack_from(payload, 6 + 8 * k) for k in range(n)]
        if first == 0 and self.state == IDLE:  # rule 1
            self.points.clear()
            self.next_index = self.exec_index = 0
            self.final = self.discarded = False
            self.last_point = None
        if self.state not in (IDLE, RUNNING) or self.discarded:  # rule 2
            return BAD_STATE
        if first + n <= self.next_index:  # rule 3
            self._count("late_chunk")
            return OK
        if first != self.next_index:  # rule 4
            return SEQUENCE_GAP
        if self.final:  # rule 5
            return BAD_STATE
        if n > BUFFER_CAPACITY - len(self.points):  # rule 6
            return NO_SPACE
        if any(not self.cfg.steps_min <= s <= self.cfg.steps_max for s, _ in pts):  # rule 7
            return OUT_OF_LIMITS
        prev = self.last_point if self.last_point is not None else self.steps
        for s, _ in pts:
            if abs(s - prev) > self.cfg.max_step_delta:
                return BAD_VALUE
            prev = s
        self.points.extend(pts)
        self.next_index += n
        self.last_point = pts[-1][0]
        self.final = bool(flags & 1)
        return OK

    def _cmd_0x05(self, payload: bytes) -> int:  # START
        if self.state != IDLE:
            return BAD_STATE
        if self.faults:
            return FAULT_ACTIVE
        if not self.points:
            return EMPTY
        self._set_state(RUNNING, R_COMMAND)
        self.run = Run(self.sample, points=self.next_index)
        return OK

    def _cmd_0x06(self, payload: bytes) -> int:  # STOP
        if self.state == RUNNING:
            self._controlled_stop(R_COMMAND)
        elif self.state == IDLE:
            self._discard()
        return OK

    def _cmd_0x08(self, payload: bytes) -> int:  # CLEAR_FAULT
        if self.state in (RUNNING, STOPPING):
            return BAD_STATE
        if self._conditions_present():
            return FAULT_ACTIVE
        self.faults = 0
        if self.state in (FAULT, ESTOP):
            self._set_state(IDLE, R_COMMAND)
        return OK

    def _cmd_0x09(self, payload: bytes) -> int:  # SET_POSITION
        if self.state != IDLE:
            return BAD_STATE
        steps, enc = SETPOS_FMT.unpack_from(payload)
        self.steps_off = steps - round(self.pos)
        self.enc_off = enc - self.enc_raw
        self.referenced = True
        self.points.clear()
        self.next_index = self.exec_index = 0
        self.final = self.discarded = False
        self.last_point = None
        return OK

    def _cmd_0x0b(self, payload: bytes) -> int:  # STORE_CALIBRATION (1.3)
        offset, gain = STORE_CAL_FMT.unpack_from(payload)
        if self.state != IDLE:
            return BAD_STATE
        if not (math.isfinite(gain) and gain > 0 and ADC_MIN < offset < ADC_MAX):
            return BAD_VALUE
        self.nvm = {"seq": self.nvm["seq"] + 1, "offset": offset, "gain": gain}
        self.load_offset, self.load_gain = offset, gain  # in use at once
        return OK

    def _cmd_0x0c(self, payload: bytes) -> int:  # READ_CALIBRATION (1.3)
        return OK

    def _cmd_0x0a(self, payload: bytes) -> int:  # BYE
        if self.state in (RUNNING, STOPPING):
            return BAD_STATE
        self.session = False
        if self.state == IDLE:
            self._set_state(BOOT, R_COMMAND)
        return OK
