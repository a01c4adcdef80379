"""The stored-calibration commands of protocol 1.3 (docs/rig-protocol.md, section 5), as one
script every MCU runs: the Python model and the host build (tests/test_mcu_config.py)
and the rehosted NUCLEO image (tests/test_firmware_rehost.py). Their answers must be equal.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from hil.link import protocol as p

Answer = tuple[object, ...]


def answer(reply: p.Message) -> Answer:
    """What must be equal across MCUs: all but the seq and the sample (timing)."""
    if isinstance(reply, p.CalibrationReply):
        return ("CALIBRATION", reply.result, reply.state, reply.buf_level, reply.buf_free,
                reply.cal_seq, reply.load_offset, reply.load_gain_n)
    if isinstance(reply, p.HelloReply):
        return ("HELLO_REPLY", reply.result, reply.state, reply.load_offset, reply.load_gain_n)
    assert isinstance(reply, p.Ack), reply
    return ("ACK", reply.result, reply.state, reply.buf_level, reply.buf_free)


def calibration_script(command: Callable[[p.Message], p.Message],
                       reboot: Callable[[], p.HelloReply]) -> list[Answer]:
    """Run the script in an open session at rest; ``reboot`` resets the MCU and opens a new
    session (its HELLO_REPLY). Returns every answer, in order."""
    out = [answer(command(p.ReadCalibration()))]
    out.append(answer(command(p.StoreCalibration(-20_000, 1.25e-4))))
    for offset, gain in ((0, 0.0), (0, -1e-4), (8_388_607, 1e-4), (-8_388_608, 1e-4),
                         (5, math.nan), (5, math.inf)):
        out.append(answer(command(p.StoreCalibration(offset, gain))))
    out.append(answer(command(p.Config(load_offset=0, load_gain_n=2e-4))))  # an override
    out.append(answer(command(p.ReadCalibration())))  # the stored one, not the override
    out.append(answer(reboot()))  # the new session uses the stored calibration
    out.append(answer(command(p.ReadCalibration())))
    out.append(answer(command(p.StoreCalibration(777, 2e-4))))
    out.append(answer(command(p.TrajChunk(0, p.TrajChunk.FINAL, ((0, p.NO_CHECK),) * 30))))
    out.append(answer(command(p.StoreCalibration(778, 2e-4))))  # IDLE, points buffered
    out.append(answer(command(p.Bye())))
    out.append(answer(command(p.StoreCalibration(779, 2e-4))))  # no session: ACK
    return out


#: What the script must answer (docs/rig-protocol.md 1.3), besides being equal everywhere.
G1, G2 = p.StoreCalibration.unpack(p.StoreCalibration(0, 1.25e-4).pack()).load_gain_n, \
    p.StoreCalibration.unpack(p.StoreCalibration(0, 2e-4).pack()).load_gain_n
D = p.StoreCalibration.unpack(p.StoreCalibration(0, 1e-4).pack()).load_gain_n
IDLE, BOOT, CAP = p.State.IDLE, p.State.BOOT, 2048
EXPECTED: list[Answer] = [
    ("CALIBRATION", p.Result.OK, IDLE, 0, CAP, 0, 1500, D),
    ("CALIBRATION", p.Result.OK, IDLE, 0, CAP, 1, -20_000, G1),
    *[("CALIBRATION", p.Result.BAD_VALUE, IDLE, 0, CAP, 1, -20_000, G1)] * 6,
    ("ACK", p.Result.OK, IDLE, 0, CAP),
    ("CALIBRATION", p.Result.OK, IDLE, 0, CAP, 1, -20_000, G1),
    ("HELLO_REPLY", p.Result.OK, IDLE, -20_000, G1),
    ("CALIBRATION", p.Result.OK, IDLE, 0, CAP, 1, -20_000, G1),
    ("CALIBRATION", p.Result.OK, IDLE, 0, CAP, 2, 777, G2),
    ("ACK", p.Result.OK, IDLE, 30, CAP - 30),
    ("CALIBRATION", p.Result.OK, IDLE, 30, CAP - 30, 3, 778, G2),
    ("ACK", p.Result.OK, BOOT, 30, CAP - 30),
    ("ACK", p.Result.NO_SESSION, BOOT, 30, CAP - 30),
]
