"""The conformance checklist of docs/rig-protocol-behaviour.md §13, over the bytes, against
both MCUs: framing, sequence numbers, the state machine and its stops, the checks of §8, telemetry.

Every test runs twice: against the Python MCU model (hil.emulators.mcu_model.ModelMcu) and
against the C firmware's host build on the simulated rig (hil.emulators.firmware.FirmwareMcu),
through the byte-level interface the rig emulator uses (the bench of tests/mcu_bench.py): host
frames in, wire frames out, one tick per period. The two must give the same answers;
``test_a_whole_session_is_the_same_on_both`` compares every frame of a scripted session field
by field. The defects of issue 27 that the model once had (a stop begun at standstill never
ended, and the rest) are cases here. CONFIG and the stored calibration are
tests/test_mcu_config.py.
"""

from __future__ import annotations

import mcu_bench
import numpy as np
import pytest
from mcu_bench import HAVE_GCC, NOISY, Bench, ramp

from hil.link import protocol as p

kind, bench = mcu_bench.kind, mcu_bench.bench  # the bench's fixtures, for pytest


# --- framing ------------------------------------------------------------------------------


def test_the_worked_hello_gets_its_reply(kind: str) -> None:
    b = Bench(kind)
    wire = bytes.fromhex("04 01 01 01 02 01 07 78 56 34 12 d6 b7 00")  # §12
    (reply,) = b.raw(wire)
    assert isinstance(reply, p.HelloReply) and reply.acked_seq == 1
    assert (reply.result, reply.host_nonce, reply.point_period_us) == (p.Result.OK,
                                                                       0x12345678, 1000)


def test_a_259_byte_frame_is_accepted_and_bad_frames_get_no_reply(bench: Bench) -> None:
    body = p.HEADER.pack(p.MsgType.CLEAR_FAULT, p.FLAG_ACK_REQ, 0x0F0F) + b"\x55" * 250
    body += p.CRC.pack(p.crc16(body))
    wire = p.cobs_encode(body) + b"\x00"
    assert len(wire) == 259 and 0 not in body
    (ack,) = bench.raw(wire)  # the longest frame; its extra payload bytes are ignored
    assert (ack.acked_seq, ack.result) == (0x0F0F, p.Result.OK)
    assert bench.raw(b"\x11" * 300 + b"\x00") == []  # overflow: discarded to the delimiter
    assert bench.raw(b"\x00\x00\x03\xff\xfe\x00") == []  # empty frames and junk
    good = p.encode_frame(p.Frame(p.MsgType.CLEAR_FAULT, p.FLAG_ACK_REQ, 0x0F10))
    for bit in range(0, 8 * (len(good) - 1), 3):  # every third bit flipped, one at a time
        bad = bytearray(good)
        bad[bit // 8] ^= 1 << bit % 8
        assert bench.raw(bytes(bad) + b"\x00") == [], bit
    (ack,) = bench.raw(good)  # the receiver resynchronised
    assert ack.acked_seq == 0x0F10


def test_payload_lengths_and_unknown_types(bench: Bench) -> None:
    assert bench.ack(p.SetPosition(0, 0), extra=b"\x01\x02").result == p.Result.OK
    short = p.Frame(p.MsgType.SET_POSITION, p.FLAG_ACK_REQ, 0x0400, b"\x00" * 7)
    assert bench.raw(p.encode_frame(short))[0].result == p.Result.BAD_LENGTH
    for code in (0x0D, 0x7F, 0x80, 0x82, 0x85, 0xFF):
        frame = p.Frame(code, p.FLAG_ACK_REQ, 0x0500 + code, b"")
        (ack,) = bench.raw(p.encode_frame(frame))
        assert (ack.result, ack.acked_seq) == (p.Result.UNKNOWN_TYPE, 0x0500 + code)


def test_nothing_is_answered_without_ack_req(bench: Bench) -> None:
    """Defect: a short HEARTBEAT (no ACK_REQ) got BAD_LENGTH."""
    for frame in (p.Frame(p.MsgType.HEARTBEAT, 0, 1, b"\x01"),
                  p.Frame(p.MsgType.SET_POSITION, 0, 2, b"\x00"),
                  p.Frame(0x82, 0, 3, b""), p.Frame(0x33, 0, 4, b"")):
        assert bench.raw(p.encode_frame(frame)) == []
    assert bench.send(p.SetPosition(5, 6), flags=0) == []  # executed, not answered
    assert (bench.tick().steps, bench.tel[-1].enc) == (5, 6)


# --- sequence numbers -------------------------------------------------------------------


def test_retransmissions_stale_seqs_and_half_the_space(bench: Bench) -> None:
    assert bench.ack(p.SetPosition(10, 0), seq=2000).result == p.Result.OK
    bench.tick()
    bench.ack(p.SetPosition(20, 0), seq=2001)
    again = bench.ack(p.SetPosition(99, 0), seq=2001)  # same seq: answered, not redone
    assert again.result == p.Result.OK and bench.tick().steps == 20
    assert bench.ack(p.ClearFault(), seq=1950).result == p.Result.STALE
    assert bench.ack(p.ClearFault(), seq=1980).result == p.Result.STALE  # not re-based
    assert bench.ack(p.ClearFault(), seq=2001 + 0x8000).result == p.Result.OK


def test_stop_and_estop_act_whatever_their_seq(bench: Bench) -> None:
    """Defect: a STOP with the stored seq was answered but not executed."""
    bench.load(ramp(200))
    start = bench.ack(p.Start(), seq=3000)
    assert start.result == p.Result.OK
    bench.tick(20)
    assert bench.ack(p.Stop(), seq=3000).result == p.Result.OK  # the START's seq
    assert bench.tick().state == p.State.STOPPING
    bench.tick(30)
    assert bench.tel[-1].state == p.State.IDLE
    assert bench.ack(p.EStop(), seq=12).result == p.Result.OK  # stale seq: still acts
    assert bench.tick().state == p.State.ESTOP and bench.tel[-1].faults & p.Fault.ESTOP
    assert bench.ack(p.ClearFault(), seq=3001).result == p.Result.OK
    assert bench.tick().state == p.State.IDLE


# --- the state machine and its stops -----------------------------------------------------


def test_a_run_of_n_points_is_n_plus_one_samples(bench: Bench) -> None:
    bench.load(ramp(100))
    first = bench.ack(p.Start()).sample
    bench.tick(101)
    run = [t for t in bench.tel if t.sample >= first]
    assert [t.exec_index for t in run] == list(range(1, 101)) + [100]
    assert run[-1].state == p.State.IDLE and run[-2].state == p.State.RUNNING
    assert run[-1].steps == run[-2].steps == 100 * 100
    assert (p.State.RUNNING, p.State.IDLE, p.Reason.RUN_COMPLETE) in bench.states()
    assert all(t.flags & p.TelemetryFlag.MOVING for t in run[:-1])
    assert not run[-1].flags & p.TelemetryFlag.MOVING


@pytest.mark.parametrize("how", ["stop", "underrun", "heartbeat"])
def test_a_stop_begun_at_standstill_ends_and_the_rig_is_reusable(kind: str, how: str) -> None:
    """Defect: a stop begun in a zero-step period stayed in STOPPING forever."""
    b = Bench(kind).session()
    b.load(ramp(50, hold=400 if how == "heartbeat" else 100), final=how != "underrun")
    b.ack(p.Start())
    b.tick(140 if how == "underrun" else 100)
    b.beating = how != "heartbeat"
    if how == "stop":
        b.ack(p.Stop())
    for _ in range(400):  # the heartbeat case waits out its 250 ms
        if b.tick().state not in (p.State.RUNNING, p.State.STOPPING):
            break
    stopped = b.tel[-1]  # at zero speed the period after the stop began is the standstill
    assert stopped.state == (p.State.IDLE if how == "stop" else p.State.FAULT)
    assert b.tel[-2].steps == stopped.steps == 5000 and not stopped.flags & p.TelemetryFlag.MOVING
    (_, begun, _), (was, _, reason) = b.states()[-2:]
    assert (begun, was, reason) == (p.State.STOPPING, p.State.STOPPING, p.Reason.STOP_COMPLETE)
    if how != "stop":
        assert b.ack(p.ClearFault()).result == p.Result.OK
    b.tick()
    b.load([(5000 - 10 * (i + 1), p.NO_CHECK) for i in range(20)])
    assert b.ack(p.Start()).result == p.Result.OK
    b.tick(22)
    assert b.tel[-1].state == p.State.IDLE and b.tel[-1].steps == 4800


def test_the_stop_ramp_is_the_same_discrete_law(bench: Bench) -> None:
    """From 125 steps per period (25 mm/s) at 1 m/s^2: 25 periods and about 0.30 mm."""
    bench.load(ramp(100, rate=125))
    bench.ack(p.Start())
    bench.tick(60)
    bench.ack(p.Stop())
    steps = [bench.tick().steps]
    while bench.tel[-1].state == p.State.STOPPING:
        steps.append(bench.tick().steps)
    assert len(steps) == 25 and steps[-1] == steps[-2] and bench.tel[-1].state == p.State.IDLE
    assert np.diff([7500, *steps]).tolist() == list(range(120, -5, -5))  # 5 per period
    assert (steps[-1] - 7500) * 200e-6 == pytest.approx(0.30)  # mm


def test_final_received_goes_with_a_discarded_trajectory(bench: Bench) -> None:
    bench.load(ramp(10))
    assert bench.tick().flags & p.TelemetryFlag.FINAL_RECEIVED
    bench.ack(p.Stop())  # STOP in IDLE discards the buffer
    tel = bench.tick()
    assert tel.buf_level == 0 and not tel.flags & p.TelemetryFlag.FINAL_RECEIVED


# --- the checks of §8 -------------------------------------------------------------------


def test_force_limit_and_a_rail_latch_together(kind: str) -> None:
    """Defect: a sample at the ADC rail latched LOAD_SATURATED but not FORCE_LIMIT."""
    b = Bench(kind).session()
    b.mcu.force_spike(2000.0, 1)
    tel = b.tick()
    assert tel.state == p.State.FAULT
    assert tel.faults == p.Fault.FORCE_LIMIT | p.Fault.LOAD_SATURATED
    (force, _, limit), (sat, raw, adc_max) = b.faults()
    assert (force, limit, sat, raw, adc_max) == (p.Fault.FORCE_LIMIT, 400,
                                                 p.Fault.LOAD_SATURATED, 8_388_607, 8_388_607)
    assert b.states()[-1] == (p.State.IDLE, p.State.FAULT, p.Reason.FAULT)


def test_travel_limit_names_the_bound_crossed(kind: str) -> None:
    """Defect: the upper bound was reported when the lower one was crossed."""
    b = Bench(kind).session(enc_min=-5, enc_max=200_000, steps_min=-100_000)
    b.load([(-100 * (i + 1), p.NO_CHECK) for i in range(300)])
    b.ack(p.Start())
    b.tick(300)
    (fault, value, limit), = b.faults()
    assert fault == p.Fault.TRAVEL_LIMIT and value < -5 and limit == -5


def test_load_stuck_trips_at_exactly_stuck_samples(kind: str) -> None:
    """Defect: 201 identical samples were needed for stuck_samples = 200."""
    b = Bench(kind, NOISY).session(stuck_samples=20)
    b.load(ramp(10, hold=200))
    b.ack(p.Start())
    b.tick(5)
    b.mcu.stick_load(True)
    while b.tick().state == p.State.RUNNING:
        pass
    raws = [t.load_raw for t in b.tel]
    same = 1
    while raws[-1 - same] == raws[-1]:
        same += 1
    (fault, value, limit), = b.faults()
    assert (fault, value, limit, same) == (p.Fault.LOAD_STUCK, 20, 20, 20)


def test_following_error_halts_and_unreferences(kind: str) -> None:
    b = Bench(kind).session(following_error_counts=50)
    b.ack(p.SetPosition(0, 0))
    assert b.tick().flags & p.TelemetryFlag.REFERENCED
    b.load([(100 * (i + 1), 0) for i in range(100)])  # expects the platen never to move
    b.ack(p.Start())
    while b.tick().state == p.State.RUNNING:
        pass
    (fault, value, limit), = b.faults()
    assert (fault, limit) == (p.Fault.FOLLOWING_ERROR, 50) and value > 50
    assert b.tel[-1].state == p.State.FAULT
    assert not b.tel[-1].flags & p.TelemetryFlag.REFERENCED


def test_heartbeat_loss_at_rest_and_the_stop_input(kind: str) -> None:
    b = Bench(kind).session()
    b.beating = False
    b.tick(249)
    assert b.tel[-1].state == p.State.IDLE
    b.tick(3)
    assert b.tel[-1].state == p.State.FAULT
    (fault, value, limit), = b.faults()
    assert (fault, limit) == (p.Fault.HEARTBEAT_LOST, 250) and 250 <= value <= 252
    b.mcu.press_stop()
    tel = b.tick()
    assert tel.state == p.State.ESTOP and not tel.flags & p.TelemetryFlag.DRIVER_ENABLED


# --- telemetry, boots and homing -------------------------------------------------------


def test_telemetry_every_period_of_a_session_only_and_new_boot_ids(kind: str) -> None:
    b = Bench(kind)
    b.silent(5)  # no host, no telemetry; the sample count runs on
    b.session()
    b.ack(p.EStop())
    b.tick(5)
    samples = [t.sample for t in b.tel]
    assert samples == list(range(samples[0], samples[0] + len(samples)))
    assert samples[0] == 5 and b.tel[0].t_us == 5000  # since the MCU's boot
    assert all(t.flags & p.TelemetryFlag.SESSION for t in b.tel)
    first = b.tel[-1].boot_id
    b.mcu.reset()
    b.silent(1)  # the reset ended the session
    assert b.ack(p.Hello(1, 1, 43)).result == p.Result.OK
    tel = b.tick()
    assert tel.boot_id not in (0, first) and tel.sample == 1 and tel.t_us == 1000
    assert (tel.state, tel.steps, tel.enc) == (p.State.IDLE, 0, 0)
    assert not tel.flags & p.TelemetryFlag.REFERENCED
    assert b.ack(p.Bye()).result == p.Result.OK
    b.silent(3)  # BYE ended it


def test_home_switch_follows_the_table(bench: Bench) -> None:
    assert bench.tick().flags & p.TelemetryFlag.HOME_SWITCH  # at the open position
    bench.load(ramp(10, rate=10))
    bench.ack(p.Start())
    bench.tick(12)
    assert not bench.tel[-1].flags & p.TelemetryFlag.HOME_SWITCH
    assert bench.ack(p.SetPosition(0, 0)).result == p.Result.OK
    assert bench.tick().flags & p.TelemetryFlag.REFERENCED


# --- the two implementations side by side ----------------------------------------------


def script(b: Bench) -> None:
    """A session with a run, a stop in motion, a fault and its clearing."""
    b.session(force_limit_n=300.0)
    b.ack(p.SetPosition(0, 0))
    b.load(ramp(200, rate=100, hold=50))
    b.ack(p.Start())
    b.tick(270)
    b.load([(20_000 - 120 * (i + 1), p.NO_CHECK) for i in range(100)])
    b.ack(p.Start())
    b.tick(40)
    b.ack(p.Stop())
    b.tick(40)
    b.mcu.force_spike(1000.0, 2)
    b.tick(3)
    b.ack(p.ClearFault())
    b.tick(3)
    b.ack(p.Bye())
    b.silent(3)


@pytest.mark.skipif(not HAVE_GCC, reason="the firmware's host build needs gcc (Debian gcc)")
def test_a_whole_session_is_the_same_on_both() -> None:
    model, firmware = Bench("model"), Bench("firmware")
    script(model)
    script(firmware)
    assert len(model.tel) == len(firmware.tel) > 300
    for a, b in zip(model.tel, firmware.tel, strict=True):
        _same(a, b)
    assert [_fields(m) for m in model.events] == [_fields(m) for m in firmware.events]


def _fields(msg: p.Message) -> tuple[object, ...]:
    return (type(msg).__name__, *(v for k, v in vars_of(msg).items() if k != "boot_id"))


def vars_of(msg: p.Message) -> dict[str, object]:
    from dataclasses import fields

    return {f.name: getattr(msg, f.name) for f in fields(msg)}


def _same(a: p.Telemetry, b: p.Telemetry) -> None:
    """Equal but for the boot id and a load reading within one count (the plants agree to
    about 1e-9 N; one count is 1e-4 N)."""
    va, vb = vars_of(a), vars_of(b)
    assert abs(int(va.pop("load_raw")) - int(vb.pop("load_raw"))) <= 1, (a, b)
    va.pop("boot_id"), vb.pop("boot_id")
    assert va == vb, (a, b)


def test_repeated_estops_latch_once_and_a_stop_from_rest_stays_put(kind: str) -> None:
    """The host repeats ESTOP back to back: one FAULT frame. A STOP right after a new
    START (before its first period) starts from rest, not from the halted run's speed."""
    b = Bench(kind).session()
    b.load(ramp(100, rate=50))
    b.ack(p.Start())
    b.tick(50)
    for _ in range(3):
        b.ack(p.EStop(), seq=b.seq)
    assert [f for f, _, _ in b.faults()] == [p.Fault.ESTOP]
    b.tick()
    assert b.ack(p.ClearFault()).result == p.Result.OK
    at = b.tick().steps
    b.load([(at + 10, p.NO_CHECK)] * 20)
    b.ack(p.Start())
    b.ack(p.Stop())
    b.tick(5)
    assert {t.steps for t in b.tel[-5:]} == {at} and b.tel[-1].state == p.State.IDLE
@pytest.mark.parametrize("fault", [p.Fault.INTERNAL, p.Fault.OVERTRAVEL, p.Fault.LOAD_ADC,
                                   p.Fault.CLOCK, p.Fault.STOP_CHAIN])
def test_a_boards_fault_de_energises_the_driver_a_force_limit_holds(kind: str,
                                                                   fault: p.Fault) -> None:
    """Section 8: the board's own faults take the driver's enable low at the period that
    latched them (the board can no longer trust its sensing, timing or wiring); FORCE_LIMIT
    halts with the driver energised, holding the clamp. CLEAR_FAULT is refused while the
    board still reports it."""
    b = Bench(kind).session()
    b.load(ramp(50))
    assert b.ack(p.Start()).result == p.Result.OK
    assert b.tick(3).flags & p.TelemetryFlag.DRIVER_ENABLED
    b.mcu.board_fault(fault, 1)
    t = b.tick()
    assert (t.state, t.faults) == (p.State.FAULT, fault)
    assert not t.flags & p.TelemetryFlag.DRIVER_ENABLED
    assert b.faults()[-1] == (fault, 1, 0)
    assert b.ack(p.ClearFault()).result == p.Result.FAULT_ACTIVE
    b.mcu.board_fault(0)
    b.tick()  # the next reading shows it gone
    assert b.ack(p.ClearFault()).result == p.Result.OK
    b.load([(t.steps + k, p.NO_CHECK) for k, _ in ramp(50)])
    assert b.ack(p.Start()).result == p.Result.OK
    b.tick(3)
    b.mcu.force_spike(500.0, 5)  # over the 400 N limit, under the ADC rail
    t = b.tick()
    assert (t.state, t.faults) == (p.State.FAULT, p.Fault.FORCE_LIMIT)
    assert t.flags & p.TelemetryFlag.DRIVER_ENABLED  # holding position
