"""The NUCLEO image's worst tick and `rig_rx` in instructions, on the rehosted board.

The rehosted Cortex-M4 counts one DWT cycle per instruction, so the image's own
``board_tick_stats`` (its longest ``rig_tick`` and ``rig_rx`` in CYCCNT counts, its late
ticks and step-arming errors) are instruction counts here. The session is the costly one
for the receive path: a full 2048-point buffer, then a CONFIG that re-checks all of it and
one refused at its last block (docs/firmware-emulated.md, "Measured"), then a run, a STOP in motion,
ESTOP and CLEAR_FAULT. The counts are taken with ``Machine.exact_counts`` (CYCCNT exact to
the instruction) from the last three chunks of the upload on; the earlier ones are not
counted (the same 30-point frames, at a chunk's resolution).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from hil.emulators.mcu_model import RigHardware
from hil.emulators.rehost.nucleo import NucleoBoard
from hil.emulators.rehost.pulses import command_answered
from hil.link import protocol as p

#: board_nucleo.h's board_stats, in order (uint32 each).
STATS = ("ticks", "late_ticks", "tick_max_cycles", "rx_max_cycles", "step_errors",
         "rx_overruns", "boots", "clock_from_hsi", "rng_failed")
BUFFER_CAPACITY = 2048
CPU_HZ = 180e6
STEP_ARM_DEADLINE_S = 290e-6  # nucleo_step.c: hal_step later than this into its period


@dataclass(frozen=True)
class TickCost:
    """Instructions (DWT counts on the rehosted core) of the worst calls, and the errors."""

    config_rx: int  # the longest rig_rx of the two CONFIGs over the full buffer
    rx_max: int  # the longest rig_rx: the last chunks, the CONFIGs, the commands after
    tick_max: int  # the longest rig_tick from the last chunks on
    ticks: int
    late_ticks: int
    step_errors: int

    def deadline_cpi(self) -> float:
        """The CPI at which a tick due during the longest rig_rx, plus the longest tick,
        still arms its burst by the deadline: the margin as a cycles-per-instruction."""
        return STEP_ARM_DEADLINE_S * CPU_HZ / (self.rx_max + self.tick_max)


def _stats(board: NucleoBoard) -> dict[str, int]:
    raw = board.machine.read_bytes(board.symbol("board_tick_stats"), 4 * len(STATS))
    return dict(zip(STATS, struct.unpack(f"<{len(STATS)}I", raw)))


def _clear_counts(board: NucleoBoard) -> None:
    """The longest rig_rx and rig_tick forgotten: measured again from here."""
    base = board.symbol("board_tick_stats")
    for name in ("tick_max_cycles", "rx_max_cycles"):
        board.machine.uc.mem_write(base + 4 * STATS.index(name), bytes(4))


def measure(elf: Path) -> TickCost:
    """Run the session on a fresh board; the image's own counts."""
    from hil.host.backends import RigSetup

    board = NucleoBoard(elf, hw=RigHardware(x_origin=RigSetup().stroke[0]), seed=3,
                        rng_seed=11)
    board.run(0.02)
    decoder, seq = p.FrameDecoder(), 0

    def command(msg: p.Message, prefix: bytes = b"") -> int:
        nonlocal seq
        seq += 1
        reply, _ = command_answered(board, decoder, msg, seq, prefix=prefix)
        return int(reply.result)

    assert command(p.Hello(host_nonce=0x5EED), prefix=b"\x00") == p.Result.OK
    assert command(p.Config()) == p.Result.OK
    # 2048 points forward at 1 to 100 steps a period, the last one 200: a full buffer
    points = [(sum(1 + k % 100 for k in range(i + 1)), p.NO_CHECK)
              for i in range(BUFFER_CAPACITY - 1)]
    points.append((points[-1][0] + 200, p.NO_CHECK))
    for first in range(0, BUFFER_CAPACITY, p.MAX_CHUNK_POINTS):
        chunk = tuple(points[first:first + p.MAX_CHUNK_POINTS])
        final = p.TrajChunk.FINAL if first + len(chunk) == BUFFER_CAPACITY else 0
        assert command(p.TrajChunk(first, final, chunk)) == p.Result.OK
        if first + 4 * p.MAX_CHUNK_POINTS > BUFFER_CAPACITY and not board.machine.exact_counts:
            _clear_counts(board)  # the last three chunks on, exact
            board.machine.exact_counts = True
    upload_rx = _stats(board)["rx_max_cycles"]
    _clear_counts(board)
    assert command(p.Config(max_step_delta=p.MAX_STEP_DELTA)) == p.Result.OK  # all re-read
    assert command(p.Config(max_step_delta=199)) == p.Result.BAD_VALUE  # the last point
    config_rx = _stats(board)["rx_max_cycles"]
    assert command(p.Start()) == p.Result.OK
    board.run(0.03)
    assert command(p.Stop()) == p.Result.OK
    board.run(0.02)
    command(p.EStop())
    command(p.ClearFault())
    s = _stats(board)
    return TickCost(config_rx, max(upload_rx, s["rx_max_cycles"]), s["tick_max_cycles"],
                    s["ticks"], s["late_ticks"], s["step_errors"])
