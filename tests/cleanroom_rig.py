"""Clean-room MCU of the clamp test rig, written from docs/rig-protocol.md (v1.1) alone.

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

`Mcu` is the firmware logic without I/O (bytes in, frames out, one `tick` per period).
`serve` runs it on a pseudo-terminal with a 1 ms tick loop, and `CleanroomRig` starts
`serve` in a separate (spawned) process and talks to it over a pipe.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import os
import random
import select
import struct
import time
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

# --- constants from the document ----------------------------------------------------

PROTO_MAJOR, PROTO_MINOR = 1, 3  # 1.3: the stored calibration (written from the 1.3 text)
FW_VERSION = 0x0103
TELEMETRY_HZ = 1000
PERIOD_US = 1000
PERIOD_S = PERIOD_US * 1e-6
MAX_CHUNK_POINTS = 30
BUFFER_CAPACITY = 2048
STEP_NM = 200
MAX_STEP_DELTA = 256  # 1.3: the most steps a period may hold (HELLO_REPLY, CONFIG)
ENC_NM = 1000
ADC_MIN, ADC_MAX = -8_388_608, 8_388_607
STORED_LOAD_OFFSET = 1500  # the worked example's calibration (section 12)
STORED_LOAD_GAIN = 1e-4  # N/count, the document's default (section 3)
MAX_PAYLOAD = 250
MAX_ENCODED = 258  # receive buffer (section 2)
NO_CHECK = -(2**31)

ACK_REQ, RETRY = 0x01, 0x02

# message types
HELLO, HEARTBEAT, CONFIG, TRAJ_CHUNK, START, STOP = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
ESTOP_CMD, CLEAR_FAULT, SET_POSITION, BYE = 0x07, 0x08, 0x09, 0x0A
STORE_CAL, READ_CAL = 0x0B, 0x0C  # 1.3
ACK, HELLO_REPLY, TELEMETRY, FAULT_MSG, STATE_MSG = 0x80, 0x81, 0x82, 0x83, 0x84
CALIBRATION = 0x85  # 1.3

# result codes
OK, BAD_STATE, BAD_LENGTH, BAD_VALUE, NO_SPACE, SEQUENCE_GAP, OUT_OF_LIMITS = range(7)
NO_SESSION, UNKNOWN_TYPE, VERSION_MISMATCH, FAULT_ACTIVE, EMPTY, STALE = range(7, 13)
NVM_ERROR = 13  # 1.3

# states
BOOT, IDLE, RUNNING, STOPPING, FAULT, ESTOP = range(6)
STATE_NAMES = ("BOOT", "IDLE", "RUNNING", "STOPPING", "FAULT", "ESTOP")

# STATE reasons
R_COMMAND, R_RUN_COMPLETE, R_FAULT, R_STOP_COMPLETE, R_LINK_LOST = range(5)

# fault bits
F_FORCE, F_TRAVEL, F_FOLLOWING, F_UNDERRUN, F_SATURATED = 0x01, 0x02, 0x04, 0x08, 0x10
F_STUCK, F_HEARTBEAT, F_ESTOP, F_DRIVER, F_INTERNAL = 0x20, 0x40, 0x80, 0x100, 0x200

F_BOARD = 0x0200 | 0x0400 | 0x0800 | 0x1000 | 0x2000  # INTERNAL and the board's own

# telemetry flags
FL_MOVING, FL_FINAL, FL_SATURATED, FL_SESSION = 0x01, 0x02, 0x04, 0x08
FL_DRIVER, FL_HOME, FL_REFERENCED = 0x10, 0x20, 0x40

HEADER = struct.Struct("<BBH")
CRC = struct.Struct("<H")
HELLO_FMT = struct.Struct("<BBI")
CONFIG_FMT = struct.Struct("<fiiiiiiffHHH")
CHUNK_HEAD = struct.Struct("<IBB")
POINT = struct.Struct("<ii")
SETPOS_FMT = struct.Struct("<ii")
ACK_FMT = struct.Struct("<HBBIHH")
HELLO_TAIL = struct.Struct("<BBHIIHHBHIIifiiH")  # 1.3: max_step_delta_limit at the end
TELEMETRY_FMT = struct.Struct("<IIIiiiIHHBB")
FAULT_FMT = struct.Struct("<HIBii")
STATE_FMT = struct.Struct("<BBBII")
STORE_CAL_FMT = struct.Struct("<if")  # 1.3
CAL_TAIL = struct.Struct("<Iif")  # 1.3: after the ACK fields

#: minimum payload length of each host command (section 4)
LAYOUT_LEN = {HELLO: 6, HEARTBEAT: 4, CONFIG: 42, TRAJ_CHUNK: 6, START: 0, STOP: 0,
              ESTOP_CMD: 0, CLEAR_FAULT: 0, SET_POSITION: 8, BYE: 0, STORE_CAL: 8, READ_CAL: 0}
SESSION_ONLY = {CONFIG, TRAJ_CHUNK, START, CLEAR_FAULT, SET_POSITION, BYE, STORE_CAL,
                READ_CAL}


# --- codec ----------------------------------------------------------------------------

def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode `data` (no trailing delimiter)."""
    out = bytearray()
    block = bytearray()
    for byte in data:
        if byte == 0:
            out.append(len(block) + 1)
            out += block
            block.clear()
        else:
            block.append(byte)
            if len(block) == 254:
                out.append(0xFF)
                out += block
                block.clear()
    out.append(len(block) + 1)
    out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes | None:
    """Decode one COBS frame (delimiter removed); None if it is invalid."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0 or i + code > n:
            return None
        out += data[i + 1:i + code]
        i += code
        if code < 0xFF and i < n:
            out.append(0)
    return bytes(out)


def frame(msg_type: int, flags: int, seq: int, payload: bytes) -> bytes:
    """The wire bytes of one message: COBS(header ‖ payload ‖ crc) ‖ 0x00."""
    body = HEADER.pack(msg_type, flags, seq & 0xFFFF) + payload
    return cobs_encode(body + CRC.pack(crc16(body))) + b"\x00"


def parse_body(body: bytes) -> tuple[int, int, int, bytes] | None:
    """(type, flags, seq, payload) of a decoded body, or None (short or bad CRC)."""
    if len(body) < 6 or CRC.unpack_from(body, len(body) - 2)[0] != crc16(body[:-2]):
        return None
    msg_type, flags, seq = HEADER.unpack_from(body)
    return msg_type, flags, seq, body[4:-2]


# --- firmware logic -------------------------------------------------------------------

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


@dataclass
class Mcu:
    """The MCU of the rig: protocol, state machine, trajectory, safety checks.

    physics(x_m, t_s) -> (platen_m, force_N) is called once per period with the
    commanded table position; x_open is the table position at power-on (step 0).
    """

    physics: Callable[[float, float], tuple[float, float]]
    x_open: float
    noise_n: float = 0.2
    future: bool = False  # act as the next minor version would (section 10, item 2)
    seed: int | None = None
    out: list[bytes] = field(default_factory=list)
    runs: list[Run] = field(default_factory=list)
    log: deque[tuple[Any, ...]] = field(default_factory=lambda: deque(maxlen=4000))
    stats: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)
        self.boot_id = int.from_bytes(os.urandom(4), "little") or 1
        self.sample = 0  # index of the next telemetry sample
        self.state = BOOT
        self.session = False
        self.faults = 0
        self.cfg = Config()
        self.nvm: dict[str, Any] = {"seq": 0, "offset": STORED_LOAD_OFFSET,
                                    "gain": STORED_LOAD_GAIN}  # non-volatile: 1.3
        self.load_offset, self.load_gain = self.nvm["offset"], self.nvm["gain"]
        self.pos = 0.0  # table position in steps since power-on (float for the stop ramp)
        self.rate = 0.0  # steps per period of the present period
        self.steps_off = 0  # reported steps = round(pos) + steps_off
        self.enc_off = 0  # reported enc = encoder counts since power-on + enc_off
        self.referenced = False
        self.platen0: float | None = None
        self.enc_raw = 0  # encoder counts since power-on, last reading
        self.load_raw = STORED_LOAD_OFFSET
        self.stuck_count = 0
        # trajectory
        self.points: deque[tuple[int, int]] = deque()
        self.next_index = 0
        self.exec_index = 0
        self.final = False
        self.discarded = False
        self.last_point: int | None = None
        # command bookkeeping
        self.mseq = 0
        self.last_seq: int | None = None
        self.last_reply: tuple[int, bytes] | None = None
        self.last_rx = 0.0
        self.rx = bytearray()
        self.rx_skip = False
        self.run: Run | None = None

    # -- helpers -----------------------------------------------------------------------

    def _count(self, key: str) -> None:
        self.stats[key] = self.stats.get(key, 0) + 1

    def _send(self, msg_type: int, payload: bytes) -> None:
        if self.future:
            payload += b"\x5a\xa5\x00\x01"  # a later minor version's appended fields
        self.out.append(frame(msg_type, 0, self.mseq, payload))
        self.mseq = (self.mseq + 1) & 0xFFFF

    @property
    def steps(self) -> int:
        """Present step count (commanded table position), as reported."""
        return round(self.pos) + self.steps_off

    @property
    def enc(self) -> int:
        """Present encoder count, as reported."""
        return self.enc_raw + self.enc_off

    @property
    def force(self) -> float:
        """Force from the last reading with the calibration in use, N."""
        return (self.load_raw - self.load_offset) * self.load_gain

    def _set_state(self, new: int, reason: int) -> None:
        if new != self.state:
            self.log.append((self.sample, "state", STATE_NAMES[self.state], STATE_NAMES[new],
                             reason))
            self._send(STATE_MSG, STATE_FMT.pack(self.state, new, reason,
                                                 self.exec_index, self.sample))
            self.state = new

    def _latch(self, bit: int, value: float, limit: float) -> bool:
        """Latch a fault bit; sends FAULT if it is new. True if it was new."""
        if self.faults & bit:
            return False
        self.faults |= bit
        self.log.append((self.sample, "fault", bit, value, limit))
        self._send(FAULT_MSG, FAULT_FMT.pack(bit, self.sample, self.state,
                                             _i32(value), _i32(limit)))
        return True

    def _discard(self) -> None:
        self.points.clear()
        self.discarded = True

    def _halt(self, to: int = FAULT) -> None:
        self.rate = 0.0
        self._discard()
        self._set_state(to, R_FAULT if to == FAULT else R_COMMAND)

    def _controlled_stop(self, reason: int) -> None:
        self._discard()
        self._set_state(STOPPING, reason)

    def _ack(self, seq: int, result: int) -> bytes:
        level = len(self.points)
        return ACK_FMT.pack(seq, result, self.state, self.sample, level,
                            BUFFER_CAPACITY - level)

    def _conditions_present(self) -> int:
        """Fault bits whose condition holds on the last readings."""
        bits = 0
        if abs(self.force) > self.cfg.force_limit_n:
            bits |= F_FORCE
        if not (self.cfg.steps_min <= self.steps <= self.cfg.steps_max
                and self.cfg.enc_min <= self.enc <= self.cfg.enc_max):
            bits |= F_TRAVEL
        if not ADC_MIN < self.load_raw < ADC_MAX:
            bits |= F_SATURATED
        return bits

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

    # -- the period --------------------------------------------------------------------

    def tick(self, now: float) -> None:
        """One period: step output, sensor reading, checks, FAULT/STATE, TELEMETRY."""
        executed: tuple[int, int] | None = None
        underrun = False
        if self.state == RUNNING:
            if self.points:
                executed = self.points.popleft()
                target = executed[0] - self.steps_off
                self.rate = target - self.pos
                self.pos = float(target)
                self.exec_index += 1
            elif not self.final:
                underrun = True
        if self.state == STOPPING or underrun:
            self._ramp()
        elif executed is None:
            self.rate = 0.0
        # sensors, latched together after the step output of this period
        t_s = self.sample * PERIOD_S
        platen, force = self.physics(self.x_open + round(self.pos) * STEP_NM * 1e-9, t_s)
        if self.platen0 is None:
            self.platen0 = platen
        self.enc_raw = round((platen - self.platen0) * 1e9 / ENC_NM)
        noise = self.rng.gauss(0.0, self.noise_n) if self.noise_n > 0 else 0.0
        raw = round(STORED_LOAD_OFFSET + (force + noise) / STORED_LOAD_GAIN)
        raw = min(max(raw, ADC_MIN), ADC_MAX)
        self.stuck_count = self.stuck_count + 1 if raw == self.load_raw else 1
        self.load_raw = raw
        self._checks(executed, underrun, now)
        if self.state == RUNNING and not self.points and self.final:
            self._set_state(IDLE, R_RUN_COMPLETE)
        if self.state == STOPPING and self.rate == 0.0:
            if self.faults:
                self._set_state(FAULT, R_FAULT)
            else:
                self._set_state(IDLE, R_STOP_COMPLETE)
        self._telemetry()
        if self.run is not None and self.state not in (RUNNING, STOPPING):
            self.run.end_sample, self.run.end_state = self.sample, self.state
            self.run.exec_index, self.run.faults = self.exec_index, self.faults
            self.run.points = self.next_index
            self.runs.append(self.run)
            self.run = None
        self.sample += 1

    def _ramp(self) -> None:
        dv = self.cfg.decel_steps_s2 * PERIOD_S * PERIOD_S
        speed = max(abs(self.rate) - dv, 0.0)
        self.rate = math.copysign(speed, self.rate) if speed > 0 else 0.0
        self.pos += self.rate

    def _checks(self, executed: tuple[int, int] | None, underrun: bool, now: float) -> None:
        cfg, st = self.cfg, self.state
        halt = False
        if st in (IDLE, RUNNING, STOPPING):
            force = self.force
            if abs(force) > cfg.force_limit_n:
                self._latch(F_FORCE, force, cfg.force_limit_n)
                halt = True
            if not cfg.steps_min <= self.steps <= cfg.steps_max:
                lim = cfg.steps_min if self.steps < cfg.steps_min else cfg.steps_max
                self._latch(F_TRAVEL, self.steps, lim)
                halt = True
            elif not cfg.enc_min <= self.enc <= cfg.enc_max:
                lim = cfg.enc_min if self.enc < cfg.enc_min else cfg.enc_max
                self._latch(F_TRAVEL, self.enc, lim)
                halt = True
            if not ADC_MIN < self.load_raw < ADC_MAX:
                self._latch(F_SATURATED, self.load_raw,
                            ADC_MIN if self.load_raw <= ADC_MIN else ADC_MAX)
                halt = True
        if st == RUNNING:
            if executed is not None and executed[1] != NO_CHECK:
                err = self.enc - executed[1]
                if abs(err) > cfg.following_error_counts:
                    self._latch(F_FOLLOWING, err, cfg.following_error_counts)
                    self.referenced = False  # counts may be lost (doc revision of 10.6)
                    halt = True
            if self.stuck_count >= cfg.stuck_samples:
                self._latch(F_STUCK, self.stuck_count, cfg.stuck_samples)
                halt = True
        if halt:
            self._halt()
            return
        if underrun and self.state == RUNNING:
            self._latch(F_UNDERRUN, self.exec_index, self.next_index)
            self._controlled_stop(R_FAULT)
        if self.session:
            silent_ms = (now - self.last_rx) * 1e3
            if silent_ms > cfg.heartbeat_timeout_ms and not self.faults & F_HEARTBEAT:
                self._latch(F_HEARTBEAT, silent_ms, cfg.heartbeat_timeout_ms)
                if self.state == RUNNING:
                    self._controlled_stop(R_FAULT)
                elif self.state == IDLE:
                    self._discard()
                    self._set_state(FAULT, R_FAULT)

    def _telemetry(self) -> None:
        flags = FL_SESSION if self.session else 0
        if self.rate != 0.0:
            flags |= FL_MOVING
        if self.final:
            flags |= FL_FINAL
        if not ADC_MIN < self.load_raw < ADC_MAX:
            flags |= FL_SATURATED
        if self.state != ESTOP and not self.faults & F_BOARD:  # section 8: the board's faults
            flags |= FL_DRIVER  # de-energise (this rig raises none of them)
        if round(self.pos) <= 0:  # switch at x_open, active at or behind it
            flags |= FL_HOME
        if self.referenced:
            flags |= FL_REFERENCED
        if self.future:
            flags |= 0x80
            if self.sample % 100 == 50:
                self._send(0x85, struct.pack("<I", self.sample))  # a type this host lacks
        t_us = (self.sample * PERIOD_US) & 0xFFFFFFFF
        self._send(TELEMETRY, TELEMETRY_FMT.pack(
            self.boot_id, self.sample & 0xFFFFFFFF, t_us, self.steps, self.enc, self.load_raw,
            self.exec_index, len(self.points), self.faults, self.state, flags))


def _i32(v: float) -> int:
    return max(-(2**31), min(2**31 - 1, round(v)))


# --- serving it on a pseudo-terminal --------------------------------------------------

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
