"""Codec of the rig protocol (docs/rig-protocol.md): the message layouts on the frames of
:mod:`hil.link.framing` (COBS, CRC-16), whose names this module re-exports.

Pure functions and dataclasses, no I/O, shared by the host link and the rig emulator.
Every decoding failure raises a :class:`ProtocolError` subclass.
"""

from __future__ import annotations

import functools
import struct
from dataclasses import dataclass, field, fields
from enum import IntEnum, IntFlag
from typing import ClassVar, TypeVar

# the framing is the codec's first half: its names are this module's too (p.FrameDecoder, ...)
from hil.link.framing import (
    CRC as CRC,
)
from hil.link.framing import (
    HEADER as HEADER,
)
from hil.link.framing import (
    MAX_BODY as MAX_BODY,
)
from hil.link.framing import (
    MAX_ENCODED as MAX_ENCODED,
)
from hil.link.framing import (
    MAX_PAYLOAD as MAX_PAYLOAD,
)
from hil.link.framing import (
    CobsError as CobsError,
)
from hil.link.framing import (
    CrcError as CrcError,
)
from hil.link.framing import (
    DecoderStats as DecoderStats,
)
from hil.link.framing import (
    Frame as Frame,
)
from hil.link.framing import (
    FrameDecoder as FrameDecoder,
)
from hil.link.framing import (
    FrameLengthError as FrameLengthError,
)
from hil.link.framing import (
    ProtocolError as ProtocolError,
)
from hil.link.framing import (
    cobs_decode as cobs_decode,
)
from hil.link.framing import (
    cobs_encode as cobs_encode,
)
from hil.link.framing import (
    crc16 as crc16,
)
from hil.link.framing import (
    decode_frame as decode_frame,
)
from hil.link.framing import (
    encode_frame as encode_frame,
)

PROTO_MAJOR = 1
#: 1.1: telemetry flags HOME_SWITCH and REFERENCED, the extension rule; 1.2: CONFIG re-checks
#: the buffered trajectory points against its limits (docs/rig-protocol.md, section 5); 1.3:
#: the load-cell calibration stored on the board (STORE_CALIBRATION, READ_CALIBRATION)
#: and HELLO_REPLY's max_step_delta_limit, which CONFIG's max_step_delta may not exceed.
PROTO_MINOR = 3

MAX_CHUNK_POINTS = 30
#: The most steps an MCU emits in one period (the boards' TIM1 burst, 256 pulses): CONFIG
#: refuses a larger max_step_delta, HELLO_REPLY states it (1.3).
MAX_STEP_DELTA = 256
NO_CHECK = -(2**31)  # expected encoder count meaning "do not check the following error"

FLAG_ACK_REQ = 0x01  # host -> MCU: answer with an ACK
FLAG_RETRY = 0x02  # host -> MCU: this frame is a retransmission (informative)


class MessageError(ProtocolError):
    """A valid frame holds an unknown message type or a payload of the wrong length."""


class MsgType(IntEnum):
    """Message type codes: host -> MCU below 0x80, MCU -> host from 0x80."""

    HELLO = 0x01
    HEARTBEAT = 0x02
    CONFIG = 0x03
    TRAJ_CHUNK = 0x04
    START = 0x05
    STOP = 0x06
    ESTOP = 0x07
    CLEAR_FAULT = 0x08
    SET_POSITION = 0x09
    BYE = 0x0A
    STORE_CALIBRATION = 0x0B  # 1.3
    READ_CALIBRATION = 0x0C  # 1.3
    ACK = 0x80
    HELLO_REPLY = 0x81
    TELEMETRY = 0x82
    FAULT = 0x83
    STATE = 0x84
    CALIBRATION = 0x85  # 1.3: answer to STORE_CALIBRATION and READ_CALIBRATION


class State(IntEnum):
    """MCU states (section 'State machine' of the protocol document)."""

    BOOT = 0
    IDLE = 1
    RUNNING = 2
    STOPPING = 3
    FAULT = 4
    ESTOP = 5


class Fault(IntFlag):
    """Latched fault bits, carried in every telemetry sample."""

    NONE = 0
    FORCE_LIMIT = 0x0001
    TRAVEL_LIMIT = 0x0002
    FOLLOWING_ERROR = 0x0004
    BUFFER_UNDERRUN = 0x0008
    LOAD_SATURATED = 0x0010
    LOAD_STUCK = 0x0020
    HEARTBEAT_LOST = 0x0040
    ESTOP = 0x0080
    DRIVER = 0x0100
    INTERNAL = 0x0200
    # reported by a board only (firmware/board/nucleo_inputs.c;
    # docs/rig-protocol-behaviour.md sec. 8)
    OVERTRAVEL = 0x0400
    LOAD_ADC = 0x0800
    CLOCK = 0x1000
    STOP_CHAIN = 0x2000


class Result(IntEnum):
    """Result code of an ACK: OK or the reason a command was refused."""

    OK = 0
    BAD_STATE = 1
    BAD_LENGTH = 2
    BAD_VALUE = 3
    NO_SPACE = 4
    SEQUENCE_GAP = 5
    OUT_OF_LIMITS = 6
    NO_SESSION = 7
    UNKNOWN_TYPE = 8
    VERSION_MISMATCH = 9
    FAULT_ACTIVE = 10
    EMPTY = 11
    STALE = 12
    NVM_ERROR = 13  # 1.3: the calibration did not verify in non-volatile memory


class Reason(IntEnum):
    """Why the MCU changed state (STATE message)."""

    COMMAND = 0
    RUN_COMPLETE = 1
    FAULT = 2
    STOP_COMPLETE = 3
    LINK_LOST = 4


class TelemetryFlag(IntFlag):
    """Instantaneous status bits of a telemetry sample."""

    NONE = 0
    MOVING = 0x01
    FINAL_RECEIVED = 0x02
    LOAD_SATURATED = 0x04
    SESSION = 0x08
    DRIVER_ENABLED = 0x10
    HOME_SWITCH = 0x20  # 1.1: the reference switch at the open position is active (now)
    REFERENCED = 0x40  # 1.1: step and encoder counts are referenced (SET_POSITION since boot)


# --- messages -----------------------------------------------------------------------------


M = TypeVar("M", bound="Message")


@dataclass(frozen=True, slots=True)
class Message:
    """A message with a fixed little-endian layout ``FORMAT`` over its fields, in order."""

    TYPE: ClassVar[MsgType]
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<")

    def pack(self) -> bytes:
        """Payload bytes of this message."""
        return self.FORMAT.pack(*(getattr(self, name) for name in _wire_fields(type(self))))

    @classmethod
    def unpack(cls: type[M], payload: bytes) -> M:
        """Payload bytes -> message; MessageError when it is shorter than the layout.

        Bytes beyond the layout are ignored: a later minor version appends fields
        (docs/rig-protocol-behaviour.md, section 10).
        """
        if len(payload) < cls.FORMAT.size:
            raise MessageError(
                f"{cls.TYPE.name} payload is {len(payload)} bytes, expected {cls.FORMAT.size}"
            )
        return cls(*cls.FORMAT.unpack_from(payload))

    def frame(self, seq: int, flags: int = 0) -> Frame:
        """Wrap this message in a frame."""
        return Frame(self.TYPE, flags, seq & 0xFFFF, self.pack())


@dataclass(frozen=True, slots=True)
class Hello(Message):
    """Host opens a session; the MCU answers with HELLO_REPLY."""

    TYPE: ClassVar[MsgType] = MsgType.HELLO
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<BBI")
    proto_major: int = PROTO_MAJOR
    proto_minor: int = PROTO_MINOR
    host_nonce: int = 0


@dataclass(frozen=True, slots=True)
class Heartbeat(Message):
    """Host is alive; resets the MCU's heartbeat watchdog (as does every valid host frame)."""

    TYPE: ClassVar[MsgType] = MsgType.HEARTBEAT
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<I")
    host_ms: int = 0


@dataclass(frozen=True, slots=True)
class Config(Message):
    """Safety limits, load-cell calibration and stop deceleration (accepted in IDLE only).

    ``load_gain_n == 0`` keeps the calibration stored in the MCU (``load_offset`` ignored).
    """

    TYPE: ClassVar[MsgType] = MsgType.CONFIG
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<fiiiiiiffHHH")
    force_limit_n: float = 400.0
    steps_min: int = -50_000
    steps_max: int = 400_000
    enc_min: int = -20_000
    enc_max: int = 200_000
    following_error_counts: int = 1_000
    load_offset: int = 0
    load_gain_n: float = 0.0
    decel_steps_s2: float = 5e6
    max_step_delta: int = 250
    heartbeat_timeout_ms: int = 250
    stuck_samples: int = 200


@dataclass(frozen=True, slots=True)
class TrajChunk(Message):
    """Up to MAX_CHUNK_POINTS trajectory points (absolute steps, expected encoder counts)."""

    TYPE: ClassVar[MsgType] = MsgType.TRAJ_CHUNK
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<IBB")
    POINT: ClassVar[struct.Struct] = struct.Struct("<ii")
    FINAL: ClassVar[int] = 0x01
    first_index: int = 0
    flags: int = 0
    points: tuple[tuple[int, int], ...] = ()

    def pack(self) -> bytes:
        """Payload: header then n points of ``<ii``."""
        if not 0 < len(self.points) <= MAX_CHUNK_POINTS:
            n = len(self.points)
            raise MessageError(f"a chunk holds 1..{MAX_CHUNK_POINTS} points, not {n}")
        head = self.FORMAT.pack(self.first_index, self.flags, len(self.points))
        return head + b"".join(self.POINT.pack(s, e) for s, e in self.points)

    @classmethod
    def unpack(cls, payload: bytes) -> TrajChunk:
        """Payload -> chunk; MessageError when it is too short for its point count."""
        if len(payload) < cls.FORMAT.size:
            raise MessageError(f"TRAJ_CHUNK payload of {len(payload)} bytes is too short")
        first, flags, n = cls.FORMAT.unpack_from(payload)
        end = cls.FORMAT.size + n * cls.POINT.size
        if not 0 < n <= MAX_CHUNK_POINTS or len(payload) < end:
            raise MessageError(f"TRAJ_CHUNK of {len(payload)} bytes does not hold {n} points")
        points = tuple(cls.POINT.iter_unpack(payload[cls.FORMAT.size : end]))
        return cls(first, flags, points)

    @property
    def final(self) -> bool:
        """True when this chunk ends the trajectory."""
        return bool(self.flags & self.FINAL)


@dataclass(frozen=True, slots=True)
class Start(Message):
    """Start executing the buffered trajectory."""

    TYPE: ClassVar[MsgType] = MsgType.START


@dataclass(frozen=True, slots=True)
class Stop(Message):
    """Controlled stop: decelerate, discard the buffer, go IDLE."""

    TYPE: ClassVar[MsgType] = MsgType.STOP


@dataclass(frozen=True, slots=True)
class EStop(Message):
    """Emergency stop: halt stepping at once, disable the driver, go ESTOP."""

    TYPE: ClassVar[MsgType] = MsgType.ESTOP


@dataclass(frozen=True, slots=True)
class ClearFault(Message):
    """Leave FAULT or ESTOP for IDLE once no fault condition remains."""

    TYPE: ClassVar[MsgType] = MsgType.CLEAR_FAULT


@dataclass(frozen=True, slots=True)
class SetPosition(Message):
    """Redefine the current step and encoder counts (reference after homing)."""

    TYPE: ClassVar[MsgType] = MsgType.SET_POSITION
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<ii")
    steps: int = 0
    enc: int = 0


@dataclass(frozen=True, slots=True)
class Bye(Message):
    """End the session: stop if moving, go BOOT, disarm the heartbeat watchdog."""

    TYPE: ClassVar[MsgType] = MsgType.BYE


@dataclass(frozen=True, slots=True)
class StoreCalibration(Message):
    """1.3: write the load-cell calibration to the MCU's non-volatile memory (IDLE only)."""

    TYPE: ClassVar[MsgType] = MsgType.STORE_CALIBRATION
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<if")
    load_offset: int = 0
    load_gain_n: float = 0.0


@dataclass(frozen=True, slots=True)
class ReadCalibration(Message):
    """1.3: ask for the calibration stored in the MCU's non-volatile memory."""

    TYPE: ClassVar[MsgType] = MsgType.READ_CALIBRATION


@dataclass(frozen=True, slots=True)
class Ack(Message):
    """Answer to a command frame carrying FLAG_ACK_REQ."""

    TYPE: ClassVar[MsgType] = MsgType.ACK
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<HBBIHH")
    acked_seq: int = 0
    result: int = Result.OK
    state: int = State.BOOT
    sample: int = 0
    buf_level: int = 0
    buf_free: int = 0


@dataclass(frozen=True, slots=True)
class HelloReply(Message):
    """Answer to HELLO: the ACK fields, then the MCU's identity, capacities and scalings."""

    TYPE: ClassVar[MsgType] = MsgType.HELLO_REPLY
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<HBBIHH" + "BBHIIHHBHIIifiiH")
    #: The 1.2 layout, without max_step_delta_limit (a 1.2 MCU states no limit: 65535).
    FORMAT_1_2: ClassVar[struct.Struct] = struct.Struct("<HBBIHH" + "BBHIIHHBHIIifii")
    acked_seq: int = 0
    result: int = Result.OK
    state: int = State.BOOT
    sample: int = 0
    buf_level: int = 0
    buf_free: int = 0
    proto_major: int = PROTO_MAJOR
    proto_minor: int = PROTO_MINOR
    fw_version: int = 0
    boot_id: int = 0
    host_nonce: int = 0
    telemetry_hz: int = 1000
    point_period_us: int = 1000
    max_chunk_points: int = MAX_CHUNK_POINTS
    buffer_capacity: int = 2048
    step_nm: int = 200
    enc_nm: int = 1000
    load_offset: int = 0
    load_gain_n: float = 1e-4
    adc_min: int = -8_388_608
    adc_max: int = 8_388_607
    max_step_delta_limit: int = MAX_STEP_DELTA

    @classmethod
    def unpack(cls, payload: bytes) -> HelloReply:
        """Payload -> reply; a 1.2 MCU's 55 bytes give ``max_step_delta_limit`` 65535."""
        if cls.FORMAT_1_2.size <= len(payload) < cls.FORMAT.size:
            return cls(*cls.FORMAT_1_2.unpack_from(payload), max_step_delta_limit=0xFFFF)
        return super(HelloReply, cls).unpack(payload)


@dataclass(frozen=True, slots=True)
class Telemetry(Message):
    """One 1 kHz sample; ``rx_time`` is set by the receiver (host monotonic s), not sent."""

    TYPE: ClassVar[MsgType] = MsgType.TELEMETRY
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<IIIiiiIHHBB")
    boot_id: int = 0
    sample: int = 0
    t_us: int = 0
    steps: int = 0
    enc: int = 0
    load_raw: int = 0
    exec_index: int = 0
    buf_level: int = 0
    faults: int = 0
    state: int = State.BOOT
    flags: int = 0
    rx_time: float = field(default=0.0, compare=False, metadata={"wire": False})


@dataclass(frozen=True, slots=True)
class FaultReport(Message):
    """Sent once when a fault bit latches; the bits also stay set in every telemetry sample."""

    TYPE: ClassVar[MsgType] = MsgType.FAULT
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<HIBii")
    fault: int = 0
    sample: int = 0
    state: int = State.FAULT
    value: int = 0
    limit: int = 0


@dataclass(frozen=True, slots=True)
class StateChange(Message):
    """Sent on every state transition."""

    TYPE: ClassVar[MsgType] = MsgType.STATE
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<BBBII")
    old: int = 0
    new: int = 0
    reason: int = Reason.COMMAND
    exec_index: int = 0
    sample: int = 0


@dataclass(frozen=True, slots=True)
class CalibrationReply(Message):
    """1.3: the ACK fields, then the stored calibration (after the command) and its record
    number ``cal_seq`` (0: none stored, the firmware's defaults)."""

    TYPE: ClassVar[MsgType] = MsgType.CALIBRATION
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<HBBIHH" + "Iif")
    acked_seq: int = 0
    result: int = Result.OK
    state: int = State.BOOT
    sample: int = 0
    buf_level: int = 0
    buf_free: int = 0
    cal_seq: int = 0
    load_offset: int = 0
    load_gain_n: float = 0.0


@functools.cache
def _wire_fields(cls: type[Message]) -> tuple[str, ...]:
    """Names of the fields of ``cls`` that are on the wire, in layout order."""
    return tuple(f.name for f in fields(cls) if f.metadata.get("wire", True))


MESSAGES: dict[int, type[Message]] = {
    cls.TYPE: cls
    for cls in (
        Hello, Heartbeat, Config, TrajChunk, Start, Stop, EStop, ClearFault, SetPosition, Bye,
        StoreCalibration, ReadCalibration,
        Ack, HelloReply, Telemetry, FaultReport, StateChange, CalibrationReply,
    )
}


def parse_message(frame: Frame) -> Message:
    """Frame -> typed message; MessageError on an unknown type or a bad payload length."""
    cls = MESSAGES.get(frame.msg_type)
    if cls is None:
        raise MessageError(f"unknown message type {frame.msg_type:#04x}")
    return cls.unpack(frame.payload)


def encode_message(msg: Message, seq: int, flags: int = 0) -> bytes:
    """Message -> wire bytes (frame, COBS, delimiter)."""
    return encode_frame(msg.frame(seq, flags))


def seq_newer(seq: int, last: int) -> bool:
    """RFC 1982 serial-number order on 16 bits: True when ``seq`` is after ``last``."""
    return 0 < ((seq - last) & 0xFFFF) < 0x8000


def seq_stale(seq: int, last: int) -> bool:
    """True when ``seq`` is older than ``last``: 0 < (last - seq) mod 2^16 < 2^15.

    Exactly 2^15 apart is undefined in RFC 1982; the protocol executes it (not stale).
    """
    return 0 < ((last - seq) & 0xFFFF) < 0x8000
