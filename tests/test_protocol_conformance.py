"""The MCU model and the host link against the rules of docs/rig-protocol.md, version 1.1.

Each test is one rule of the document that the model or the host once broke: stale seqs
must not re-base the stored seq, 2^15 apart is not stale, boot ids differ per boot, a
later minor version's extra bytes are ignored on both sides, MCU-type frames from the
host are unknown commands, ESTOP repeats carry RETRY, a dead rig is left quickly, and
the last sample of a complete run is no "stopping" sample (tests/test_hil_faults.py).
"""

from __future__ import annotations

import random
import time

import pytest

from hil.emulators.mcu_model import McuModel, RigHardware
from hil.emulators.rig_emulator import FaultPlan, RigEmulator
from hil.link import protocol as p
from hil.link.serial_link import SerialLink

pytestmark = pytest.mark.real_time


def flat(x: float, t: float) -> tuple[float, float]:
    return 0.0, 0.0


def mcu() -> McuModel:
    model = McuModel(flat, RigHardware(), random.Random(0))
    model.handle(p.Hello(1, 1, 7).frame(100, p.FLAG_ACK_REQ), 0.0)  # session, seq 100
    return model


def command(model: McuModel, msg: p.Message, seq: int) -> p.Ack:
    return model.handle(msg.frame(seq, p.FLAG_ACK_REQ), 0.0)[0]


def test_a_stale_command_does_not_rebase_the_stored_seq() -> None:
    model = mcu()
    assert command(model, p.ClearFault(), 200).result == p.Result.OK  # last executed: 200
    assert command(model, p.ClearFault(), 150).result == p.Result.STALE
    # had the STALE answer stored 150, 180 (> 150 but < 200) would now execute
    assert command(model, p.ClearFault(), 180).result == p.Result.STALE
    assert command(model, p.ClearFault(), 201).result == p.Result.OK


def test_a_seq_exactly_half_the_space_away_is_executed() -> None:
    model = mcu()
    assert command(model, p.ClearFault(), 200).result == p.Result.OK
    assert command(model, p.ClearFault(), 200 + 0x8000).result == p.Result.OK
    assert not p.seq_stale(10 + 0x8000, 10) and p.seq_stale(9, 10)


def test_stop_acts_whatever_its_seq_and_hello_always_resets_the_order() -> None:
    model = mcu()
    model.handle(p.Hello(1, 1, 7).frame(60020, p.FLAG_ACK_REQ), 0.0)  # the old host
    assert command(model, p.ClearFault(), 60021).result == p.Result.OK
    # a new host after a dead one: its random seq may be "older"; HELLO re-bases the order
    # even when it is refused, and STOP is never lost to the order
    assert command(model, p.Stop(), 47812).result == p.Result.OK
    assert command(model, p.ClearFault(), 47813).result == p.Result.STALE
    model.handle(p.Hello(1, 1, 8).frame(47814, p.FLAG_ACK_REQ), 0.0)
    assert command(model, p.ClearFault(), 47815).result == p.Result.OK


def test_boot_ids_differ_between_boots_and_emulator_starts() -> None:
    ids = {McuModel(flat, RigHardware(), random.Random(1)).boot_id for _ in range(20)}
    assert len(ids) == 20 and 0 not in ids  # the same fault seed, yet fresh ids
    model = McuModel(flat, RigHardware(), random.Random(1))
    before = model.boot_id
    model.boot()
    assert model.boot_id not in (before, 0)


def test_a_later_minor_version_appends_bytes_that_are_ignored() -> None:
    tel = p.Telemetry(5, 6, 7, 8, 9, 10, 11, 12, 0, p.State.IDLE, 0)
    longer = p.Frame(p.MsgType.TELEMETRY, 0, 1, tel.pack() + b"\x01\x02")
    assert p.parse_message(longer) == tel
    chunk = p.TrajChunk(0, 0, ((1, 2),))
    assert p.parse_message(p.Frame(p.MsgType.TRAJ_CHUNK, 0, 1, chunk.pack() + b"\xff")) == chunk
    model = mcu()
    hello = p.Frame(p.MsgType.HELLO, p.FLAG_ACK_REQ, 300, p.Hello(1, 2, 9).pack() + b"\x00" * 4)
    assert model.handle(hello, 0.0)[0].result == p.Result.OK
    short = p.Frame(p.MsgType.SET_POSITION, p.FLAG_ACK_REQ, 301, b"\x00" * 7)
    assert model.handle(short, 0.0)[0].result == p.Result.BAD_LENGTH


def test_mcu_types_sent_by_the_host_are_unknown_commands() -> None:
    model = mcu()
    for code in range(0x80, 0x85):
        replies = model.handle(p.Frame(code, p.FLAG_ACK_REQ, 400 + code, b""), 0.0)
        assert [type(r) for r in replies] == [p.Ack]
        assert replies[0].result == p.Result.UNKNOWN_TYPE and replies[0].acked_seq == 400 + code
    assert model.handle(p.Frame(0x82, 0, 999, b""), 0.0) == []  # no ACK_REQ, no answer


def test_estop_repeats_reuse_the_seq_and_carry_retry() -> None:
    seen: list[p.Frame] = []
    link = SerialLink("loop://")
    link._ser = type("Capture", (), {"write": lambda _self, data: seen.extend(
        p.FrameDecoder().feed(data))})()
    link.ack_timeout = 0.001
    link.estop()
    assert [f.msg_type for f in seen] == [p.MsgType.ESTOP] * 3
    assert len({f.seq for f in seen}) == 1
    assert [bool(f.flags & p.FLAG_RETRY) for f in seen] == [False, True, True]


def test_a_dead_rig_is_left_without_a_stop_storm() -> None:
    """A rig that stopped answering gets STOP 3 times, then ESTOP 3 times, and no BYE
    (the MCU's heartbeat watchdog ends that session)."""
    emulator = RigEmulator(flat, faults=FaultPlan(stall_at=0.02, stall_for=0.6))
    link = SerialLink(emulator.start(), telemetry_timeout=5.0)
    try:
        link.open()
        link.send_chunk(0, [(i, p.NO_CHECK) for i in range(30)], final=True)
        link.start()  # the MCU hangs 20 ms later (its START acknowledged)
        time.sleep(0.05)
        closing = time.monotonic()
        link.close()
        time.sleep(0.8)  # the MCU wakes up and reads what the host sent
        after = [kind for t, kind in emulator.log.commands if t >= closing]
    finally:
        emulator.close()
    kinds = [k for k in after if k != p.MsgType.HEARTBEAT]
    stops = kinds.count(p.MsgType.STOP)  # 3, more only if the host itself ran late
    assert stops >= 3 and kinds == [p.MsgType.STOP] * stops + [p.MsgType.ESTOP] * 3
