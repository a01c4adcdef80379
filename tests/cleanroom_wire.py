"""The clean-room rig's wire, written from docs/rig-protocol.md and
docs/rig-protocol-behaviour.md alone (tests/cleanroom_rig.py says how): the document's
constants, message types, result codes, states, fault and telemetry bits, message layouts,
and the framing (COBS, CRC-16/CCITT-FALSE)."""

from __future__ import annotations

import struct

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
