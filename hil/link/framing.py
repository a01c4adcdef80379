"""The rig protocol's framing (docs/rig-protocol.md section 2): COBS, CRC-16/CCITT-FALSE,
frames and the streaming decoder that drops and counts every bad one.

A frame on the wire is ``COBS(header + payload + crc) + b"\\x00"``; the header is ``<BBH``
(type, flags, seq), the CRC covers header and payload, stored little-endian. Pure
functions, no I/O; :mod:`hil.link.protocol` lays the messages out on these frames (and
re-exports these names: ``p.FrameDecoder`` and the rest are the codec's).
"""

from __future__ import annotations

import binascii
import struct
from collections.abc import Iterator
from dataclasses import dataclass

HEADER = struct.Struct("<BBH")
CRC = struct.Struct("<H")
MAX_PAYLOAD = 250
MAX_BODY = HEADER.size + MAX_PAYLOAD + CRC.size  # 256
MAX_ENCODED = MAX_BODY + 1 + MAX_BODY // 254  # 258: COBS worst case, without the delimiter


class ProtocolError(Exception):
    """Base of every error raised by this codec."""


class CobsError(ProtocolError):
    """The bytes between two delimiters are not valid COBS."""


class FrameLengthError(ProtocolError):
    """A frame is shorter than a header plus CRC or longer than the maximum."""


class CrcError(ProtocolError):
    """The CRC trailer does not match the frame's contents."""


# --- COBS and CRC -------------------------------------------------------------------------


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, unreflected; '123456789' -> 0x29B1."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """Consistent-overhead byte stuffing: the result holds no zero byte."""
    out = bytearray()
    for piece in bytes(data).split(b"\x00"):
        while len(piece) >= 254:
            out.append(0xFF)
            out += piece[:254]
            piece = piece[254:]
        out.append(len(piece) + 1)
        out += piece
    return bytes(out)


def cobs_decode(encoded: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`CobsError` on malformed input."""
    if b"\x00" in encoded:
        raise CobsError("zero byte inside a COBS block")
    out = bytearray()
    i, n = 0, len(encoded)
    while i < n:
        code = encoded[i]
        end = i + code
        if end > n:
            raise CobsError(f"COBS block at offset {i} runs {end - n} bytes past the frame end")
        out += encoded[i + 1 : end]
        if code < 0xFF and end < n:
            out.append(0)
        i = end
    return bytes(out)


# --- frames -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded frame: header fields and the raw payload."""

    msg_type: int
    flags: int
    seq: int
    payload: bytes = b""


def encode_frame(frame: Frame) -> bytes:
    """Frame -> wire bytes, including the trailing zero delimiter."""
    if len(frame.payload) > MAX_PAYLOAD:
        raise FrameLengthError(f"payload of {len(frame.payload)} bytes exceeds {MAX_PAYLOAD}")
    body = HEADER.pack(frame.msg_type, frame.flags, frame.seq & 0xFFFF) + frame.payload
    return cobs_encode(body + CRC.pack(crc16(body))) + b"\x00"


def decode_frame(encoded: bytes) -> Frame:
    """COBS bytes between two delimiters -> Frame; raises a ProtocolError on any defect."""
    if len(encoded) > MAX_ENCODED:
        raise FrameLengthError(f"frame of {len(encoded)} encoded bytes exceeds {MAX_ENCODED}")
    body = cobs_decode(encoded)
    if len(body) < HEADER.size + CRC.size:
        raise FrameLengthError(f"frame of {len(body)} bytes is shorter than header + CRC")
    if len(body) > MAX_BODY:
        raise FrameLengthError(f"frame body of {len(body)} bytes exceeds {MAX_BODY}")
    (crc,) = CRC.unpack_from(body, len(body) - CRC.size)
    if crc != crc16(body[: -CRC.size]):
        raise CrcError(f"CRC mismatch (frame says {crc:#06x})")
    msg_type, flags, seq = HEADER.unpack_from(body)
    return Frame(msg_type, flags, seq, body[HEADER.size : -CRC.size])


@dataclass
class DecoderStats:
    """Counters of what a FrameDecoder received and rejected."""

    frames: int = 0
    crc_errors: int = 0
    cobs_errors: int = 0
    length_errors: int = 0
    bytes_in: int = 0

    @property
    def rejected(self) -> int:
        """Frames dropped for any reason."""
        return self.crc_errors + self.cobs_errors + self.length_errors


class FrameDecoder:
    """Streaming decoder: feed arbitrary byte chunks, get every valid frame.

    Junk, truncated and corrupted frames are dropped and counted in :attr:`stats`
    (the last reason in :attr:`last_error`); a frame with a bad CRC is never returned.
    An over-long run without a delimiter is discarded up to the next delimiter.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overflowed = False
        self.stats = DecoderStats()
        self.last_error: ProtocolError | None = None

    def feed(self, data: bytes) -> Iterator[Frame]:
        """Consume ``data``; yield the frames it completes, in order."""
        self.stats.bytes_in += len(data)
        *complete, tail = bytes(data).split(b"\x00")
        for piece in complete:
            encoded = bytes(self._buf) + piece
            overflowed = self._overflowed
            self._buf.clear()
            self._overflowed = False
            if overflowed:
                self._reject(FrameLengthError("frame longer than the maximum, dropped"))
            elif encoded:
                frame = self._decode(encoded)
                if frame is not None:
                    yield frame
        if not self._overflowed:
            self._buf += tail
            if len(self._buf) > MAX_ENCODED:
                self._buf.clear()
                self._overflowed = True

    def _decode(self, encoded: bytes) -> Frame | None:
        try:
            frame = decode_frame(encoded)
        except ProtocolError as exc:
            self._reject(exc)
            return None
        self.stats.frames += 1
        return frame

    def _reject(self, exc: ProtocolError) -> None:
        self.last_error = exc
        if isinstance(exc, CrcError):
            self.stats.crc_errors += 1
        elif isinstance(exc, CobsError):
            self.stats.cobs_errors += 1
        else:
            self.stats.length_errors += 1
