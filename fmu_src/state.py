"""Serialised FMU state: versioned, checksummed, bounded, and data only (JSON, never pickle).

Layout (little-endian): ``MAGIC`` (8 bytes), u32 format version, u32 phase (the index
in :data:`PHASES` of the phase the state was taken in), u32 payload length, the
payload (UTF-8 JSON of plain numbers, strings, lists and dicts), u32 CRC-32 of
everything before it. The FMI guard (fmu_src/guard/fmi2_guard.c) checks magic,
version, phase, length and CRC before Python sees the bytes, and takes the phase
from the header; :func:`unpack` checks them again, so a state is refused the same
way in a Python host. A checksum proves nothing (anyone can recompute one): the
payload is parsed within bounds (:data:`MAX_PAYLOAD` bytes, :data:`MAX_CONTAINERS`
lists and objects, numbers of at most :data:`MAX_NUMBER` characters), so no input
can exhaust the parser, and the slave then checks every field
(:meth:`fmu_src.slave.DeclaredSlave._set_fmu_state`). Floats round-trip exactly
(JSON writes ``repr``), so a restored instance continues bit for bit; a non-finite
value (an input a master set to NaN) is written as the text ``"nan"``, ``"inf"`` or
``"-inf"``.
"""

from __future__ import annotations

import json
import math
import re
import struct
import zlib
from typing import Any

MAGIC = b"TOGGLEST"
VERSION = 4  # 3: the pending input derivatives (issue 39); 4: the drive's slope span (issue 46)
#: The phases of an instance, in the order of their codes in the header.
PHASES = ("instantiated", "initialising", "stepping", "terminated")
MAX_PAYLOAD = 1 << 16  # bytes; a clamp's state is about 2 kB
MAX_CONTAINERS = 16  # lists and objects; a clamp's state has 5
MAX_NUMBER = 32  # characters of one number; repr of a float has at most 24
MAX_TEXT = 4096  # characters of one string (the guard refuses longer String values)
NON_FINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}
_HEAD = struct.Struct("<8sIII")
_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")
_LONG_NUMBER = re.compile(rf"[-+0-9.eE]{{{MAX_NUMBER + 1},}}")


class StateError(ValueError):
    """Bytes that are not a state this FMU wrote, or a field that no instance could hold."""


def pack(state: dict[str, Any]) -> bytes:
    """The bytes of a state made of JSON-able plain data (finite floats only), whose
    ``phase`` is one of :data:`PHASES`."""
    payload = json.dumps(state, allow_nan=False, separators=(",", ":"),
                         sort_keys=True).encode()
    body = _HEAD.pack(MAGIC, VERSION, PHASES.index(state["phase"]), len(payload)) + payload
    return body + struct.pack("<I", zlib.crc32(body))


def unpack(data: bytes) -> dict[str, Any]:
    """The state in ``data``; raises :class:`StateError` saying what is wrong."""
    data = bytes(data)
    if len(data) < _HEAD.size + 4 or data[:8] != MAGIC:
        raise StateError("not a serialised ToggleClamp state")
    _, version, phase, length = _HEAD.unpack_from(data)
    if version != VERSION:
        raise StateError(f"state format version {version}, this FMU reads version {VERSION}")
    if phase >= len(PHASES):
        raise StateError(f"unknown phase code {phase} in the state header")
    if length != len(data) - _HEAD.size - 4:
        raise StateError(f"truncated or padded state ({len(data)} bytes)")
    if zlib.crc32(data[:-4]) != struct.unpack("<I", data[-4:])[0]:
        raise StateError("state checksum mismatch")
    state = parse(data[_HEAD.size:-4])
    if not isinstance(state, dict):
        raise StateError("state payload is not an object")
    if state.get("phase") != PHASES[phase]:
        raise StateError(f"the state's phase {short(state.get('phase'))} is not the header's "
                         f"{PHASES[phase]!r}")
    return state


def parse(payload: bytes) -> Any:
    """JSON ``payload`` within the bounds above (no recursion or integer-conversion limit
    can be reached); raises :class:`StateError` naming the bound or the syntax error."""
    if len(payload) > MAX_PAYLOAD:
        raise StateError(f"state payload of {len(payload)} bytes (at most {MAX_PAYLOAD})")
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise StateError(f"state payload is not UTF-8: {exc}") from exc
    # counts over the whole text bound those outside strings (where brackets and digits
    # do not count): strip the strings only when a bound is reached
    problem = _beyond_bounds(text) and _beyond_bounds(_STRING.sub('""', text))
    if problem:
        raise StateError(problem)
    try:
        return json.loads(text, parse_constant=_no_constant)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise StateError(f"state payload is not valid JSON: {exc}") from exc


def _beyond_bounds(text: str) -> str | None:
    """What in ``text`` exceeds the parser's bounds, or None."""
    containers = text.count("[") + text.count("{")
    if containers > MAX_CONTAINERS:
        return f"state payload nests {containers} lists and objects (at most {MAX_CONTAINERS})"
    if _LONG_NUMBER.search(text):
        return f"state payload has a number of more than {MAX_NUMBER} characters"
    return None


def _no_constant(name: str) -> float:
    raise StateError(f"non-finite number {name} in the state")


def encode_real(value: float) -> float | str:
    """A Real variable's value as the state holds it: the float, or its text if non-finite."""
    return value if math.isfinite(value) else repr(value)


def decode_real(value: Any, what: str, finite_only: bool = False) -> float:
    """A Real value from a state: a float (never an int or bool), or the text of a
    non-finite one unless ``finite_only``; :class:`StateError` naming ``what`` otherwise."""
    if isinstance(value, float) and math.isfinite(value):
        return value
    if not finite_only and isinstance(value, str) and value in NON_FINITE:
        return NON_FINITE[value]
    raise StateError(f"{what} must be a finite number, got {short(value)}")


def finite(value: Any, what: str) -> float:
    """``value`` as a finite float (never an int or bool), or :class:`StateError`."""
    return decode_real(value, what, finite_only=True)


def text(value: Any, what: str) -> str:
    """A string from a state: at most :data:`MAX_TEXT` characters of valid UTF-8 with no
    control character but line breaks and tabs, as an FMI String variable or a message
    can be; :class:`StateError` otherwise."""
    if not isinstance(value, str):
        raise StateError(f"{what} must be a string, got {short(value)}")
    if len(value) > MAX_TEXT or _CONTROL.search(value):
        raise StateError(f"{what} must be text of at most {MAX_TEXT} characters without "
                         "control characters")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise StateError(f"{what} is not valid UTF-8 text") from exc
    return value


def keys(value: Any, names: set[str] | frozenset[str], what: str) -> dict[str, Any]:
    """``value`` as a dict with exactly the keys ``names``; :class:`StateError` naming the
    missing or extra ones otherwise."""
    if not isinstance(value, dict):
        raise StateError(f"{what} must be an object, got {short(value)}")
    missing, extra = sorted(names - value.keys()), sorted(value.keys() - names)
    if missing or extra:
        raise StateError(f"{what}: " + "; ".join(
            part for part in (missing and f"missing {', '.join(missing)}",
                              extra and f"unknown {', '.join(map(short, extra))}") if part))
    return value


def short(value: Any) -> str:
    """A value as a message shows it: its repr, cut to 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
