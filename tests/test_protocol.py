"""Codec of the rig protocol: COBS, CRC, frames, messages, the streaming decoder."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.link import protocol as p

# one message of every type, with non-default field values that survive f32 rounding
SAMPLES: list[p.Message] = [
    p.Hello(1, 0, 0x12345678),
    p.Heartbeat(123456),
    p.Config(350.5, -1000, 300_000, -50, 90_000, 800, 1500, 0.0001220703125, 4e6, 200, 80, 150),
    p.TrajChunk(60, p.TrajChunk.FINAL, ((10, 4), (-20, p.NO_CHECK), (2**31 - 1, -(2**31)))),
    p.Start(), p.Stop(), p.EStop(), p.ClearFault(), p.SetPosition(-5, 7), p.Bye(),
    p.Ack(65535, p.Result.NO_SPACE, p.State.RUNNING, 2**32 - 1, 10, 2038),
    p.HelloReply(3, 0, 1, 9, 0, 2048, 1, 0, 0x0100, 0xDEADBEEF, 42, 1000, 1000, 30, 2048,
                 200, 1000, 1500, 0.0001220703125, -8_388_608, 8_388_607),
    p.Telemetry(0xDEADBEEF, 7, 7000, 100, 40, -5000, 6, 2000, 0x21, p.State.FAULT, 0x1F),
    p.FaultReport(p.Fault.FORCE_LIMIT, 99, p.State.FAULT, 450, 400),
    p.StateChange(p.State.RUNNING, p.State.IDLE, p.Reason.RUN_COMPLETE, 500, 1234),
]


def test_crc16_check_value() -> None:
    assert p.crc16(b"123456789") == 0x29B1  # the catalogue's check value of CCITT-FALSE


@pytest.mark.parametrize(("data", "encoded"), [
    (b"", b"\x01"),
    (b"\x00", b"\x01\x01"),
    (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
    (b"\x11\x00\x00\x00", b"\x02\x11\x01\x01\x01"),
])
def test_cobs_known_vectors(data: bytes, encoded: bytes) -> None:
    assert p.cobs_encode(data) == encoded
    assert p.cobs_decode(encoded) == data


@given(st.binary(max_size=1000))
def test_cobs_round_trip_has_no_zero(data: bytes) -> None:
    encoded = p.cobs_encode(data)
    assert b"\x00" not in encoded
    assert len(encoded) <= len(data) + 1 + len(data) // 254
    assert p.cobs_decode(encoded) == data


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_every_message_round_trips(msg: p.Message) -> None:
    wire = p.encode_message(msg, 0xABCD, p.FLAG_ACK_REQ)
    assert wire.endswith(b"\x00") and b"\x00" not in wire[:-1]
    assert len(wire) <= p.MAX_ENCODED + 1
    (frame,) = p.FrameDecoder().feed(wire)
    assert (frame.msg_type, frame.flags, frame.seq) == (msg.TYPE, p.FLAG_ACK_REQ, 0xABCD)
    assert p.parse_message(frame) == msg


def test_largest_chunk_fits_the_maximum_frame() -> None:
    points = tuple((-1, -1) for _ in range(p.MAX_CHUNK_POINTS))  # 0xFF bytes: worst COBS case
    wire = p.encode_message(p.TrajChunk(2**32 - 1, 1, points), 0xFFFF)
    assert len(wire) <= p.MAX_ENCODED + 1
    with pytest.raises(p.MessageError):
        p.TrajChunk(0, 0, points + ((0, 0),)).pack()


def test_wrong_payload_length_and_unknown_type_are_message_errors() -> None:
    with pytest.raises(p.MessageError):
        p.parse_message(p.Frame(p.MsgType.TELEMETRY, 0, 1, b"\x00" * 5))
    with pytest.raises(p.MessageError):
        p.parse_message(p.Frame(0x7E, 0, 1, b""))
    with pytest.raises(p.MessageError):
        p.TrajChunk.unpack(p.TrajChunk.FORMAT.pack(0, 0, 2) + b"\x00" * 8)


@pytest.mark.parametrize("msg", SAMPLES[:4] + SAMPLES[-3:], ids=lambda m: type(m).__name__)
def test_every_single_bit_flip_is_rejected(msg: p.Message) -> None:
    wire = p.encode_message(msg, 0x0102)
    frame = p.decode_frame(wire[:-1])
    for bit in range(8 * (len(wire) - 1)):
        bad = bytearray(wire)
        bad[bit // 8] ^= 1 << (bit % 8)
        decoder = p.FrameDecoder()
        accepted = list(decoder.feed(bytes(bad)))
        assert not accepted, f"flipped bit {bit} of {frame} was accepted"
        assert decoder.stats.rejected >= 1


def test_decoder_handles_split_junk_truncated_and_oversize() -> None:
    good = [p.encode_message(m, i) for i, m in enumerate(SAMPLES)]
    stream = (b"\x00\x00junk\x17\x00" + good[0] + good[1][:5] + b"\x00" + good[2]
              + b"\x55" * 600 + b"\x00" + b"".join(good[3:]))
    decoder = p.FrameDecoder()
    frames = [f for i in range(0, len(stream), 7) for f in decoder.feed(stream[i : i + 7])]
    assert [p.parse_message(f) for f in frames] == [SAMPLES[0], SAMPLES[2], *SAMPLES[3:]]
    assert decoder.stats.length_errors >= 1  # the 600-byte run
    assert decoder.stats.rejected == 3  # "junk\x17", the truncated frame, the oversize run


def test_decode_frame_errors_are_specific() -> None:
    wire = p.encode_message(p.Heartbeat(1), 5)[:-1]
    with pytest.raises(p.CrcError):
        p.decode_frame(p.cobs_encode(p.cobs_decode(wire)[:-1] + b"\x01"))
    with pytest.raises(p.FrameLengthError):
        p.decode_frame(p.cobs_encode(b"\x01\x02"))
    with pytest.raises(p.CobsError):
        p.decode_frame(b"\x05\x01")
    with pytest.raises(p.FrameLengthError):
        p.encode_frame(p.Frame(1, 0, 0, b"\x01" * (p.MAX_PAYLOAD + 1)))


def _intact_bodies(stream: bytes) -> set[bytes]:
    """Bodies of the delimited pieces of ``stream`` whose CRC trailer is right."""
    bodies = set()
    for piece in stream.split(b"\x00"):
        try:
            body = p.cobs_decode(piece)
        except p.CobsError:
            continue
        if len(body) >= 6 and p.crc16(body[:-2]) == int.from_bytes(body[-2:], "little"):
            bodies.add(body)
    return bodies


def _overwrite(wire: bytes, pos: int, value: int) -> bytes:
    """``wire`` with one byte before its delimiter set to ``value`` (non-zero)."""
    pos %= len(wire) - 1
    return wire[:pos] + bytes([value]) + wire[pos + 1 :]


WIRES = [p.encode_message(m, n) for n, m in enumerate(SAMPLES)]
# byte streams: random bytes, whole frames, and frames with one byte changed (CRC broken)
STREAMS = st.lists(st.one_of(
    st.binary(max_size=300),
    st.sampled_from(WIRES),
    st.builds(_overwrite, st.sampled_from(WIRES), st.integers(0, 255), st.integers(1, 255)),
), max_size=12).map(b"".join)


@settings(max_examples=300, deadline=None)
@given(STREAMS, st.lists(st.integers(1, 64), min_size=1, max_size=20))
def test_fuzz_decoder_never_raises_and_only_returns_intact_frames(
    junk: bytes, cuts: list[int]
) -> None:
    decoder = p.FrameDecoder()
    frames, i, k = [], 0, 0
    while i < len(junk):
        step = cuts[k % len(cuts)]
        frames += decoder.feed(junk[i : i + step])
        i, k = i + step, k + 1
    intact = _intact_bodies(junk)
    for frame in frames:  # every frame returned is a whole, CRC-correct piece of the input
        body = p.HEADER.pack(frame.msg_type, frame.flags, frame.seq) + frame.payload
        assert body + p.CRC.pack(p.crc16(body)) in intact


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from(range(len(SAMPLES))), min_size=1, max_size=20),
       st.binary(max_size=400), st.randoms(use_true_random=False))
def test_fuzz_corrupted_stream_yields_only_sent_frames(
    which: list[int], noise: bytes, rnd: random.Random
) -> None:
    sent = [p.encode_message(SAMPLES[w], n) for n, w in enumerate(which)]
    stream = bytearray(b"".join(sent))
    for b in noise:  # overwrite, insert or delete bytes at random places
        pos = rnd.randrange(len(stream) + 1)
        op = b % 3
        if op == 0 and pos < len(stream):
            stream[pos] = b
        elif op == 1:
            stream.insert(pos, b)
        elif pos < len(stream):
            del stream[pos]
    decoder = p.FrameDecoder()
    frames = list(decoder.feed(bytes(stream)))
    originals = {p.decode_frame(w[:-1]) for w in sent}
    for frame in frames:
        try:
            p.parse_message(frame)
        except p.MessageError:
            continue  # a random frame can pass CRC-16 (2^-16); it never reaches a handler
        assert frame in originals or frame.msg_type not in p.MESSAGES


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=600))
def test_fuzz_decode_frame_raises_only_protocol_errors(data: bytes) -> None:
    try:
        frame = p.decode_frame(data)
    except p.ProtocolError:
        return
    body = p.cobs_decode(data)  # accepted: so its CRC trailer must be right
    assert p.crc16(body[:-2]) == int.from_bytes(body[-2:], "little")
    assert p.decode_frame(p.encode_frame(frame)[:-1]) == frame


def test_seq_newer_wraps() -> None:
    assert p.seq_newer(1, 0) and p.seq_newer(0, 0xFFFF) and p.seq_newer(0x7FFF, 0)
    assert not p.seq_newer(0, 0) and not p.seq_newer(0xFFFF, 0) and not p.seq_newer(0x8000, 0)
