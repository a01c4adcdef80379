"""Serialised FMU state: versioned, checksummed, and data only (JSON, never pickle).

Layout (little-endian): ``MAGIC`` (8 bytes), u32 format version, u32 payload
length, the payload (UTF-8 JSON of plain numbers, strings, lists and dicts),
u32 CRC-32 of everything before it. The FMI guard (fmu_src/guard/fmi2_guard.c)
checks magic, version, length and CRC before Python sees the bytes;
:func:`unpack` checks them again, so a state is refused the same way in a
Python host. Floats round-trip exactly (JSON writes ``repr``), so a restored
instance continues bit for bit.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from typing import Any

MAGIC = b"TOGGLEST"
VERSION = 1
_HEAD = struct.Struct("<8sII")


class StateError(ValueError):
    """Bytes that are not a state this FMU wrote."""


def pack(state: dict[str, Any]) -> bytes:
    """The bytes of a state made of JSON-able plain data (finite floats only)."""
    payload = json.dumps(state, allow_nan=False, separators=(",", ":"), sort_keys=True)
    body = _HEAD.pack(MAGIC, VERSION, len(payload.encode())) + payload.encode()
    return body + struct.pack("<I", zlib.crc32(body))


def unpack(data: bytes) -> dict[str, Any]:
    """The state in ``data``; raises :class:`StateError` saying what is wrong."""
    data = bytes(data)
    if len(data) < _HEAD.size + 4 or data[:8] != MAGIC:
        raise StateError("not a serialised ToggleClamp state")
    _, version, length = _HEAD.unpack_from(data)
    if version != VERSION:
        raise StateError(f"state format version {version}, this FMU reads version {VERSION}")
    if length != len(data) - _HEAD.size - 4:
        raise StateError(f"truncated or padded state ({len(data)} bytes)")
    if zlib.crc32(data[:-4]) != struct.unpack("<I", data[-4:])[0]:
        raise StateError("state checksum mismatch")
    try:
        state = json.loads(data[_HEAD.size:-4].decode(), parse_constant=_no_constant)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StateError(f"state payload is not valid JSON: {exc}") from exc
    if not isinstance(state, dict):
        raise StateError("state payload is not an object")
    return state


def _no_constant(name: str) -> float:
    raise StateError(f"non-finite number {name} in the state")


def finite(value: Any, what: str) -> float:
    """``value`` as a finite float, or :class:`StateError` naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise StateError(f"{what} must be a finite number, got {value!r}")
    return float(value)
